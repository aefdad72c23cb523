"""Numpy quaternion and rotation helpers (w, x, y, z order), following HumanML3D's common/quaternion.py.

Every function is vectorised over leading dimensions: a quaternion array is (..., 4), a vector array
(..., 3), a rotation matrix (..., 3, 3) and a 6D rotation (..., 6). Quaternions rotate vectors as
q v q^-1, and `qmul(q, r)` applies r first, then q (the Hamilton product, as in HumanML3D).
"""
from __future__ import annotations

import numpy as np

_EPS = 1e-12


def unit(v: np.ndarray, fallback: np.ndarray | None = None) -> np.ndarray:
    """Vectors (..., n) scaled to length 1: the one normaliser of the runtime. A vector of length <= 1e-12 becomes
    `fallback` where one is given (a direction that cannot be known), else stays near zero."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if fallback is None:
        return v / np.maximum(n, _EPS)
    return np.where(n > _EPS, v / np.maximum(n, 1e-300), fallback)


def _check_last(a: np.ndarray, n: int, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.shape[-1:] != (n,):
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


def qinv(q: np.ndarray) -> np.ndarray:
    """Conjugate, which is the inverse of a unit quaternion."""
    q = _check_last(q, 4, "q")
    return q * np.array([1, -1, -1, -1], dtype=q.dtype if q.dtype.kind == "f" else np.float64)


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
    uv = np.cross(q[..., 1:], v)
    return v + 2 * (q[..., :1] * uv + np.cross(q[..., 1:], uv))


def qbetween(v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """The shortest-arc unit quaternion that rotates direction v0 onto direction v1.

    Same formula as HumanML3D (w = |v0||v1| + v0.v1, xyz = v0 x v1, then normalise), so w >= 0.
    Where v0 and v1 are opposite that quaternion is zero; HumanML3D then returns NaN, here it is a
    half turn about an axis perpendicular to v0 instead.
    """
    v0, v1 = np.broadcast_arrays(_check_last(v0, 3, "v0"), _check_last(v1, 3, "v1"))
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


def quaternion_to_cont6d(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 6): the first two columns of the rotation matrix, column 0 then column 1."""
    m = quaternion_to_matrix(q)
    return np.concatenate([m[..., 0], m[..., 1]], axis=-1)


def matrix_to_quaternion(m: np.ndarray, continuous_axis: int | None = None) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z), w >= 0; with `continuous_axis`
    (the time axis of the leading dimensions) each quaternion's sign is instead chosen nearest the previous one,
    so that interpolating between neighbours turns the short way (q and -q are the same rotation)."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"m must have shape (..., 3, 3), got {m.shape}")
    # Shepperd's method: from the largest of w, x, y, z, whichever is best conditioned.
    t = np.stack([1 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2], 1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                  1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2], 1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]], -1)
    cand = np.stack([
        np.stack([t[..., 0], m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1),
        np.stack([m[..., 2, 1] - m[..., 1, 2], t[..., 1], m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
        np.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0], t[..., 2], m[..., 1, 2] + m[..., 2, 1]], -1),
        np.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1], t[..., 3]], -1),
    ], -2)                                                                      # (..., 4 candidates, 4)
    best = np.argmax(t, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., :1] < 0, -q, q)
    if continuous_axis is not None:
        q = np.moveaxis(q, continuous_axis, 0).copy()
        for i in range(1, len(q)):
            flip = (q[i] * q[i - 1]).sum(-1) < 0
            q[i][flip] *= -1
        q = np.moveaxis(q, 0, continuous_axis)
    return q
