"""The control benchmark's geometry (benchmarks/control.py): random game paths, where a motion is along a path, which
way its body faces, and the data's typical walking speed."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

STEP = 0.1                   # m between the points of a smooth path
SEARCH = (1.0, 5.0)          # m of path behind and ahead of the last progress searched for the nearest point


def smooth_path(rng, speed: float, length: float) -> np.ndarray:
    """A path of `length` m from the origin: pieces of 1.5-4 s at `speed`, each of constant curvature (a quarter of
    them straight), radius at least max(1 m, speed^2 / 4 m/s^2), the first heading within 45 degrees of +z."""
    kmax = min(1.0, 4.0 / speed ** 2)
    heading, xy, out, done = float(rng.uniform(-math.pi / 4, math.pi / 4)), np.zeros(2), [np.zeros(2)], 0.0
    while done < length:
        piece = min(length - done, speed * float(rng.uniform(1.5, 4.0)))
        k = 0.0 if rng.random() < 0.25 else float(rng.uniform(-kmax, kmax))
        for _ in range(max(1, round(piece / STEP))):
            heading += k * STEP
            xy = xy + STEP * np.array([math.sin(heading), math.cos(heading)])
            out.append(xy)
        done += piece
    return np.array(out)


def polyline_path(rng, length: float) -> tuple[np.ndarray, list[float]]:
    """3-6 straight legs (at least 2 m each) turning 45-135 degrees left or right at each corner -> (points, the arc
    length of each corner)."""
    legs = int(rng.integers(3, 7))
    shares = rng.dirichlet(np.ones(legs))
    lengths = 2.0 + shares * max(0.0, length - 2.0 * legs)
    heading, pts, corners, arc = float(rng.uniform(-math.pi / 4, math.pi / 4)), [np.zeros(2)], [], 0.0
    for i, leg in enumerate(lengths):
        if i:
            heading += math.radians(float(rng.uniform(45, 135))) * float(rng.choice([-1, 1]))
            corners.append(arc)
        pts.append(pts[-1] + leg * np.array([math.sin(heading), math.cos(heading)]))
        arc += leg
    return np.array(pts), corners


def random_path(rng, speed: float, seconds: float) -> tuple[np.ndarray, list[float], str]:
    """Half smooth, half polylines with sharp corners, as long as `seconds` at `speed`."""
    if rng.random() < 0.5:
        return smooth_path(rng, speed, speed * seconds), [], "smooth"
    points, corners = polyline_path(rng, speed * seconds)
    return points, corners, "corners"


def path_progress(points: np.ndarray, xz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Root positions (T, 2) against a polyline -> per frame the distance to the path, the arc length of the nearest
    point (searched around the last one, so a path that crosses itself is followed in order; never going back), and
    the path's direction there (yaw: facing (sin, cos))."""
    seg = np.diff(points, axis=0)
    lengths = np.hypot(*seg.T)
    keep = lengths > 1e-9
    points = np.concatenate([points[:1], points[1:][keep]])
    seg, lengths = seg[keep], lengths[keep]
    starts = np.concatenate([[0.0], np.cumsum(lengths)])
    dirs = seg / lengths[:, None]
    dist, arc, yaw = np.empty(len(xz)), np.empty(len(xz)), np.empty(len(xz))
    progress = 0.0
    for t, p in enumerate(xz):
        k = np.nonzero((starts[1:] >= progress - SEARCH[0]) & (starts[:-1] <= progress + SEARCH[1]))[0]
        along = np.clip(((p - points[k]) * dirs[k]).sum(1), 0.0, lengths[k])
        d = np.hypot(*(points[k] + dirs[k] * along[:, None] - p).T)
        best = int(np.argmin(d))
        progress = max(progress, float(starts[k[best]] + along[best]))
        dist[t], arc[t] = d[best], progress
        yaw[t] = math.atan2(*dirs[k[best]])
    return dist, arc, yaw


def body_yaw(joints: np.ndarray, face_joints) -> np.ndarray:
    """(T, J, 3) -> (T,) the yaw the body faces (sin, cos), from the hips and shoulders as HumanML3D's features
    define the facing: forward = up x across, across = (right hip - left hip) + (right shoulder - left shoulder)."""
    r_hip, l_hip, r_sh, l_sh = face_joints
    across = joints[:, r_hip] - joints[:, l_hip] + joints[:, r_sh] - joints[:, l_sh]
    return np.arctan2(across[:, 2], -across[:, 0])         # forward (x, z) = (across_z, -across_x)


def facing_error(joints: np.ndarray, face_joints, path_yaw: np.ndarray) -> np.ndarray:
    """Per frame the angle (rad, 0..pi) between where the body faces and the path's direction."""
    return np.abs(np.angle(np.exp(1j * (body_yaw(joints, face_joints) - path_yaw))))


def corner_frames(arc: np.ndarray, corners: list[float]) -> list[int]:
    """The frames at which the motion passes each corner (its progress reaches the corner's arc length)."""
    return [int(np.searchsorted(arc, c)) for c in corners if arc[-1] > c]


def travel_agreement(own: np.ndarray, capsule: np.ndarray, fps: float, window_s: float = 0.5,
                     moving: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Where the model walked against where the game moved its capsule: root positions (T, 2) of the model's own
    motion (before it is put on the capsule) and of the capsule -> over each `window_s` window in which the capsule
    moves faster than `moving` m/s, the angle (rad, 0..pi) between the two displacements and the ratio of their
    lengths (own / capsule)."""
    k = max(1, round(window_s * fps))
    a, b = own[k:] - own[:-k], capsule[k:] - capsule[:-k]
    keep = np.hypot(*b.T) > moving * k / fps
    a, b = a[keep], b[keep]
    angle = np.abs(np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(1)))
    return angle, np.hypot(*a.T) / np.hypot(*b.T)


def walking_speed(data: Path, limit: int = 200) -> float:
    """The data's typical walking speed: the median root speed over the middle of its walk_forward clips."""
    info = json.loads((data / "dataset.json").read_text())
    fps = float(info.get("fps", 20.0))
    speeds = []
    for cid in sorted(p.stem for p in (data / "labels").glob("*.txt")):
        if (data / "labels" / f"{cid}.txt").read_text().strip() != "walk_forward":
            continue
        root = np.load(data / "new_joints" / f"{cid}.npy")[:, 0, [0, 2]].astype(np.float64)
        mid = root[len(root) // 4: 3 * len(root) // 4]
        speeds.append(np.hypot(*(mid[-1] - mid[0])) / ((len(mid) - 1) / fps))
        if len(speeds) == limit:
            break
    if not speeds:
        raise ValueError(f"{data}: no walk_forward clips to measure a walking speed on")
    return float(np.median(speeds))
