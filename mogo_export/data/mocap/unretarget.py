"""The inverse of the runtime's retarget (mogo_runtime/outputs/retarget.py): a rig's animated bones -> HumanML3D joints.

    joints, residual = unretarget(bones, rest, fps=20.0, layout="humanml3d")

`bones` (T, 22, 3) are the world positions (y up) of the rig bones that follow each HumanML3D joint, `rest` (22, 3)
the same bones in the file's rest pose, in any units: the rig is scaled to HumanML3D's legs (thigh plus shin), as
the retarget scales paths by the ratio of the legs, so the result is in metres on HumanML3D's skeleton.

What a rig carries of a HumanML3D motion, and so what comes back:
- every bone with one followed child points where the source's bone pointed (the retarget swings it there), so a
  joint with one child gets that direction, with HumanML3D's bone length;
- a bone with several followed children (hips: both thighs and the spine; chest: neck and collars) turns as the
  best fit of the source's children, whose layout (how the hips sit around the pelvis) the rig does not keep: it is
  `layout`'s, "humanml3d" as measured on the real dataset's clip (hips 8 cm below the pelvis, collars rising) or
  "procedural" as mogo's procedural clips and the `humanml3d` rig have it (the skeleton's rest directions: hips
  level with the pelvis, collars level). A clip of the other layout comes back with its hips and collars moved
  (about 8 cm; the rest of the body follows the bones' directions, as it should);
- the hips' path, divided by the leg ratio; the height from the feet (the retarget puts the rig's lowest foot as
  high above its floor as the source's, scaled), with the clip's lowest joint on y = 0 as HumanML3D's are;
- planted feet: the retarget swings a leg up to 1.9 degrees and shifts the hips up to 0.9 cm to keep a toe still
  on a rig of other proportions. Undone by fixed-point iteration: retarget the current estimate onto a rig of the
  file's own rest pose, and correct the estimate by what that changes; it converges in 3 to 5 rounds on the
  shipped rigs, and the best estimate is kept with its `residual` (metres, largest joint difference between what
  the file's bones give and what the estimate's retarget gives: about 0 for a file the runtime wrote).
"""
from __future__ import annotations

import numpy as np

from mogo_runtime.kinematics.quaternion import unit
from mogo_runtime.kinematics.skeleton import HUMANML3D, rest_positions
from mogo_runtime.outputs.ik import kabsch, min_rotation
from mogo_runtime.outputs.retarget import retarget
from mogo_runtime.outputs.rig import FOOT_SOURCES, Rig

from . import MotionFileError, resample_index

LAYOUTS = ("humanml3d", "procedural")
ITERATIONS = 8
CONVERGED_M = 1e-7
MAX_REACH_M = 10_000.0
# The rest offsets of the children of HumanML3D's two branching joints (pelvis, spine3), measured on the real clip
# 012314 (mogo_runtime.outputs.ik.rest_offsets: the rigid best fit over its 170 frames, within 1e-6 m; their
# lengths are skeleton.py's). Every other bone lies along its rest direction in both layouts.
_MEASURED = {"left_hip": (0.053541, -0.08423, -0.025748), "right_hip": (-0.06701, -0.08367, -0.024153),
             "spine1": (0.003892, 0.131511, 0.0), "neck": (-0.004235, 0.219319, 0.0),
             "left_collar": (0.067391, 0.118839, -0.015442), "right_collar": (-0.076392, 0.120431, -0.014807)}
_FEET = [HUMANML3D.joint_names.index(f) for f in FOOT_SOURCES]
_LEGS = [[HUMANML3D.joint_names.index(f"{side}_{j}") for j in ("hip", "knee", "ankle")] for side in ("left", "right")]


def layout_offsets(layout: str) -> np.ndarray:
    """(22, 3) HumanML3D rest offsets (metres) in `layout` (one of LAYOUTS; see the module docstring)."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    offsets = HUMANML3D.offsets.copy()
    if layout == "humanml3d":
        for name, v in _MEASURED.items():
            offsets[HUMANML3D.joint_names.index(name)] = v
    return offsets


def up_rotation(rest: np.ndarray, where: str) -> np.ndarray:
    """The turn that stands a file's rest pose (22 bones, as HumanML3D's joints) upright: from the world axis its
    spine is nearest to (pelvis to neck; BVH files come y up or z up) onto +y. Facing does not matter: HumanML3D's
    features turn every clip to face +z."""
    spine = rest[HUMANML3D.joint_names.index("neck")] - rest[HUMANML3D.root]
    axis = np.zeros(3)
    axis[np.argmax(np.abs(spine))] = np.sign(spine[np.argmax(np.abs(spine))])
    if spine @ axis < np.cos(np.radians(45.0)) * np.linalg.norm(spine):
        raise MotionFileError(f"{where}: the rest pose is not upright (its spine is more than 45 degrees from every "
                              f"axis), so which way is up is not known")
    return min_rotation(axis[None], np.array([[0.0, 1.0, 0.0]]))[0]


def unretarget(bones: np.ndarray, rest: np.ndarray, fps: float, layout: str = "humanml3d",
               iterations: int = ITERATIONS, where: str = "motion") -> tuple[np.ndarray, float]:
    """-> (joints (T, 22, 3) metres, residual metres); see the module docstring."""
    offsets = layout_offsets(layout)
    scale = _leg_length(rest) / _leg_length(rest_positions(offsets, HUMANML3D.parents))
    if not np.isfinite(scale) or scale <= 0:
        raise MotionFileError(f"{where}: its legs have no length in the rest pose")
    bones, rest = bones / scale, rest / scale
    reach = float(max(np.abs(bones).max(), np.abs(rest).max()))
    if reach > MAX_REACH_M:       # finite but absurd numbers overflow in the features
        raise MotionFileError(f"{where}: its bones go {reach:.3g} m from the origin (scaled to HumanML3D's body); at "
                              f"most {MAX_REACH_M:g} m")
    for j, p in enumerate(HUMANML3D.parents):
        if p >= 0 and np.linalg.norm(rest[j] - rest[p]) < 0.01:
            raise MotionFileError(f"{where}: the bones following {HUMANML3D.joint_names[p]} and "
                                  f"{HUMANML3D.joint_names[j]} sit on each other in the rest pose (under 1 cm apart "
                                  f"at HumanML3D's size), so the bone between them has no direction")
    rig = Rig(name="import", description=where, rest_pose="T", bone_names=HUMANML3D.joint_names,
              parents=HUMANML3D.parents, heads=rest, sources=tuple(range(HUMANML3D.num_joints)), where=where)
    target = _direct(bones, rig, offsets)
    best, src = (np.inf, target), target
    for _ in range(iterations):
        diff = target - _direct(retarget(src, rig, fps=fps).positions, rig, offsets)
        residual = float(np.abs(diff).max())
        if residual < best[0]:
            best = (residual, src)
        if residual < CONVERGED_M:
            break
        src = _rebuild(src + diff, offsets)
        # _direct sets the floor from the clip, so the residual cannot see the estimate's height drift; but the
        # retarget's planted-foot test reads it (a toe under 5 cm): keep the lowest joint on the floor.
        src[..., 1] -= src[..., 1].min()
    return best[1], best[0]


def resample(joints: np.ndarray, fps_in: float, fps_out: float, layout: str = "humanml3d") -> np.ndarray:
    """HumanML3D joints at `fps_out`: a frame between two of the clip's gets the root moved linearly and each bone
    turned part of the way (its direction interpolated), so bones keep their length; a time that falls on a frame
    takes it exactly (60 and 120 fps go to 20 by taking every 3rd or 6th frame, as HumanML3D took AMASS's)."""
    if fps_in == fps_out:
        return joints
    i0, i1, w = resample_index(len(joints), fps_in, fps_out)
    w = w[:, None, None]
    return _rebuild(joints[i0] + w * (joints[i1] - joints[i0]), layout_offsets(layout))


def _direct(bones: np.ndarray, rig: Rig, offsets: np.ndarray) -> np.ndarray:
    """One pass of the inverse: HumanML3D joints from the bones' directions, the hips' path and the feet's heights
    (planted-foot corrections left in)."""
    out = np.zeros(bones.shape)
    out[:, 0] = bones[:, 0] - rig.heads[0]
    src_rest = rest_positions(offsets, HUMANML3D.parents)
    for j in HUMANML3D.depth_first():
        ch = HUMANML3D.children[j]
        if len(ch) == 1:
            out[:, ch[0]] = out[:, j] + unit(bones[:, ch[0]] - bones[:, j]) * np.linalg.norm(offsets[ch[0]])
        elif ch:
            # The retarget turned this bone by kabsch(rig's rest directions -> source's directions); kabsch commutes
            # with turning the source, so the source's turn is the bone's turn less the constant turn between the
            # rig's rest directions and the layout's.
            rest_dirs = unit(rig.heads[ch] - rig.heads[j])
            turn = kabsch(rest_dirs[None], unit(bones[:, ch] - bones[:, None, j]))
            between = kabsch(rest_dirs[None], unit(src_rest[ch] - src_rest[j])[None])[0]
            out[:, ch] = out[:, None, j] + np.einsum("tij,kj->tki", turn @ between.T, offsets[ch])
    # The retarget sets the hips' height so the rig's lowest foot is as high above the floor as the source's (scaled);
    # the floor itself (a constant) is the clip's lowest joint, as HumanML3D's clips have it.
    out[..., 1] += (bones[:, _FEET, 1].min(1) - out[:, _FEET, 1].min(1))[:, None]
    out[..., 1] -= out[..., 1].min()
    return out


def _rebuild(joints: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The same pose with the skeleton's bone lengths again (an iteration's correction moves joints freely)."""
    out = joints.copy()
    for j in HUMANML3D.depth_first()[1:]:
        p = HUMANML3D.parents[j]
        out[:, j] = out[:, p] + unit(joints[:, j] - joints[:, p]) * np.linalg.norm(offsets[j])
    return out


def _leg_length(heads: np.ndarray) -> float:
    """Thigh plus shin, mean of the two legs: the ratio the retarget scales paths by (retarget._leg_length)."""
    return float(np.mean([sum(np.linalg.norm(heads[b] - heads[a]) for a, b in zip(leg, leg[1:])) for leg in _LEGS]))
