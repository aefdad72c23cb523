"""mogo_runtime.quaternion: conventions (w first, q*r applies r first) checked against rotation matrices."""
import numpy as np
import pytest

from mogo_runtime.quaternion import (cont6d_to_matrix, cont6d_to_quaternion, euler_to_quaternion, matrix_to_quaternion,
                                     qbetween, qeuler, qfix, qinv, qmul, qnormalize, qrot, quaternion_to_cont6d,
                                     quaternion_to_matrix)

rng = np.random.default_rng(0)


def _rand_q(*shape):
    return qnormalize(rng.normal(size=shape + (4,)))


def test_qrot_matches_matrix_and_about_y():
    q, v = _rand_q(5, 7), rng.normal(size=(5, 7, 3))
    np.testing.assert_allclose(qrot(q, v), (quaternion_to_matrix(q) @ v[..., None])[..., 0], atol=1e-12)
    # a quarter turn about +y takes +z to +x (right-handed, y up)
    q_y = np.array([np.cos(np.pi / 4), 0, np.sin(np.pi / 4), 0])
    np.testing.assert_allclose(qrot(q_y, np.array([0.0, 0, 1])), [1, 0, 0], atol=1e-12)


def test_qmul_applies_right_operand_first_and_qinv_inverts():
    q, r, v = _rand_q(10), _rand_q(10), rng.normal(size=(10, 3))
    np.testing.assert_allclose(qrot(qmul(q, r), v), qrot(q, qrot(r, v)), atol=1e-12)
    np.testing.assert_allclose(qmul(q, qinv(q)), np.tile([1.0, 0, 0, 0], (10, 1)), atol=1e-12)
    # broadcasting: one quaternion against many
    np.testing.assert_allclose(qmul(q[:1], r), qmul(np.repeat(q[:1], 10, 0), r), atol=1e-12)


def test_qbetween_rotates_v0_onto_v1_including_opposite():
    v0, v1 = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    v1[0] = -3 * v0[0]  # antiparallel: HumanML3D would give NaN
    q = qbetween(v0, v1)
    assert np.all(np.isfinite(q)) and np.all(q[1:, 0] >= 0)
    unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(unit(qrot(q, v0)), unit(v1), atol=1e-9)


def test_matrix_quaternion_cont6d_round_trips():
    q = _rand_q(200)
    q = np.where(q[:, :1] < 0, -q, q)
    np.testing.assert_allclose(matrix_to_quaternion(quaternion_to_matrix(q)), q, atol=1e-9)
    m = quaternion_to_matrix(q)
    c = quaternion_to_cont6d(q)
    np.testing.assert_allclose(c, np.concatenate([m[..., :, 0], m[..., :, 1]], -1))  # columns 0 and 1
    np.testing.assert_allclose(cont6d_to_matrix(c), m, atol=1e-12)
    np.testing.assert_allclose(cont6d_to_quaternion(c), q, atol=1e-9)
    # Gram-Schmidt: a perturbed 6D vector still gives a proper rotation
    r = cont6d_to_matrix(c + 0.1 * rng.normal(size=c.shape))
    np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)


@pytest.mark.parametrize("order", ["xyz", "xzy", "yxz", "yzx", "zxy", "zyx"])
def test_euler_round_trip_and_composition(order):
    e = rng.uniform(-1.4, 1.4, size=(100, 3))
    q = euler_to_quaternion(e, order)
    np.testing.assert_allclose(qeuler(q, order), e, atol=1e-9)
    axes = {c: np.eye(3)[i] for i, c in enumerate("xyz")}
    mats = {}
    for c in "xyz":  # R about axis c by its angle, via Rodrigues' formula
        a, k = e[:, "xyz".index(c)], axes[c]
        kx = np.cross(np.eye(3), k)
        mats[c] = np.eye(3) + np.sin(a)[:, None, None] * kx + (1 - np.cos(a))[:, None, None] * (kx @ kx)
    want = mats[order[0]] @ mats[order[1]] @ mats[order[2]]
    np.testing.assert_allclose(quaternion_to_matrix(q), want, atol=1e-12)


def test_qfix_removes_sign_flips():
    q = np.repeat(_rand_q(1, 3), 6, axis=0)  # (6, 3, 4)
    flipped = q.copy()
    flipped[[2, 4], 1] *= -1
    fixed = qfix(flipped)
    assert np.all((fixed[1:] * fixed[:-1]).sum(-1) > 0)
    np.testing.assert_allclose(np.abs(fixed), np.abs(q))


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        qmul(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="permutation"):
        qeuler(_rand_q(2), "xxy")
