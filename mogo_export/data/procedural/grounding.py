"""Putting a posed body on the floor: `solve_ground` places the root so heels and toes (and the knees, hands,
back... an action lets rest on the floor, pose.Pose.rest_on) that land on the floor stay where they landed
(and the lowest one is on y=0, or the body follows a ballistic arc in the air), and `lock_feet` takes up with leg IK what the pose leaves over. `pose_to_joints` runs the whole
chain from a Pose's angles to world joint positions.

Separate from kinematics.py because this is where the clip's timeline matters (pins held across frames,
flight phases); forward kinematics is per frame.
"""
from __future__ import annotations

import numpy as np

from mogo_runtime.kinematics.skeleton import HUMANML3D

from .curves import ease
from .kinematics import body_points, contact_points, forward_kinematics, two_bone_ik
from .pose import FPS, GRAVITY, Pose


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in a 1-D bool array."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


TOUCH = 0.02    # m: a pinned heel or toe stays pinned until it rises above this
LAND = 0.01     # m: a heel or toe this low on a supporting foot gets pinned where it is
GRAZE = 0.004   # m: ... and so does any heel or toe this low, support or not (a landing foot)


def _root_heights(points: np.ndarray, flight: np.ndarray) -> np.ndarray:
    """Root y: the lowest contact point on the floor; in the air a ballistic arc from take-off to landing."""
    T = len(points)
    ground = -points[..., 1].min(axis=1)
    y = ground.copy()
    for a, b in _runs(flight):
        a, b = max(a, 1), min(b, T - 1)  # keep a grounded frame on each side
        if b <= a:
            continue
        dur = (b - a + 1) / FPS
        s = np.arange(1, b - a + 1) / FPS
        base = np.interp(np.arange(a, b), [a - 1, b], [ground[a - 1], ground[b]])
        y[a:b] = np.maximum(base + 0.5 * GRAVITY * s * (dur - s), ground[a:b])
    return y


def _leap_velocity(xz: list, a: int, b: int, travel: np.ndarray) -> tuple[float, float]:
    """Root velocity (m/frame) through a leap airborne on frames [a, b): the one that sets the toes down
    at frame b where they left the floor at frame a - 1, moved by `travel` (x, z)."""
    n = b - a + 1
    return tuple(float((xz[a - 1][1][i] + xz[a - 1][3][i] - xz[b][1][i] - xz[b][3][i]) / 2 + travel[i]) / n
                 for i in (0, 1))


def solve_ground(points: np.ndarray, support: np.ndarray, flight: np.ndarray, leap: np.ndarray,
                 air_speed: np.ndarray, yaw_deg: np.ndarray,
                 resting: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Root translation (T, 3), per-foot floor corrections (T, 2, 3) and whether each foot is pinned
    (T, 2), for contact points (T, 4 + K, 3) given relative to the root (heel, toe of left then right foot,
    then the K body parts of kinematics.body_points, which `resting` (T, K) allows on the floor).

    Every heel or toe that comes down on the floor (on a foot the action marks as support, or grazing
    it) is pinned where it lands, and stays pinned until it rises above TOUCH. Each frame the root is
    placed where the pinned points, given the pose, best keep their pins (least squares; newly pinned
    and lifting points, and those of feet the action no longer marks as support, weigh less, so
    hand-overs between feet do not jerk the body). Whatever a foot still misses its pins by is its
    correction, which `lock_feet` applies with leg IK and blends away once the foot lifts. With nothing
    pinned the root keeps its velocity; in the air (`flight`) it follows a ballistic arc. A `leap` (a jump
    off both feet) sets the toes down where they took off, moved by the jump's `air_speed` (m/s along the
    heading) over its airborne frames: the toes do what the action says, whatever the legs' swing
    would carry the body to (it carried in-place jumps 1.6 m forward a jump).

    A body part allowed to rest on the floor (a knee, a hand, the back) is a contact like a heel or toe of a
    supporting foot: the lowest contact is on the floor, and one that comes down is pinned until it lifts,
    so it does not slide; what it misses its pin by is left (no IK moves it), the least squares keep it
    small. Without body parts (K = 0) this is the feet-only solve of every original family, unchanged.
    """
    T = len(points)
    root = np.zeros((T, 3))
    root[:, 1] = _root_heights(points, flight)
    xz = points[..., [0, 2]].tolist()                       # (T, 4, 2) as lists: the loop is per frame
    height = (points[..., 1] + root[:, 1:2]).tolist()
    P = points.shape[1]
    sup = support[:, [0, 0, 1, 1]] if resting is None else np.concatenate([support[:, [0, 0, 1, 1]], resting], 1)
    sup = sup.tolist()                                      # per point: may it carry the body
    air = flight.tolist()
    yaw = np.radians(yaw_deg)
    air_vel = np.stack([np.sin(yaw), np.cos(yaw)], -1) * (air_speed / FPS)[:, None]  # m/frame
    leaps = {a: b for a, b in _runs(leap & flight) if 0 < a and b < T}  # take-off -> landing frame
    pin = [None] * P                                        # [x, z, frames pinned] per point
    corr = np.zeros((T, 2, 3))
    pinned = np.zeros((T, 2), dtype=bool)
    rx = rz = vx = vz = 0.0
    for t in range(T):
        if t in leaps:
            b = leaps[t]
            vx, vz = _leap_velocity(xz, t, b, air_vel[t:b].sum(axis=0))
        h = height[t]
        for p in range(P):
            if pin[p] is not None and (h[p] > TOUCH or air[t]):
                pin[p] = None
        # root from the points pinned so far; weights grow over a pin's first frames and shrink as it lifts
        sw = sx = sz = 0.0
        for p in range(P):
            if pin[p] is not None:
                w = min(1.0, (pin[p][2] + 1) / 4.0) * max(0.05, 1.0 - h[p] / TOUCH)
                if not sup[t][p]:  # a foot the action is lifting is held down, not leant on
                    w *= 0.02
                sw += w
                sx += w * (pin[p][0] - xz[t][p][0])
                sz += w * (pin[p][1] - xz[t][p][1])
        if air[t]:  # nothing is pinned in the air (see above): keep the velocity of the flight
            nx, nz = rx + vx, rz + vz
        elif sw > 0:
            nx, nz = sx / sw, sz / sw
        else:  # nothing on the floor: keep going as before (e.g. the feet of a running stride)
            nx, nz = rx + vx, rz + vz
        if t > 0:
            vx, vz = nx - rx, nz - rz
        rx, rz = nx, nz
        root[t, 0], root[t, 2] = rx, rz
        # pin what just came down, where it is now
        for p in range(P):
            if pin[p] is None and not air[t] and (h[p] < GRAZE or (sup[t][p] and h[p] < LAND)):
                pin[p] = [rx + xz[t][p][0], rz + xz[t][p][1], 0]
            elif pin[p] is not None:
                pin[p][2] += 1
        for f in range(2):  # a foot's correction: the mean miss of its pinned points
            missed = [(pin[p][0] - rx - xz[t][p][0], pin[p][1] - rz - xz[t][p][1])
                      for p in (2 * f, 2 * f + 1) if pin[p] is not None]
            if missed:
                pinned[t, f] = True
                corr[t, f, 0] = sum(m[0] for m in missed) / len(missed)
                corr[t, f, 2] = sum(m[1] for m in missed) / len(missed)
    return root, corr, pinned


def lock_feet(joints: np.ndarray, corr: np.ndarray, pinned: np.ndarray, skeleton=HUMANML3D,
              blend_s: float = 0.4) -> np.ndarray:
    """Move each foot by its floor correction (T, 2, 3) while pinned (T, 2), re-solving the leg with
    two-bone IK (hip fixed, foot translated, so bone lengths are unchanged). The correction a foot lifts
    off with is blended away over the swing (at most `blend_s` seconds), so it rejoins its kinematic
    path smoothly."""
    out = joints.copy()
    T = len(joints)
    for f, (ankle, toe) in enumerate((skeleton.foot_left, skeleton.foot_right)):
        c = np.where(pinned[:, f, None], corr[:, f], 0.0)
        runs = _runs(pinned[:, f])
        for i, (a, b) in enumerate(runs):
            end = min(runs[i + 1][0] if i + 1 < len(runs) else T, b + int(blend_s * FPS))
            if end > b:
                w = ease((np.arange(b, end) - b + 1) / (end - b + 1))[:, None]
                c[b:end] = c[b - 1] * (1 - w)
        fix = np.flatnonzero(np.abs(c).sum(-1) > 1e-7)
        if len(fix) == 0:
            continue
        knee = skeleton.parents[ankle]
        hip = skeleton.parents[knee]
        new_knee, new_ankle = two_bone_ik(joints[fix, hip], joints[fix, knee], joints[fix, ankle] + c[fix],
                                          float(skeleton.bone_lengths[knee]), float(skeleton.bone_lengths[ankle]),
                                          forward=joints[fix, toe] - joints[fix, ankle])
        out[fix, knee] = new_knee
        out[fix, toe] = joints[fix, toe] + (new_ankle - joints[fix, ankle])
        out[fix, ankle] = new_ankle
    return out


def pose_to_joints(pose: Pose) -> np.ndarray:
    """(T, 22, 3) world joint positions (metres, y up) for a Pose."""
    rel, glob = forward_kinematics(pose.angles)
    points, resting = contact_points(rel, glob), pose.resting
    if resting.any():  # body parts that may rest on the floor join the feet's contacts
        points = np.concatenate([points, body_points(rel, resting)], axis=1)
    else:
        resting = None
    root, corr, pinned = solve_ground(points, pose.support, pose.flight, pose.leap, pose.air_speed,
                                      pose.angles[:, 0, 1], resting)
    return lock_feet(rel + root[:, None, :], corr, pinned)
