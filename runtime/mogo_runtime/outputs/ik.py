"""Inverse kinematics: joint positions -> joint rotations that reproduce them, for any `Skeleton`.

Every joint's rest rotation is identity, so its rest bone vector is in world axes (y up, the body faces +z): the
skeleton's rest direction with the bone length measured on the clip (median over frames), so a clip on a skeleton of
another size is still reproduced. Where a joint has several children (pelvis, spine3) their layout is a fact of the
clip too (HumanML3D's hips are 69 degrees apart seen from the pelvis, not the 180 of the rest directions): the rigid
shape that best fits all frames (generalised Procrustes), turned to lie as close as it can to the rest directions.
Such a joint gets the best-fit (Kabsch) rotation of its children's offsets onto the observed bones; a joint with one
child gets the smallest rotation, in its parent's frame, that swings its rest bone onto the observed one (no twist),
except near the one direction where that swing is undefined (bone opposite its rest direction, e.g. an arm straight
up): there the twist is carried over from the previous frame and then relaxed back to zero, so nothing flips. Leaves
keep their parent's rotation. The BVH writer and the retargeter both start from these rotations.
"""
from __future__ import annotations

import numpy as np

from ..kinematics.quaternion import unit
from ..kinematics.skeleton import HUMANML3D, Skeleton

_TWIST_RELAX_S = 0.25  # time constant (seconds) for a carried-over twist to relax back to the swing


def rest_offsets(joints, skeleton: Skeleton = HUMANML3D) -> np.ndarray:
    """(J, 3) rest bone vectors (metres) fitted to a clip `joints` (T, J, 3); see the module docstring."""
    pos = skeleton.check_joints(joints, count=True)
    raw = np.asarray(skeleton.raw_offsets, dtype=np.float64)
    offsets = np.zeros((skeleton.num_joints, 3))
    for j, p in enumerate(skeleton.parents):
        if p < 0:
            continue
        norm = np.linalg.norm(raw[j])
        if norm == 0:
            raise ValueError(f"skeleton {skeleton.name!r}: joint {skeleton.joint_names[j]!r} has a zero rest direction")
        length = np.median(np.linalg.norm(pos[:, j] - pos[:, p], axis=-1))
        if length < 1e-6:
            raise ValueError(f"bone {skeleton.joint_names[p]!r} -> {skeleton.joint_names[j]!r} has zero length "
                             f"in the clip (median over frames); cannot build a skeleton")
        offsets[j] = raw[j] / norm * length
    for j, ch in enumerate(skeleton.children):
        if len(ch) < 2:
            continue
        bones = pos[:, ch] - pos[:, None, j]                            # (T, k, 3)
        shape = offsets[ch]
        for _ in range(3):  # exact after one pass on rigid data; more passes for noisy clips
            rot = kabsch(shape[None], bones)                           # (T, 3, 3): rot @ shape ~ bones
            shape = np.einsum("tji,tkj->ki", rot, bones) / len(bones)   # mean of rot^T @ bones
        # Turn the measured shape to lie as near the skeleton's rest directions as it can.
        offsets[ch] = shape @ kabsch(shape[None], offsets[None, ch])[0].T
    return offsets


def local_rotations(pos: np.ndarray, skeleton: Skeleton, offsets: np.ndarray, fps: float) -> np.ndarray:
    T, J, _ = pos.shape
    children = skeleton.children
    glob = np.zeros((T, J, 3, 3))
    local = np.zeros((T, J, 3, 3))
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))
    relax = float(np.exp(-1.0 / (fps * _TWIST_RELAX_S)))
    for j in skeleton.depth_first():
        p = skeleton.parents[j]
        parent = glob[:, p] if p >= 0 else eye
        ch = children[j]
        bones = pos[:, ch] - pos[:, None, j]                            # (T, k, 3)
        if len(ch) >= 2 and not _collinear(offsets[ch]):
            glob[:, j] = kabsch(offsets[None, ch], bones)
            local[:, j] = np.swapaxes(parent, -1, -2) @ glob[:, j]
        elif ch:  # one child, or children on one line: the first one sets the rotation
            d = np.einsum("tji,tj->ti", parent, bones[:, 0])            # the bone in the parent's frame
            local[:, j] = _swing_with_continuous_twist(offsets[ch[0]], d, relax)
            glob[:, j] = parent @ local[:, j]
        else:
            local[:, j] = np.eye(3)
            glob[:, j] = parent
    return local


def _swing_with_continuous_twist(u: np.ndarray, d: np.ndarray, relax: float) -> np.ndarray:
    """(T, 3, 3) rotations taking direction u to each d[t]: the pure swing, with a twist about u only
    where the swing jumps (d near -u); that twist follows the bone over time and decays by `relax`/frame."""
    u = u / np.linalg.norm(u)
    d = unit(d, fallback=u)
    swing = min_rotation(np.broadcast_to(u, d.shape), d)              # (T, 3, 3)
    # How much twist (about u) carrying the previous frame's rotation along the bone's motion adds
    # on top of the swing: Tw(delta_t) = swing_t^T @ M_t @ swing_{t-1}, M_t the min rotation d_{t-1} -> d_t.
    carry = min_rotation(d[:-1], d[1:])
    tw = np.swapaxes(swing[1:], -1, -2) @ carry @ swing[:-1]           # (T-1, 3, 3), each fixes u
    w = _perpendicular(u)
    tw_w = tw @ w
    delta = np.arctan2(np.cross(w, tw_w) @ u, tw_w @ w)
    near_flip = (d @ u) < -0.7                                          # swing is ill-conditioned there
    theta = np.zeros(len(d))
    for t in range(1, len(d)):
        theta[t] = theta[t - 1] + delta[t - 1]
        theta[t] = (theta[t] + np.pi) % (2 * np.pi) - np.pi
        if not near_flip[t]:
            theta[t] *= relax
    return swing @ axis_angle(u, theta)


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotations R (..., 3, 3) minimising sum_k |R @ src[..., k, :] - dst[..., k, :]|^2."""
    h = np.swapaxes(src, -1, -2) @ dst                                  # sum_k src_k dst_k^T
    u, _, vt = np.linalg.svd(h)
    v, ut = np.swapaxes(vt, -1, -2), np.swapaxes(u, -1, -2)
    flip = np.sign(np.linalg.det(v @ ut))
    flip = np.where(flip == 0, 1.0, flip)
    v = v.copy()
    v[..., :, 2] *= flip[..., None]
    return v @ ut


def min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, 3, 3) smallest rotations taking unit vectors a[n] to b[n] (any half-turn axis if b = -a)."""
    axis = np.cross(a, b)
    sin = np.linalg.norm(axis, axis=-1)
    cos = np.einsum("ni,ni->n", a, b)
    axis = np.where(sin[:, None] > 1e-12, axis / np.maximum(sin, 1e-300)[:, None], _perpendicular(a))
    return axis_angle(axis, np.arctan2(sin, cos))


def axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: (N, 3, 3) rotations by angle[n] about unit axis[n] (axis (N, 3), or (3,) for all)."""
    x, y, z = np.broadcast_to(axis, (len(angle), 3)).T
    k = np.zeros((len(angle), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -z, y, -x
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = z, -y, x
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def _perpendicular(u: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3) perpendicular to u (..., 3)."""
    helper = np.where(np.abs(u[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    return unit(np.cross(u, helper), fallback=np.array([0.0, 0.0, 1.0]))


def _collinear(vectors: np.ndarray) -> bool:
    s = np.linalg.svd(vectors, compute_uv=False)
    return len(s) < 2 or s[1] < 1e-6 * max(s[0], 1e-12)
