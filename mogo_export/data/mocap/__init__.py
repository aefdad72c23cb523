"""Reading a studio's motion files (BVH, glTF binary) and turning a rig's animated bones back into HumanML3D joints.

    take = read_bvh("walk.bvh")                  # bvh.py: any skeleton, any channel order, any units
    take = read_glb("walk.glb")                  # gltf.py: the first animation, at its own key rate
    rig, index = map_bones(take, "mixamo")       # mapping.py: which bone follows each HumanML3D joint
    joints, residual = unretarget(...)           # unretarget.py: the inverse of the runtime's retarget
    joints = resample(joints, take.fps, 20.0)    # ... and HumanML3D's frame rate

Both readers give a `Take`: every joint's (node's) name, parent, rest-pose position and animated world position,
in the file's own axes and units. Nothing here knows about rigs or captions; `mogo_export.data.importer` maps a
take's bones onto HumanML3D's joints and writes the dataset.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np


class MotionFileError(ValueError):
    """A motion file that cannot be imported: the message names the file and what is wrong, on one line."""


class Take(NamedTuple):
    names: list[str]            # joint (node) names, as the file spells them
    parents: list[int]          # parent index per joint, -1 for a root; parents come before their children
    rest: np.ndarray            # (J, 3) world position of each joint in the file's rest pose (file units)
    positions: np.ndarray       # (T, J, 3) world position of each joint per frame (file units)
    fps: float                  # frames per second of `positions`
    where: str                  # the file, for messages


def resample_index(frames: int, fps_in: float, fps_out: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames at `fps_out` over a take of `frames` frames at `fps_in`, as (i0, i1, w): output frame k is input frame
    i0[k] moved w[k] of the way to i1[k]. A time that falls on an input frame takes it exactly (w = 0), so
    60 or 120 fps takes go to 20 fps by picking every 3rd or 6th frame, as HumanML3D downsampled AMASS."""
    x = np.arange(int(np.floor((frames - 1) * fps_out / fps_in + 1e-9)) + 1) * (fps_in / fps_out)
    i0 = np.minimum(np.floor(x + 1e-9).astype(np.int64), frames - 1)
    w = np.where(np.abs(x - i0) < 1e-9, 0.0, x - i0)
    return i0, np.minimum(i0 + 1, frames - 1), w
