"""BVH reader: a .bvh file -> a `Take` (joint names, parents, rest and animated world positions, in file units).

Read as most tools write it (Blender, MotionBuilder, bvhio, CMU's conversions, the runtime's own writer):
- joints (ROOT / JOINT, names may contain spaces) with an OFFSET from their parent and 0 to 6 CHANNELS, in any
  order; End Sites are left out (they have no name and carry no motion);
- rotation channels are intrinsic Euler angles in degrees, in the order the CHANNELS line lists them
  (R = R_first @ R_second @ R_third), each joint turned relative to its parent, the rest pose having none;
- position channels, where a joint has them, are its translation from its parent and replace its OFFSET (what
  Blender and bvhio do; the root's OFFSET is usually zero, so the two readings differ only for odd files).
The file is untrusted: its size, joint count, frame count and frame time are bounded, and every problem is one
MotionFileError naming the file and the line.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from mogo_runtime.checks import read_file

from . import MotionFileError, Take

MAX_FILE_BYTES = 256 << 20
MAX_JOINTS = 1024           # the runtime's rig limit (rig.MAX_BONES)
MAX_FRAMES = 200_000        # about 28 minutes at 120 fps
MAX_VALUES = 40_000_000     # frames x channels: 320 MB of float64
MAX_JOINT_FRAMES = 4_000_000   # joints x frames read: 60 joints for 9 minutes at 120 fps (about 0.5 GB)
FPS_RANGE = (1.0, 1000.0)
_AXES = {"X": 0, "Y": 1, "Z": 2}


def read_bvh(path) -> Take:
    """Read `path` (see the module docstring); MotionFileError names the file and what is wrong."""
    where = str(path)
    try:
        text = read_file(Path(path), MAX_FILE_BYTES, error=MotionFileError).decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as e:
        raise MotionFileError(f"{where}: not a text BVH file (byte {e.start} is not UTF-8)") from None
    head, sep, motion = text.partition("\nMOTION")
    if not sep:
        raise MotionFileError(f"{where}: no MOTION section: not a BVH file")
    names, parents, offsets, channels = _hierarchy(head.splitlines(), where)
    values, fps = _motion(motion, sum(len(c) for c in channels), where, head.count("\n") + 2)
    if len(values) * len(names) > MAX_JOINT_FRAMES:
        raise MotionFileError(f"{where}: {len(values)} frames of {len(names)} joints; at most {MAX_JOINT_FRAMES:,} "
                              f"joint positions are computed")
    with np.errstate(all="ignore"):     # the check below says what overflowed, once
        positions, rest = _forward(values, offsets, parents, channels)
    if not np.isfinite(positions).all():
        raise MotionFileError(f"{where}: its motion overflows (values too large to place the joints)")
    return Take(names, parents, rest, positions, fps, where)


def _forward(values: np.ndarray, offsets: np.ndarray, parents: list[int], channels: list[list[str]]):
    """Forward kinematics: channel values (T, C) -> world positions (T, J, 3) and the rest pose's (J, 3)."""
    T, J = len(values), len(parents)
    world_r = np.zeros((T, J, 3, 3))
    positions = np.zeros((T, J, 3))
    rest = np.zeros_like(offsets)
    col = 0
    for j, (p, chans) in enumerate(zip(parents, channels)):     # the file lists parents before their children
        local_t, local_r = np.broadcast_to(offsets[j], (T, 3)).copy(), np.broadcast_to(np.eye(3), (T, 3, 3))
        for c in chans:
            if c.endswith("position"):
                local_t[:, _AXES[c[0]]] = values[:, col]
            else:       # R = R_first @ R_second @ ...: intrinsic, in the order listed
                local_r = local_r @ _axis_rotation(_AXES[c[0]], np.radians(values[:, col]))
            col += 1
        if p < 0:
            world_r[:, j], positions[:, j], rest[j] = local_r, local_t, offsets[j]
        else:
            world_r[:, j] = world_r[:, p] @ local_r
            positions[:, j] = positions[:, p] + np.einsum("tij,tj->ti", world_r[:, p], local_t)
            rest[j] = rest[p] + offsets[j]
    return positions, rest


def _hierarchy(lines: list[str], where: str):
    """The HIERARCHY section -> (names, parents, offsets (J, 3), channel names per joint)."""
    names, parents, offsets, channels = [], [], [], []
    stack: list[int] = []          # open blocks: a joint's index, or -2 for an End Site
    pending = None                 # a joint (or End Site) named but whose '{' has not come yet
    seen_root = False
    for n, raw in enumerate(lines, 1):
        line = raw.strip()
        if not line or (n == 1 and line == "HIERARCHY"):
            continue
        at = f"{where}:{n}"
        word = line.split()[0]
        if word in ("ROOT", "JOINT"):
            name = line[len(word):].strip().removesuffix("{").strip()
            if not name:
                raise MotionFileError(f"{at}: {word} without a name")
            if (word == "ROOT") != (not stack) or (word == "ROOT" and seen_root):
                raise MotionFileError(f"{at}: {word} {name!r} out of place (one ROOT, then JOINTs inside it)")
            if stack and stack[-1] == -2:
                raise MotionFileError(f"{at}: JOINT {name!r} inside an End Site")
            if name in names:
                raise MotionFileError(f"{at}: joint name {name!r} is used twice")
            if len(names) >= MAX_JOINTS:
                raise MotionFileError(f"{at}: more than {MAX_JOINTS} joints")
            seen_root = True
            names.append(name)
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            channels.append(None)
            pending = len(names) - 1
            if line.endswith("{"):
                stack.append(pending)
                pending = None
        elif word == "End":
            if not stack or stack[-1] == -2:
                raise MotionFileError(f"{at}: End Site out of place")
            pending = -2
            if line.endswith("{"):
                stack.append(-2)
                pending = None
        elif line == "{":
            if pending is None:
                raise MotionFileError(f"{at}: '{{' without a joint before it")
            stack.append(pending)
            pending = None
        elif line == "}":
            if not stack:
                raise MotionFileError(f"{at}: '}}' closes nothing")
            j = stack.pop()
            if j >= 0 and (offsets[j] is None or channels[j] is None):
                raise MotionFileError(f"{at}: joint {names[j]!r} has no OFFSET or no CHANNELS line")
        elif word == "OFFSET":
            if not stack:
                raise MotionFileError(f"{at}: OFFSET outside a joint")
            vec = _floats(line.split()[1:], 3, at, "OFFSET")
            if stack[-1] >= 0:
                offsets[stack[-1]] = vec
        elif word == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise MotionFileError(f"{at}: CHANNELS outside a joint")
            channels[stack[-1]] = _channels(line.split()[1:], at)
        else:
            raise MotionFileError(f"{at}: unexpected {shorten(line)!r} in the HIERARCHY")
    if not names:
        raise MotionFileError(f"{where}: no ROOT joint: not a BVH file")
    if stack or pending is not None:
        raise MotionFileError(f"{where}: the HIERARCHY ends before every '{{' is closed")
    return names, parents, np.array(offsets, dtype=np.float64), channels


def _channels(tokens: list[str], at: str) -> list[str]:
    try:
        count = int(tokens[0])
    except (IndexError, ValueError):
        raise MotionFileError(f"{at}: CHANNELS needs a count, got {shorten(' '.join(tokens))!r}") from None
    chans = tokens[1:]
    known = {f"{a}{kind}" for a in "XYZ" for kind in ("position", "rotation")}
    if count != len(chans) or count > 6 or len(set(chans)) != count or not set(chans) <= known:
        raise MotionFileError(f"{at}: CHANNELS must be a count (0 to 6) and that many distinct names from "
                              f"Xposition .. Zrotation, got {shorten(' '.join(tokens))!r}")
    return chans


def _motion(text: str, num_channels: int, where: str, first_line: int) -> tuple[np.ndarray, float]:
    """The MOTION section -> (values (T, channels), fps)."""
    lines = text.split("\n", 3)            # "" (rest of the MOTION line), Frames:, Frame Time:, the rows
    if len(lines) < 3 or not lines[1].strip().startswith("Frames:") or not lines[2].strip().startswith("Frame Time:"):
        raise MotionFileError(f"{where}:{first_line + 1}: MOTION must be followed by 'Frames: N' and 'Frame Time: S'")
    try:
        frames = int(lines[1].split(":", 1)[1])
        frame_time = float(lines[2].split(":", 1)[1])
    except ValueError:
        raise MotionFileError(f"{where}:{first_line + 1}: unreadable frame count or frame time") from None
    if not 1 <= frames <= MAX_FRAMES or frames * max(num_channels, 1) > MAX_VALUES:
        raise MotionFileError(f"{where}: {frames} frames of {num_channels} channels; at most {MAX_FRAMES} frames "
                              f"and {MAX_VALUES:,} values are read")
    if not (np.isfinite(frame_time) and frame_time > 0 and FPS_RANGE[0] <= 1.0 / frame_time <= FPS_RANGE[1]):
        raise MotionFileError(f"{where}: Frame Time {frame_time!r} is not between {1 / FPS_RANGE[1]:g} and "
                              f"{1 / FPS_RANGE[0]:g} seconds")
    rows = lines[3] if len(lines) > 3 else ""
    try:
        values = np.loadtxt(io.StringIO(rows), dtype=np.float64, ndmin=2, max_rows=frames + 1)
    except ValueError as e:
        raise MotionFileError(f"{where}: unreadable MOTION values ({shorten(str(e), 120)})") from None
    if values.size == 0 and num_channels == 0:
        values = np.zeros((frames, 0))
    if values.shape != (frames, num_channels):
        raise MotionFileError(f"{where}: MOTION has {values.shape[0]} rows of {values.shape[1]} values; the header "
                              f"says {frames} frames of {num_channels} channels")
    bad = ~(np.abs(values) < 1e9)      # NaN, infinite, or past any sane position or angle
    if bad.any():
        raise MotionFileError(f"{where}: MOTION has NaN, infinite or huge (1e9 or more) values (first in frame "
                              f"{int(np.argwhere(bad)[0, 0])})")
    return values, 1.0 / frame_time


def _floats(tokens: list[str], n: int, at: str, what: str) -> list[float]:
    try:
        vals = [float(t) for t in tokens]
    except ValueError:
        vals = []
    if len(vals) != n or not all(np.isfinite(v) and abs(v) < 1e9 for v in vals):
        raise MotionFileError(f"{at}: {what} needs {n} finite numbers, got {shorten(' '.join(tokens))!r}")
    return vals


def _axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """(T,) radians -> (T, 3, 3) rotations about x (0), y (1) or z (2)."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros(angle.shape + (3, 3))
    i, k = [(1, 2), (2, 0), (0, 1)][axis]
    m[..., axis, axis] = 1.0
    m[..., i, i], m[..., k, k], m[..., i, k], m[..., k, i] = c, c, -s, s
    return m


def shorten(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[:limit] + "..."
