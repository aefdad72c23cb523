"""Joints frame by frame, as a stream's features arrive: the root integrated over time, and planted toes held.

    joints = FrameJoints(skeleton)        # RootIntegrator, then FootLock
    for features in chunks:               # (n, D) de-normalised features of the next n frames
        out = joints.push(features)       # (n, J, 3) metres, y up: what the whole motion's frames would be
"""
from __future__ import annotations

import numpy as np

from .features import FeatureLayout
from .skeleton import Skeleton


class RootIntegrator:
    """`features.recover_from_ric` one frame at a time, for streaming: the same joints, frame for frame.

    A frame's root heading and xz position integrate the *previous* frames' velocities (features 0-2),
    so the running heading and position are all the state there is. float64 throughout, as recover_from_ric.
    """

    def __init__(self, skeleton: Skeleton):
        num_joints = skeleton.num_joints
        self.layout = FeatureLayout(num_joints)
        self.num_joints = num_joints
        # [angle, x, z, rot_vel, vel_x, vel_z] in one row (a crowd gathers its streams' with one operation): the
        # half-angle of the root's facing about y as in the features, the root's x and z, and the velocities of
        # the last frame seen (`previous`: frame 0 stays put)
        self._state = np.zeros(6)

    @property
    def angle(self) -> float:
        return self._state[0]

    @angle.setter
    def angle(self, value: float) -> None:
        self._state = np.concatenate([[value], self._state[1:]])

    @property
    def position(self) -> np.ndarray:
        return self._state[1:3]

    @position.setter
    def position(self, value) -> None:
        self._state = np.concatenate([self._state[:1], np.asarray(value, np.float64).reshape(2), self._state[3:]])

    @property
    def previous(self) -> np.ndarray:
        return self._state[3:6]

    @previous.setter
    def previous(self, value) -> None:
        self._state = np.concatenate([self._state[:3], np.asarray(value, np.float64).reshape(3)])

    def push(self, features: np.ndarray) -> np.ndarray:
        """features (n, D) of the next n frames -> joints (n, J, 3), in the features' float dtype."""
        x = np.asarray(features)
        if x.ndim != 2 or x.shape[1] != self.layout.dim:
            raise ValueError(f"RootIntegrator.push wants (n, {self.layout.dim}) features, got {x.shape}")
        return RootIntegrator.push_many([self], x[None])[0]

    @staticmethod
    def push_many(roots: list["RootIntegrator"], features: np.ndarray) -> np.ndarray:
        """`push` for many streams at once, the same numbers: features (B, n, D), stream b's next n frames ->
        joints (B, n, J, 3). Elementwise arithmetic and in-order running sums only, so a stream's joints do not
        depend on the batch it is in (its cos and sin too: numpy's float64 sin and cos gave libm's bits at every
        array length and offset tried, 200,000 values)."""
        x = np.asarray(features)
        out_dtype = x.dtype if x.dtype.kind == "f" else np.float32
        x64 = x.astype(np.float64)
        B, n = x64.shape[:2]
        J = roots[0].num_joints
        state = np.stack([r._state for r in roots])
        angle, position, previous = state[:, 0], state[:, 1:3], state[:, 3:6]   # previous: the frame before each
        velocity = np.concatenate([previous[:, None], x64[:, :-1, :3]], axis=1)    # (B, n, 3) moving frame i
        # running sums over the frames: cumsum adds in order, as a frame-by-frame loop would
        angles = np.cumsum(np.concatenate([angle[:, None], velocity[..., 0]], axis=1), axis=1)[:, 1:]   # (B, n)
        # contiguous, as the angles a frame-by-frame loop would pass: numpy may take another path for strided input
        angles = np.ascontiguousarray(angles)
        c, s = np.cos(angles), np.sin(angles)
        # qrot(qinv(q(angle)), v) for v = (vx, 0, vz): a rotation by -2*angle about y
        cos2, sin2 = c * c - s * s, 2 * c * s
        vx, vz = velocity[..., 1], velocity[..., 2]
        step = np.stack([cos2 * vx - sin2 * vz, sin2 * vx + cos2 * vz], axis=-1)                     # (B, n, 2)
        pos = np.cumsum(np.concatenate([position[:, None], step], axis=1), axis=1)[:, 1:]          # (B, n, 2)
        ric = x64[:, :, 4:4 + (J - 1) * 3].reshape(B, n, J - 1, 3)
        joints = np.empty((B, n, J, 3))
        joints[:, :, 0, 0], joints[:, :, 0, 1], joints[:, :, 0, 2] = pos[..., 0], x64[:, :, 3], pos[..., 1]
        c2, s2 = cos2[..., None], sin2[..., None]
        joints[:, :, 1:, 0] = c2 * ric[..., 0] - s2 * ric[..., 2] + pos[..., :1]
        joints[:, :, 1:, 1] = ric[..., 1]
        joints[:, :, 1:, 2] = s2 * ric[..., 0] + c2 * ric[..., 2] + pos[..., 1:]
        if n:
            for r, row in zip(roots, np.concatenate([angles[:, -1:], pos[:, -1], x64[:, -1, :3]], axis=1)):
                r._state = row
        return joints.astype(out_dtype)

    def next_pose(self) -> np.ndarray:
        """The root pose (x, z, yaw) of the next frame, which the frames so far fix (yaw as control/vector.py has
        it: the root faces (sin yaw, cos yaw))."""
        return np.array(_next_pose(*self._state))


def _next_pose(angle, x, z, rot_vel, vx, vz):
    """The next frame's root pose (x, z, yaw) from a RootIntegrator's state, of one stream (numpy scalars) or of many
    (arrays): the same numbers."""
    angle = angle + rot_vel
    cos2, sin2 = np.cos(2 * angle), np.sin(2 * angle)
    return x + (cos2 * vx - sin2 * vz), z + (sin2 * vx + cos2 * vz), -2.0 * angle


class FootLock:
    """Keeps a planted toe planted by moving the whole body (x, z) by what the toe slides.

    The decoder predicts each frame's foot contacts (features `foot_contact`: left ankle, left toe, right ankle,
    right toe). Where a toe's contact channel is above CONTACT on the previous frame and on this one, its
    horizontal step between them (in the unlocked joints) is a slide; the body's running offset takes away the
    mean slide of the toes so held, and every later frame carries the offset:

        offset_0 = 0,  offset_t = offset_{t-1} - mean over held toes k of (toe_k[t] - toe_k[t-1])[x, z]

    Causal, with the offset and the last frame's toes as its state, so a stream and a whole motion get the same
    joints. It is there for the frames after a prompt switch, where the decoder joins two motions: on the base
    model's 10-minute streams it took foot skating (a toe below 5 cm moving over 2.5 cm a frame) within 1 s of a
    switch from 9.1% to 5.3% of frames (the data's own transitions: 6.1%), keeping the displacement of segments
    that travel over 1 m (median ratio 0.994-1.008). HumanML3D marks a foot in contact when it moves under
    ~4.5 cm a frame, so on real data the body also moves a little (at most 18 cm over 8.5 s of the test clip).
    Features stay the model's: `recover_from_ric(features)` is the unlocked motion.
    float64 inside; joints in and out float32.
    """

    CONTACT = 0.5

    def __init__(self, skeleton: Skeleton):
        self.toes = [skeleton.foot_left[1], skeleton.foot_right[1]]    # the joints of the toe contact channels
        start = FeatureLayout(skeleton.num_joints).foot_contact.start
        self.channels = [start + 1, start + 3]          # left toe, right toe
        # [offset x, z, whether a frame was seen, its toes' (x, z) twice, their contacts (1.0 or 0.0)] in one row
        # (a crowd gathers its streams' with one operation)
        self._state = np.zeros(9)

    @property
    def offset(self) -> np.ndarray:
        """The body's running (x, z) offset."""
        return self._state[:2]

    @offset.setter
    def offset(self, value) -> None:
        self._state = np.concatenate([np.asarray(value, np.float64).reshape(2), self._state[2:]])

    @property
    def previous(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The last frame's toes (2, 2: (x, z) each) and their contacts (2,) bool; None before the first frame."""
        if not self._state[2]:
            return None
        return self._state[3:7].reshape(2, 2), self._state[7:9] > 0

    @previous.setter
    def previous(self, value: tuple[np.ndarray, np.ndarray] | None) -> None:
        seen = [] if value is None else [np.asarray(value[0], np.float64).reshape(4), np.asarray(value[1], bool)]
        self._state = np.concatenate([self._state[:2], [1.0, *seen[0], *seen[1]] if seen else np.zeros(7)])

    def push(self, joints: np.ndarray, features: np.ndarray) -> np.ndarray:
        """joints (n, J, 3) float32 and their features (n, D) -> the locked joints (n, J, 3) float32."""
        if not len(joints):
            return np.asarray(joints, np.float32)
        return FootLock.push_many([self], np.asarray(joints)[None], np.asarray(features)[None])[0]

    @staticmethod
    def push_many(locks: list["FootLock"], joints: np.ndarray, features: np.ndarray) -> np.ndarray:
        """`push` for many streams at once, the same numbers: joints (B, n, J, 3), features (B, n, D), n >= 1."""
        first = locks[0]
        j = np.asarray(joints, np.float64)
        toe = j[:, :, first.toes][..., [0, 2]]                                   # (B, n, 2 toes, xz)
        contact = np.asarray(features)[:, :, first.channels] > first.CONTACT     # (B, n, 2)
        state = np.stack([k._state for k in locks])
        seen = state[:, 2] > 0                                                  # a stream's first frame: no slide
        prev_toe = np.where(seen[:, None, None], state[:, 3:7].reshape(-1, 2, 2), toe[:, 0])
        prev_contact = seen[:, None] & (state[:, 7:9] > 0)
        slide = np.diff(np.concatenate([prev_toe[:, None], toe], axis=1), axis=1)    # (B, n, 2, 2)
        held = np.concatenate([prev_contact[:, None], contact], axis=1)[:, :-1] & contact   # (B, n, 2)
        count = held.sum(2, keepdims=True)
        shift = np.where(count > 0, (slide * held[..., None]).sum(2) / np.maximum(count, 1), 0.0)   # (B, n, 2)
        # a running subtraction from the carried offset (cumsum is sequential), so chunking changes nothing
        offsets = np.cumsum(np.concatenate([state[:, None, :2], -shift], axis=1), axis=1)[:, 1:]
        B = len(locks)
        for k, row in zip(locks, np.concatenate([offsets[:, -1], np.ones((B, 1)), toe[:, -1].reshape(B, 4),
                                                 contact[:, -1]], axis=1)):
            k._state = row
        j[..., 0] += offsets[..., None, 0]
        j[..., 2] += offsets[..., None, 1]
        return j.astype(np.float32)


class FrameJoints:
    """A stream's features -> its joints, chunk by chunk: the root integrated (RootIntegrator), then planted toes
    held (FootLock). The joints equal those of the whole motion's features, whatever the chunks."""

    def __init__(self, skeleton: Skeleton):
        self.root, self.lock = RootIntegrator(skeleton), FootLock(skeleton)

    def push(self, features: np.ndarray) -> np.ndarray:
        """features (n, D) of the next n frames -> joints (n, J, 3) float32."""
        return self.lock.push(self.root.push(features), features)

    @staticmethod
    def push_many(streams: list["FrameJoints"], features: np.ndarray) -> np.ndarray:
        """`push` for many streams at once (a crowd's), the same numbers: features (B, n, D), n >= 1 ->
        joints (B, n, J, 3) float32."""
        joints = RootIntegrator.push_many([s.root for s in streams], features)
        return FootLock.push_many([s.lock for s in streams], joints, features)

    def next_pose(self) -> np.ndarray:
        """The root pose (x, z, yaw) of the next frame, where the frames so far put it (the lock's offset too)."""
        pose = self.root.next_pose()
        pose[:2] += self.lock.offset
        return pose

    @staticmethod
    def next_poses(streams: list["FrameJoints"]) -> np.ndarray:
        """`next_pose` of many streams at once (a crowd's), the same numbers: (B, 3)."""
        x, z, yaw = _next_pose(*np.stack([s.root._state for s in streams]).T)
        offset = np.stack([s.lock._state[:2] for s in streams])
        return np.stack([x + offset[:, 0], z + offset[:, 1], yaw], axis=1)
