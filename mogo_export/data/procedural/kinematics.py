"""Forward kinematics on the HUMANML3D skeleton: the standing posture the joint angles are measured from,
local rotations from a Pose's angles, joint positions and global rotations, the feet's heel and toe
contact points (and those of the other body parts an action may rest on the floor), and a two-bone leg IK
solver.

Everything here is geometry relative to the root at the origin; where the body stands on the floor is
grounding.py's job.
"""
from __future__ import annotations

import numpy as np

from mogo_runtime.kinematics.skeleton import HUMANML3D

from .pose import CONTACTS


def _rot(axis: int, deg: np.ndarray) -> np.ndarray:
    """(...,) degrees -> (..., 3, 3) rotation about x (0), y (1) or z (2)."""
    r = np.radians(deg)
    c, s = np.cos(r), np.sin(r)
    m = np.zeros(np.shape(deg) + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[..., axis, axis] = 1.0
    m[..., i, i] = c
    m[..., j, j] = c
    m[..., i, j] = -s
    m[..., j, i] = s
    return m


def _foot_pitches(skeleton=HUMANML3D, left_deg: float = 20.0) -> dict[int, float]:
    """Standing pitch of each ankle -> toe bone (degrees down). The measured legs differ by ~1 cm, so the
    shorter leg's foot points down a little more and both toes touch the floor when standing straight."""
    drop = {}
    for ankle, toe in (skeleton.foot_left, skeleton.foot_right):
        knee = skeleton.parents[ankle]
        drop[ankle] = skeleton.bone_lengths[knee] + skeleton.bone_lengths[ankle]  # hip -> ankle, straight
    (la, lt), (ra, rt) = skeleton.foot_left, skeleton.foot_right
    toe_y = drop[la] + skeleton.bone_lengths[lt] * np.sin(np.radians(left_deg))
    return {la: left_deg, ra: float(np.degrees(np.arcsin((toe_y - drop[ra]) / skeleton.bone_lengths[rt])))}


FOOT_PITCH = _foot_pitches()


def _posture() -> np.ndarray:
    """Constant rotations turning the raw-offset rest pose (arms hanging from 13 cm below the collar ends,
    head in front of the neck, feet flat) into a standing person's posture, matched by eye to the
    HumanML3D fixture clip: shoulders up and out from the collar ends (about 18 cm beside the spine and
    12 cm below the neck), head above and slightly in front of the neck, toes below the ankles."""
    p = np.tile(np.eye(3), (HUMANML3D.num_joints, 1, 1))
    for collar, shoulder, sign in ((13, 16, 1.0), (14, 17, -1.0)):
        p[collar] = _rot(2, sign * 160.0)  # collar -> shoulder bone points up and out, like the trapezius
        p[shoulder] = _rot(2, -sign * 160.0)  # undo it for the arm, which hangs down again
    p[12] = _rot(0, -57.0)                  # neck -> head bone points up and slightly forward
    for ankle, deg in FOOT_PITCH.items():
        p[ankle] = _rot(0, deg)             # ankle -> toe bone points forward and down
    p.setflags(write=False)  # shared by every clip: a stray in-place edit would change all that follow
    return p


POSTURE = _posture()


def _heel(ankle: int, toe: int, skeleton=HUMANML3D) -> np.ndarray:
    """A virtual heel 4.5 cm behind the ankle, level with the toe when standing (in the ankle's frame)."""
    down = skeleton.bone_lengths[toe] * np.sin(np.radians(FOOT_PITCH[ankle]))
    heel = _rot(0, -FOOT_PITCH[ankle]) @ np.array([0.0, -down, -0.045])
    heel.setflags(write=False)
    return heel


HEELS = {ankle: _heel(ankle, toe) for ankle, toe in (HUMANML3D.foot_left, HUMANML3D.foot_right)}


def local_rotations(angles: np.ndarray) -> np.ndarray:
    """(T, J, 3) degrees (pose.Pose convention) -> (T, J, 3, 3) local joint rotations."""
    x, y, z = angles[..., 0], angles[..., 1], angles[..., 2]
    rot = POSTURE @ _rot(2, z) @ _rot(0, x) @ _rot(1, y)
    rot[:, 0] = _rot(1, y[:, 0]) @ _rot(0, x[:, 0]) @ _rot(2, -z[:, 0])  # root: yaw, pitch, roll
    return rot


def forward_kinematics(angles: np.ndarray, skeleton=HUMANML3D) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions (T, J, 3) with the root at the origin, and global rotations (T, J, 3, 3).

    Joint j's rotation turns the bones to its children: pos[c] = pos[j] + G[j] @ offset[c]. Bone lengths
    are the skeleton's by construction.
    """
    local = local_rotations(angles)
    offsets = skeleton.offsets
    T, J = angles.shape[:2]
    glob = np.empty((T, J, 3, 3))
    pos = np.zeros((T, J, 3))
    for j, parent in enumerate(skeleton.parents):  # parents come before children in HumanML3D order
        if parent < 0:
            glob[:, j] = local[:, j]
            continue
        glob[:, j] = glob[:, parent] @ local[:, j]
        pos[:, j] = pos[:, parent] + glob[:, parent] @ offsets[j]
    return pos, glob


def contact_points(pos: np.ndarray, glob: np.ndarray, skeleton=HUMANML3D) -> np.ndarray:
    """(T, 4, 3): left heel, left toe, right heel, right toe (the heels are virtual, below the ankles)."""
    pts = []
    for ankle, toe in (skeleton.foot_left, skeleton.foot_right):
        pts.append(pos[:, ankle] + glob[:, ankle] @ HEELS[ankle])
        pts.append(pos[:, toe])
    return np.stack(pts, axis=1)


OFF_FLOOR = 1e3  # m: where a body part that may not rest on the floor is put as a contact (never the lowest)


def body_points(pos: np.ndarray, resting: np.ndarray) -> np.ndarray:
    """(T, K, 3): the surface point below each body part of pose.CONTACTS (the joint lowered by its
    thickness) where `resting` (T, K) allows it on the floor, and OFF_FLOOR above the root elsewhere."""
    joints = [j for j, _ in CONTACTS.values()]
    pts = pos[:, joints].copy()
    pts[..., 1] -= np.array([r for _, r in CONTACTS.values()])
    pts[..., 1] = np.where(resting, pts[..., 1], OFF_FLOOR)
    return pts


def two_bone_ik(hip: np.ndarray, knee: np.ndarray, target: np.ndarray, l1: float, l2: float,
                forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """New (knee, ankle) (N, 3) reaching `target` from `hip` with bone lengths l1, l2, bending in the plane
    of the old knee, toward `forward` (the foot's direction) when the leg is near straight, so a knee
    never flips backwards. Out-of-reach targets are approached as far as the straight leg allows."""
    axis = target - hip
    d = np.linalg.norm(axis, axis=-1, keepdims=True)
    u = axis / np.maximum(d, 1e-9)
    d = np.clip(d, abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    pole = (knee - hip) + 0.05 * forward / np.maximum(np.linalg.norm(forward, axis=-1, keepdims=True), 1e-9)
    pole = pole - (pole * u).sum(-1, keepdims=True) * u
    pole = pole / np.maximum(np.linalg.norm(pole, axis=-1, keepdims=True), 1e-9)
    a = (l1 * l1 - l2 * l2 + d * d) / (2 * d)
    r = np.sqrt(np.maximum(l1 * l1 - a * a, 0.0))
    # a near-straight leg whose old knee sat behind the hip-ankle line (a foot pointing down at take-off gives no
    # forward) bends the other way: toward where the foot points over the floor
    ahead = (pole * forward * np.array([1.0, 0.0, 1.0])).sum(-1, keepdims=True)
    pole = np.where((ahead < 0) & (r < 0.25 * l1), -pole, pole)
    return hip + a * u + r * pole, hip + d * u
