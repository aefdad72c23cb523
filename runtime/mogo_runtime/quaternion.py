"""Numpy quaternion and rotation helpers (w, x, y, z order), following HumanML3D's common/quaternion.py.

Every function is vectorised over leading dimensions: a quaternion array is (..., 4), a vector array
(..., 3), a rotation matrix (..., 3, 3) and a 6D rotation (..., 6). Quaternions rotate vectors as
q v q^-1, and `qmul(q, r)` applies r first, then q (the Hamilton product, as in HumanML3D).
Euler angles are in radians; `order="zxy"` means R = Rz @ Rx @ Ry (BVH's channel order "Z X Y").
"""
from __future__ import annotations

import numpy as np

_EPS = 1e-12


def _check_last(a: np.ndarray, n: int, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.shape[-1:] != (n,):
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


def qinv(q: np.ndarray) -> np.ndarray:
    """Conjugate, which is the inverse of a unit quaternion."""
    q = _check_last(q, 4, "q")
    return q * np.array([1, -1, -1, -1], dtype=q.dtype if q.dtype.kind == "f" else np.float64)


def qnormalize(q: np.ndarray) -> np.ndarray:
    q = _check_last(q, 4, "q")
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def qmul(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton product q * r (rotation r, then q); q and r broadcast against each other."""
    q, r = _check_last(q, 4, "q"), _check_last(r, 4, "r")
    w0, x0, y0, z0 = np.moveaxis(q, -1, 0)
    w1, x1, y1, z1 = np.moveaxis(r, -1, 0)
    return np.stack([
        w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
        w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
        w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
        w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1,
    ], axis=-1)


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4); q and v broadcast against each other."""
    q, v = _check_last(q, 4, "q"), _check_last(v, 3, "v")
    qvec = q[..., 1:]
    uv = np.cross(qvec, v)
    uuv = np.cross(qvec, uv)
    return v + 2 * (q[..., :1] * uv + uuv)


def qbetween(v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """The shortest-arc unit quaternion that rotates direction v0 onto direction v1.

    Same formula as HumanML3D (w = |v0||v1| + v0.v1, xyz = v0 x v1, then normalise), so w >= 0.
    Where v0 and v1 are opposite that quaternion is zero; HumanML3D then returns NaN, here it is a
    half turn about an axis perpendicular to v0 instead.
    """
    v0, v1 = _check_last(v0, 3, "v0"), _check_last(v1, 3, "v1")
    v0, v1 = np.broadcast_arrays(v0, v1)
    xyz = np.cross(v0, v1)
    w = np.sqrt((v0 ** 2).sum(-1, keepdims=True) * (v1 ** 2).sum(-1, keepdims=True)) + (v0 * v1).sum(-1, keepdims=True)
    q = np.concatenate([w, xyz], axis=-1)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    opposite = norm[..., 0] < _EPS * np.maximum(np.linalg.norm(v0, axis=-1) * np.linalg.norm(v1, axis=-1), _EPS)
    if np.any(opposite):
        a = v0[opposite]
        # any axis perpendicular to v0: cross with the world axis it is least aligned with
        helper = np.eye(3)[np.argmin(np.abs(a), axis=-1)]
        axis = np.cross(a, helper)
        q = q.astype(np.result_type(q.dtype, np.float32), copy=True)
        q[opposite] = np.concatenate([np.zeros(axis.shape[:-1] + (1,)), axis], axis=-1)
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / norm


def qfix(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 (time) so consecutive quaternions have a non-negative dot product."""
    q = _check_last(q, 4, "q")
    dots = (q[1:] * q[:-1]).sum(-1)
    flip = (np.cumsum(dots < 0, axis=0) % 2).astype(bool)
    out = q.copy()
    out[1:][flip] *= -1
    return out


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 3, 3); q need not be unit length (it is normalised implicitly)."""
    q = _check_last(q, 4, "q")
    r, i, j, k = np.moveaxis(q, -1, 0)
    two_s = 2.0 / (q * q).sum(-1)
    m = np.stack([
        1 - two_s * (j * j + k * k), two_s * (i * j - k * r), two_s * (i * k + j * r),
        two_s * (i * j + k * r), 1 - two_s * (i * i + k * k), two_s * (j * k - i * r),
        two_s * (i * k - j * r), two_s * (j * k + i * r), 1 - two_s * (i * i + j * j),
    ], axis=-1)
    return m.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quaternion(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions with w >= 0."""
    m = np.asarray(m)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"m must have shape (..., 3, 3), got {m.shape}")
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    # 4*w^2, 4*x^2, 4*y^2, 4*z^2; build from the largest for numerical stability
    sq = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    best = np.argmax(sq, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(sq, best[..., None], -1)[..., 0], _EPS))  # 2*|component|
    d21, d02, d10 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    s21, s02, s10 = m[..., 2, 1] + m[..., 1, 2], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1]
    cands = np.stack([
        np.stack([s * s, d21, d02, d10], -1),
        np.stack([d21, s * s, s10, s02], -1),
        np.stack([d02, s10, s * s, s21], -1),
        np.stack([d10, s02, s21, s * s], -1),
    ], -2) / (2 * s[..., None, None])
    q = np.take_along_axis(cands, best[..., None, None], -2)[..., 0, :]
    q = np.where(q[..., :1] < 0, -q, q)
    return qnormalize(q)


def quaternion_to_cont6d(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 6): the first two columns of the rotation matrix, column 0 then column 1."""
    m = quaternion_to_matrix(q)
    return np.concatenate([m[..., 0], m[..., 1]], axis=-1)


def cont6d_to_matrix(c: np.ndarray) -> np.ndarray:
    """(..., 6) -> (..., 3, 3) by Gram-Schmidt, as HumanML3D: x = c[:3] normalised, z = x cross c[3:], y = z cross x."""
    c = _check_last(c, 6, "cont6d")
    x = c[..., 0:3] / np.linalg.norm(c[..., 0:3], axis=-1, keepdims=True)
    z = np.cross(x, c[..., 3:6])
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def cont6d_to_quaternion(c: np.ndarray) -> np.ndarray:
    return matrix_to_quaternion(cont6d_to_matrix(c))


def _axis_quat(angle: np.ndarray, axis: int) -> np.ndarray:
    q = np.zeros(np.shape(angle) + (4,))
    q[..., 0] = np.cos(angle / 2)
    q[..., 1 + axis] = np.sin(angle / 2)
    return q


def euler_to_quaternion(e: np.ndarray, order: str = "xyz") -> np.ndarray:
    """(..., 3) x/y/z angles in radians -> (..., 4), composed in `order`.

    e[..., 0], e[..., 1], e[..., 2] are always the x, y, z angles; order="zxy" gives q = qz * qx * qy,
    i.e. R = Rz @ Rx @ Ry.
    """
    e = _check_last(e, 3, "euler")
    _check_order(order)
    q = None
    for axis_name in order:
        a = "xyz".index(axis_name)
        qa = _axis_quat(e[..., a], a)
        q = qa if q is None else qmul(q, qa)
    return q


def qeuler(q: np.ndarray, order: str = "xyz") -> np.ndarray:
    """Unit quaternions (..., 4) -> (..., 3) x/y/z angles in radians, the inverse of `euler_to_quaternion`."""
    _check_order(order)
    m = quaternion_to_matrix(q)
    # R = A(a0) B(a1) C(a2) for axes i, j, k = order; the middle angle comes from R[i, k]
    i, j, k = ("xyz".index(c) for c in order)
    sign = 1.0 if (j - i) % 3 == 1 else -1.0  # even permutation (xyz, yzx, zxy) or odd
    mid = np.arcsin(np.clip(sign * m[..., i, k], -1.0, 1.0))
    first = np.arctan2(-sign * m[..., j, k], m[..., k, k])
    last = np.arctan2(-sign * m[..., i, j], m[..., i, i])
    out = np.empty(m.shape[:-2] + (3,), dtype=m.dtype)
    out[..., i], out[..., j], out[..., k] = first, mid, last
    return out


def _check_order(order: str) -> None:
    if sorted(order) != ["x", "y", "z"]:
        raise ValueError(f"euler order must be a permutation of 'xyz', got {order!r}")
