"""BVH export: joint positions in metres -> a BVH file whose forward kinematics reproduce them.

Hierarchy and joint names come from the `Skeleton` (or a retargeted rig: `rotations_to_bvh_text`); every joint has
rest rotation identity (the BVH convention), so its OFFSET is its rest bone vector in world axes (y up, the body faces
+z). The rotations are `ik.local_rotations` of the positions (see ik.py for how the rest pose is fitted to the clip).
Euler angles are intrinsic, in degrees, in the order the CHANNELS line lists them: the root's `Yrotation Xrotation
Zrotation` (R = Ry @ Rx @ Rz, heading first), every other joint's `Zrotation Yrotation Xrotation` (R = Rz @ Ry @ Rx;
ROOT_ORDER / JOINT_ORDER say why), continuous over time (of the two Euler triples of each rotation the one nearest the
previous frame, then unwrapped: no 180 or 360 degree jumps). The root has position channels and OFFSET 0 0 0, so the
channels are its world position whatever a reader does with root offsets. The file is in centimetres (`units="cm"`,
the default, what most tools expect) or metres (`units="m"`); BVH has no comment syntax, so only the caller's choice
of `units` states which.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..checks import check_fps
from ..kinematics.skeleton import HUMANML3D, Skeleton, children_of, depth_first
from .files import write_atomic
from .ik import axis_angle, local_rotations, rest_offsets

_UNIT_SCALE = {"cm": 100.0, "m": 1.0}
# Intrinsic Euler orders (R = R_first @ R_mid @ R_last), chosen so gimbal lock (middle angle +-90) needs a
# pose that hardly occurs: for the root, lying flat (heading is the outer angle, free to turn); for the
# other joints, whose rest bones lie along y or z, swinging a bone 180 degrees or a foot/head 90 sideways.
ROOT_ORDER = "YXZ"
JOINT_ORDER = "ZYX"


# ----------------------------------------------------------------------------------------------------
# public API

def joints_to_bvh_text(joints, skeleton: Skeleton = HUMANML3D, fps: float = 20.0, units: str = "cm") -> str:
    """BVH text for `joints` (T, J, 3) in metres (y up), written in `units` ("cm" or "m") at `fps`."""
    _check_units(units)
    fps = check_fps(fps)
    pos = skeleton.check_joints(joints, count=True)
    offsets = rest_offsets(pos, skeleton)
    local = local_rotations(pos, skeleton, offsets, fps)               # (T, J, 3, 3)
    return rotations_to_bvh_text(skeleton.joint_names, skeleton.parents, offsets, pos[:, skeleton.root], local,
                                 fps, units, what=f"skeleton {skeleton.name!r}")


def rotations_to_bvh_text(names, parents, offsets, root_positions, local, fps: float, units: str = "cm",
                          what: str = "hierarchy") -> str:
    """BVH text for a hierarchy (joint `names`, `parents` with -1 for the root) whose rest bone vectors are
    `offsets` (J, 3) in world axes, metres; the root at `root_positions` (T, 3) metres and every joint turned by
    `local` (T, J, 3, 3), its rotation relative to its parent's, both measured from the rest pose."""
    _check_units(units)
    fps = check_fps(fps)
    root = parents.index(-1)
    euler = np.degrees(_continuous_euler(local, JOINT_ORDER))          # (T, J, 3) in channel order
    euler[:, root] = np.degrees(_continuous_euler(local[:, root:root + 1], ROOT_ORDER))[:, 0]
    return _format(names, parents, offsets, root_positions, euler, fps, _UNIT_SCALE[units], what)


def write_bvh(path, joints, skeleton: Skeleton = HUMANML3D, fps: float = 20.0, units: str = "cm") -> Path:
    """Write `joints` (T, J, 3) in metres as a BVH file at `path` (atomically). Returns the path."""
    data = joints_to_bvh_text(joints, skeleton, fps, units).encode("ascii")
    return write_atomic(Path(path), lambda f: f.write(data))


def _check_units(units: str) -> None:
    if units not in _UNIT_SCALE:
        raise ValueError(f"units must be one of {sorted(_UNIT_SCALE)}, got {units!r}")


# ----------------------------------------------------------------------------------------------------
# Euler angles

def _continuous_euler(rot: np.ndarray, order: str) -> np.ndarray:
    """(T, N, 3, 3) rotations -> (T, N, 3) radians, intrinsic `order` (e.g. "ZYX": R = Rz @ Ry @ Rx),
    angles listed in that order, continuous in time."""
    i, j, k = ("XYZ".index(a) for a in order)
    e = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0   # parity of the axis order
    mid = np.arcsin(np.clip(e * rot[..., i, k], -1.0, 1.0))
    first = np.arctan2(-e * rot[..., j, k], rot[..., k, k])
    last = np.arctan2(-e * rot[..., i, j], rot[..., i, i])
    locked = np.cos(mid) < 1e-7  # gimbal lock: only first +- last is defined
    out = np.stack([first, mid, last], -1)
    two_pi = 2 * np.pi
    for t in range(len(rot)):
        prev = out[t - 1] if t else np.zeros_like(out[0])
        if locked[t].any():  # keep the previous `last` angle and solve `first` from what is left
            n = np.flatnonzero(locked[t])
            rest = rot[t, n] @ np.swapaxes(axis_angle(np.eye(3)[k], prev[n, 2]), -1, -2)  # = R_i(first) R_j(mid)
            out[t, n, 0] = np.arctan2(e * rest[:, k, j], rest[:, j, j])
            out[t, n, 2] = prev[n, 2]
        if t == 0:
            continue
        a = out[t]
        b = np.stack([a[:, 0] + np.pi, np.pi - a[:, 1], a[:, 2] + np.pi], -1)  # the same rotation
        a, b = (x + two_pi * np.round((prev - x) / two_pi) for x in (a, b))    # unwrapped to near the last frame
        pick_b = ((b - prev) ** 2).sum(-1) < ((a - prev) ** 2).sum(-1)
        out[t] = np.where(pick_b[:, None], b, a)
    return out


# ----------------------------------------------------------------------------------------------------
# text

def _format(names, parents, offsets, root_positions, euler, fps: float, scale: float, what: str) -> str:
    for n in names:
        if not n or any(c.isspace() for c in n):
            raise ValueError(f"{what}: joint name {n!r} cannot be written to BVH (empty or has spaces)")
    children = children_of(parents)
    lines = ["HIERARCHY"]

    def vec(v) -> str:
        return " ".join(f"{c:.6f}" for c in v)

    def joint(j: int, depth: int) -> None:
        ind = "\t" * depth
        root = parents[j] < 0
        chans = "CHANNELS 6 Xposition Yposition Zposition " if root else "CHANNELS 3 "
        rots = " ".join(f"{a}rotation" for a in (ROOT_ORDER if root else JOINT_ORDER))
        lines.extend([f"{ind}{'ROOT' if root else 'JOINT'} {names[j]}", f"{ind}{{",
                      f"{ind}\tOFFSET {vec(np.zeros(3) if root else offsets[j] * scale)}", f"{ind}\t{chans}{rots}"])
        for c in children[j]:
            joint(c, depth + 1)
        if not children[j]:
            # Half the incoming bone, along it: gives the leaf bone a visible length in viewers.
            lines.extend([f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET {vec(offsets[j] * 0.5 * scale)}",
                          f"{ind}\t}}"])
        lines.append(f"{ind}}}")

    order = depth_first(parents)
    joint(order[0], 0)
    T = len(root_positions)
    lines += ["MOTION", f"Frames: {T}", f"Frame Time: {1.0 / fps:.8f}"]
    # Channels in the hierarchy's order, which is depth first from the root.
    values = np.concatenate([np.asarray(root_positions) * scale, euler[:, order].reshape(T, -1)], axis=1)
    lines += [" ".join(f"{v:.6f}" for v in row) for row in values]
    return "\n".join(lines) + "\n"
