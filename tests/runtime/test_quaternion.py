"""mogo_runtime.kinematics.quaternion: conventions (w first) checked against rotation matrices."""
import numpy as np
import pytest

from mogo_runtime.kinematics.quaternion import matrix_to_quaternion, qinv, qrot, quaternion_to_matrix

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
    np.testing.assert_allclose(qrot(qinv(q), qrot(q, v)), v, atol=1e-12)


def test_matrix_is_a_rotation_and_back():
    q = _rand_q(200)
    m = quaternion_to_matrix(q)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-12)
    np.testing.assert_allclose(matrix_to_quaternion(m), np.where(q[:, :1] < 0, -q, q), atol=1e-12)


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        qrot(np.zeros(3), np.zeros(3))
