"""Joint positions -> HumanML3D motion features: a numpy port of HumanML3D's `process_file`.

Faithful to HumanML3D's motion_representation.py and common/skeleton.py, quirks included (marked
"HumanML3D quirk" below), so features extracted here match the released dataset. The inverse,
`recover_from_ric`, is in mogo_runtime.features.

HumanML3D first retargets every clip onto one skeleton (`uniform_skeleton`: inverse kinematics, then
forward kinematics with the reference clip's bone lengths and a leg-length scaled root path). That
step is not done here: inputs must already be on the skeleton given (e.g. joints recovered from
HumanML3D features, or clips generated on `HUMANML3D`'s bone lengths).
"""
from __future__ import annotations

import numpy as np

from mogo_runtime.kinematics.features import FeatureLayout
from mogo_runtime.kinematics.quaternion import check_last, qinv, qrot, quaternion_to_matrix
from mogo_runtime.kinematics.skeleton import HUMANML3D, Skeleton

_Y_UP = np.array([0.0, 1.0, 0.0])
_Z_FORWARD = np.array([0.0, 0.0, 1.0])
_EPS = 1e-12


# Quaternion helpers of the joints -> features direction (the runtime's kinematics.quaternion has the others).

def qmul(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton product q * r (rotation r, then q); q and r broadcast against each other."""
    q, r = check_last(q, 4, "q"), check_last(r, 4, "r")
    w0, x0, y0, z0 = np.moveaxis(q, -1, 0)
    w1, x1, y1, z1 = np.moveaxis(r, -1, 0)
    return np.stack([
        w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
        w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
        w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
        w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1,
    ], axis=-1)


def qbetween(v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """The shortest-arc unit quaternion that rotates direction v0 onto direction v1.

    Same formula as HumanML3D (w = |v0||v1| + v0.v1, xyz = v0 x v1, then normalise), so w >= 0.
    Where v0 and v1 are opposite that quaternion is zero; HumanML3D then returns NaN, here it is a
    half turn about an axis perpendicular to v0 instead.
    """
    v0, v1 = np.broadcast_arrays(check_last(v0, 3, "v0"), check_last(v1, 3, "v1"))
    w = np.sqrt((v0 ** 2).sum(-1, keepdims=True) * (v1 ** 2).sum(-1, keepdims=True)) + (v0 * v1).sum(-1, keepdims=True)
    q = np.concatenate([w, np.cross(v0, v1)], axis=-1)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    opposite = norm[..., 0] < _EPS * np.maximum(np.linalg.norm(v0, axis=-1) * np.linalg.norm(v1, axis=-1), _EPS)
    if np.any(opposite):
        a = v0[opposite]
        # any axis perpendicular to v0: cross with the world axis it is least aligned with
        axis = np.cross(a, np.eye(3)[np.argmin(np.abs(a), axis=-1)])
        q = q.astype(np.result_type(q.dtype, np.float32), copy=True)
        q[opposite] = np.concatenate([np.zeros(axis.shape[:-1] + (1,)), axis], axis=-1)
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / norm


def quaternion_to_cont6d(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 6): the first two columns of the rotation matrix, column 0 then column 1."""
    m = quaternion_to_matrix(q)
    return np.concatenate([m[..., 0], m[..., 1]], axis=-1)


def gaussian_filter1d(x: np.ndarray, sigma: float, axis: int = 0, truncate: float = 4.0) -> np.ndarray:
    """scipy.ndimage.gaussian_filter1d(x, sigma, axis, mode='nearest', truncate) in numpy."""
    radius = int(truncate * float(sigma) + 0.5)
    t = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * (t / sigma) ** 2)
    w /= w.sum()
    x = np.moveaxis(np.asarray(x, dtype=np.float64), axis, 0)
    padded = np.concatenate([np.repeat(x[:1], radius, 0), x, np.repeat(x[-1:], radius, 0)])  # mode='nearest'
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1, axis=0)  # (T, ..., 2r+1)
    return np.moveaxis(windows @ w, 0, axis)


def _forward_from_across(across: np.ndarray) -> np.ndarray:
    across = across / np.linalg.norm(across, axis=-1, keepdims=True)
    return np.cross(_Y_UP, across)  # (..., 3) in the xz plane, not yet unit length


def root_facing(joints: np.ndarray, skeleton: Skeleton, smooth_forward: bool = True) -> np.ndarray:
    """(T, 4) root quaternions that turn each frame's (smoothed) facing direction onto +z.

    HumanML3D quirk: its inverse_kinematics_np unpacks the face joints as (l_hip, r_hip, ...) while
    callers pass (r_hip, l_hip, ...), so the hip vector points left and the shoulder vector right;
    their sum still points right on real bodies (shoulders are wider than hips), and the released
    features were made this way.
    """
    a, b, sdr_r, sdr_l = skeleton.face_joints
    across = (joints[:, b] - joints[:, a]) + (joints[:, sdr_r] - joints[:, sdr_l])
    forward = _forward_from_across(across)
    if smooth_forward:
        forward = gaussian_filter1d(forward, 20, axis=0)
    forward = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    return qbetween(forward, np.broadcast_to(_Z_FORWARD, forward.shape))


def inverse_kinematics(joints: np.ndarray, skeleton: Skeleton, smooth_forward: bool = True) -> np.ndarray:
    """(T, J, 3) positions -> (T, J, 4) local joint quaternions, as HumanML3D's `inverse_kinematics_np`.

    Joint 0 holds the root facing; joint k holds the rotation taking its rest bone direction
    (skeleton.raw_offsets[k]) onto its bone, relative to the chain's previous global rotation.
    """
    root_quat = root_facing(joints, skeleton, smooth_forward)  # (T, 4)
    # HumanML3D quirk: frame 0's facing is taken as identity (the line is commented out in today's
    # common/skeleton.py, but the released features were made with it: their first rotation velocity
    # jumps to frame 1's full smoothed facing angle), so recover_from_ric's "frame 0 faces +z" holds.
    root_quat[0] = [1.0, 0.0, 0.0, 0.0]
    quat = np.zeros(joints.shape[:-1] + (4,))
    quat[:, 0] = root_quat
    for chain in skeleton.kinematic_chain:
        r = root_quat
        for parent, child in zip(chain[:-1], chain[1:]):
            bone = joints[:, child] - joints[:, parent]
            bone = bone / np.linalg.norm(bone, axis=-1, keepdims=True)
            rot_u_v = qbetween(np.broadcast_to(skeleton.raw_offsets[child], bone.shape), bone)  # (T, 4)
            r_loc = qmul(qinv(r), rot_u_v)
            quat[:, child] = r_loc
            r = qmul(r, r_loc)
    return quat


def canonicalize(joints: np.ndarray, skeleton: Skeleton = HUMANML3D) -> np.ndarray:
    """Put the lowest joint of the clip on y=0, the root at frame 0 on x=z=0, and frame 0 facing +z."""
    pos = np.array(joints, dtype=np.float64)
    pos[:, :, 1] -= pos[:, :, 1].min()  # HumanML3D takes the minimum over all joints, not just the feet
    pos -= pos[0, 0] * np.array([1.0, 0.0, 1.0])

    r_hip, l_hip, sdr_r, sdr_l = skeleton.face_joints
    across = (pos[0, r_hip] - pos[0, l_hip]) + (pos[0, sdr_r] - pos[0, sdr_l])
    forward = _forward_from_across(across)
    forward = forward / np.linalg.norm(forward)
    return qrot(qbetween(forward, _Z_FORWARD), pos)


def foot_contacts(pos: np.ndarray, skeleton: Skeleton, thres: float) -> np.ndarray:
    """(T, J, 3) -> (T-1, 4) contacts [l_ankle, l_toe, r_ankle, r_toe]: 1 where a joint moves < sqrt(thres).

    HumanML3D also defines height factors [3.0, 2.0] but their height test is commented out, so only
    the squared per-frame displacement is compared with `thres`.
    """
    feet = list(skeleton.foot_left) + list(skeleton.foot_right)
    disp2 = ((pos[1:, feet] - pos[:-1, feet]) ** 2).sum(-1)  # (T-1, 4)
    return (disp2 < thres).astype(np.float32)


def extract_features(joints: np.ndarray, skeleton: Skeleton = HUMANML3D, feet_thre: float = 0.002) -> np.ndarray:
    """(T, J, 3) joint positions (metres, y up) -> (T-1, D) float32 HumanML3D features."""
    joints = np.asarray(joints)
    j = skeleton.num_joints
    if joints.ndim != 3 or joints.shape[1:] != (j, 3):
        raise ValueError(f"joints must be (T, {j}, 3) for skeleton {skeleton.name!r}, got {joints.shape}")
    if joints.shape[0] < 2:
        raise ValueError(f"joints need at least 2 frames to give velocities, got {joints.shape[0]}")
    if not np.all(np.isfinite(joints)):
        raise ValueError("joints contain non-finite values")

    pos = canonicalize(joints, skeleton)  # (T, J, 3) global positions
    contacts = foot_contacts(pos, skeleton, feet_thre)

    quat = inverse_kinematics(pos, skeleton, smooth_forward=True)  # (T, J, 4)
    cont6d = quaternion_to_cont6d(quat)  # (T, J, 6)
    r_rot = quat[:, 0]  # (T, 4)

    # HumanML3D quirk: root velocity is rotated by the *next* frame's facing, joint velocities by the current one
    root_vel = qrot(r_rot[1:], pos[1:, 0] - pos[:-1, 0])  # (T-1, 3)
    r_velocity = qmul(r_rot[1:], qinv(r_rot[:-1]))  # (T-1, 4) rotation about y
    # HumanML3D takes arcsin of y alone; where the facing quaternion changes sign between frames (the smoothed
    # heading crossing 180 degrees from frame 0) that flips the sign of the turn and recover_from_ric then
    # misses the joints by up to 0.4 m. q and -q are the same rotation, so take the one with w >= 0 first.
    sign = np.where(r_velocity[:, :1] < 0, -1.0, 1.0)
    rot_vel = np.arcsin(np.clip(sign * r_velocity[:, 2:3], -1.0, 1.0))  # half-angle, as recover_root_rot_pos expects

    ric = pos.copy()
    ric[..., [0, 2]] -= pos[:, :1, [0, 2]]
    ric = qrot(r_rot[:, None], ric)  # (T, J, 3) in the facing frame
    local_vel = qrot(r_rot[:-1, None], pos[1:] - pos[:-1])  # (T-1, J, 3)

    t = len(pos) - 1
    data = np.concatenate([
        rot_vel, root_vel[:, [0, 2]], ric[:-1, 0, 1:2],
        ric[:-1, 1:].reshape(t, -1),
        cont6d[:-1, 1:].reshape(t, -1),
        local_vel.reshape(t, -1),
        contacts,
    ], axis=-1).astype(np.float32)
    assert data.shape[1] == FeatureLayout(j).dim, data.shape
    return data
