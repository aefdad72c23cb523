"""mogo_runtime.quaternion: conventions (w first, q*r applies r first) checked against rotation matrices."""
import numpy as np
import pytest

from mogo_runtime.kinematics.quaternion import qbetween, qinv, qmul, qrot, quaternion_to_cont6d, quaternion_to_matrix

rng = np.random.default_rng(0)


def _rand_q(*shape):
    q = rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


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


def test_matrix_is_a_rotation_and_cont6d_its_first_columns():
    q = _rand_q(200)
    m = quaternion_to_matrix(q)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-12)
    c = quaternion_to_cont6d(q)
    np.testing.assert_allclose(c, np.concatenate([m[..., :, 0], m[..., :, 1]], -1))  # columns 0 and 1


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        qmul(np.zeros(3), np.zeros(4))
