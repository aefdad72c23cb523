"""The control vector: where the game wants the character's root over the next second, as the step graph reads it
(docs/bundle.md, "Control"). One function writes it (`encode`), for training targets (a clip's own future root,
`root_poses` then `token_controls`) and for the runtime's targets (control/targets.py) alike, so both mean the same
thing.

A root pose is (x, z, yaw): metres on the floor, y up, facing the world direction (sin yaw, cos yaw), so yaw 0
faces +z, as frame 0 of every motion does. The control of the step that picks token j is read in the frame of the
root at frame j * downsample (the first frame of token j, whose pose the frames of tokens < j already fix):

    [present, then for k = 1 .. horizon: x_k, z_k, sin(yaw_k - yaw_0), cos(yaw_k - yaw_0)]

with (x_k, z_k) the root's position k tokens (k * downsample frames) later in that frame: z forward, x to the
root's left as the features' root velocity has it (HumanML3D's convention). present = 0 and all zeros: no control.
"""
from __future__ import annotations

import numpy as np

from ..kinematics.features import recover_root_rot_pos

FIELDS = 4            # per horizon step: x, z, sin, cos


def control_dim(horizon: int) -> int:
    return 1 + FIELDS * horizon


def to_local(now: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World (x, z) points (..., 2) -> the same in the frame of root pose `now` (x, z, yaw), or of poses (..., 3)
    that broadcast against the points' leading axes."""
    d = np.asarray(points, np.float64) - now[..., :2]
    c, s = np.cos(now[..., 2]), np.sin(now[..., 2])
    return np.stack([d[..., 0] * c - d[..., 1] * s, d[..., 0] * s + d[..., 1] * c], axis=-1)


def to_world(now: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Inverse of `to_local`: (..., 2) in the frame of `now` (as to_local's) -> world (x, z)."""
    local = np.asarray(local, np.float64)
    c, s = np.cos(now[..., 2]), np.sin(now[..., 2])
    return np.stack([local[..., 0] * c + local[..., 1] * s, -local[..., 0] * s + local[..., 1] * c], axis=-1) \
        + now[..., :2]


def encode(now: np.ndarray, future: np.ndarray) -> np.ndarray:
    """Root pose now (3,) and the wanted poses (horizon, 3) one token apart -> the control vector (float32)."""
    return encode_many(np.asarray(now)[None], np.asarray(future)[None])[0]


def encode_many(now: np.ndarray, future: np.ndarray) -> np.ndarray:
    """`encode` for many streams at once (a crowd's), the same numbers: poses now (B, 3), wanted poses (B, horizon,
    3) -> (B, dim) float32 (elementwise arithmetic, and numpy's float64 sin and cos, which give libm's bits at any
    array length: kinematics/frames.py)."""
    now, future = np.asarray(now, np.float64), np.asarray(future, np.float64)
    out = np.empty((len(now), 1 + FIELDS * future.shape[1]))
    out[:, 0] = 1.0
    per_step = out[:, 1:].reshape(len(now), -1, FIELDS)
    per_step[..., :2] = to_local(now[:, None], future[..., :2])
    turn = future[..., 2] - now[:, None, 2]
    per_step[..., 2], per_step[..., 3] = np.sin(turn), np.cos(turn)
    return out.astype(np.float32)


def decode(now: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """A present control vector read back as world poses (horizon, 3) from root pose `now` (for tests, plots)."""
    per_step = np.asarray(vector, np.float64)[1:].reshape(-1, FIELDS)
    xz = to_world(now, per_step[:, :2])
    yaw = now[2] + np.arctan2(per_step[:, 2], per_step[:, 3])
    return np.concatenate([xz, yaw[:, None]], axis=1)


def root_poses(features: np.ndarray) -> np.ndarray:
    """(T, D) features -> the root pose (T, 3) of every frame, as `recover_from_ric` places the root."""
    quat, pos = recover_root_rot_pos(features)
    # the features rotate by a half-angle a about y; the root faces (-sin 2a, cos 2a), i.e. yaw = -2a
    yaw = -2.0 * np.arctan2(quat[:, 2], quat[:, 0])
    return np.concatenate([pos[:, [0, 2]], yaw[:, None]], axis=1)


def token_controls(poses: np.ndarray, downsample: int, horizon: int) -> np.ndarray:
    """A clip's own future as the control of each step that picks its tokens: root poses (T, 3) of its frames ->
    (T // downsample + 1, dim) float32, row j for token j (the last row: the step that ends the clip). Poses past
    the clip's end stay at its last frame: a clip that ends has stopped."""
    T = len(poses)
    n = T // downsample
    rows = np.empty((n + 1, control_dim(horizon)), np.float32)
    for j in range(n + 1):
        f0 = min(j * downsample, T - 1)
        ahead = np.minimum(f0 + downsample * np.arange(1, horizon + 1), T - 1)
        rows[j] = encode(poses[f0], poses[ahead])
    return rows
