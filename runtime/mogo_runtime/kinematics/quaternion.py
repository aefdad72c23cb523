"""Numpy quaternion and rotation helpers (w, x, y, z order), following HumanML3D's common/quaternion.py.

Every function is vectorised over leading dimensions: a quaternion array is (..., 4), a vector array (..., 3), a
rotation matrix (..., 3, 3). Quaternions rotate vectors as q v q^-1. What only feature extraction needs (the
Hamilton product, shortest arcs, 6D rotations) is with it, in mogo_export.data.humanml3d.
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


def check_last(a: np.ndarray, n: int, name: str) -> np.ndarray:
    """`a` as an array of shape (..., n), or a ValueError naming it."""
    a = np.asarray(a)
    if a.shape[-1:] != (n,):
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


def qinv(q: np.ndarray) -> np.ndarray:
    """Conjugate, which is the inverse of a unit quaternion."""
    q = check_last(q, 4, "q")
    return q * np.array([1, -1, -1, -1], dtype=q.dtype if q.dtype.kind == "f" else np.float64)


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4); q and v broadcast against each other."""
    q, v = check_last(q, 4, "q"), check_last(v, 3, "v")
    uv = np.cross(q[..., 1:], v)
    return v + 2 * (q[..., :1] * uv + np.cross(q[..., 1:], uv))


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 3, 3); q need not be unit length (it is normalised implicitly)."""
    q = check_last(q, 4, "q")
    r, i, j, k = np.moveaxis(q, -1, 0)
    two_s = 2.0 / (q * q).sum(-1)
    m = np.stack([
        1 - two_s * (j * j + k * k), two_s * (i * j - k * r), two_s * (i * k + j * r),
        two_s * (i * j + k * r), 1 - two_s * (i * i + k * k), two_s * (j * k - i * r),
        two_s * (i * k - j * r), two_s * (j * k + i * r), 1 - two_s * (i * i + j * j),
    ], axis=-1)
    return m.reshape(q.shape[:-1] + (3, 3))


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
