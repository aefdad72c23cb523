"""mogo_export.data.humanml3d: joints -> features reproduces HumanML3D's released features, and round-trips."""
import numpy as np
import pytest

from mogo_export.data.humanml3d import (canonicalize, extract_features, gaussian_filter1d, qbetween, qmul,
                                        quaternion_to_cont6d)
from mogo_runtime.kinematics.features import FeatureLayout, recover_from_ric, recover_root_rot_pos
from mogo_runtime.kinematics.quaternion import qinv, qrot, quaternion_to_matrix
from mogo_runtime.kinematics.skeleton import HUMANML3D, KIT

LAYOUT = FeatureLayout(22)
ROOT = slice(0, 4)


@pytest.fixture(scope="module")
def clip(humanml3d_fixture):
    feats = np.load(humanml3d_fixture / "new_joint_vecs" / "012314.npy")
    joints = np.load(humanml3d_fixture / "new_joints" / "012314.npy")
    return feats, joints


def _errors(got, want):
    """Max |error| per slice, split into (all but the last 60 frames, the last 60)."""
    out = {}
    for name, s in [("root", ROOT)] + list(LAYOUT.slices().items())[3:]:
        e = np.abs(got[:, s] - want[:, s]).max(axis=-1)
        out[name] = (e[:-60].max(), e[-60:].max())
    return out


def test_extract_matches_dataset_features(clip):
    feats, joints = clip
    got = extract_features(joints)
    assert got.shape == (len(joints) - 1, 263) and got.dtype == np.float32
    n = min(len(got), len(feats))
    err = _errors(got[:n], feats[:n])
    print(f"\njoints {joints.shape} -> features {got.shape}; dataset features {feats.shape}; compared {n} frames")
    for name, (head, tail) in err.items():
        print(f"  {name:13s} max |error| frames 0..{n - 61}: {head:.3g}   last 60: {tail:.3g}")
    for name in ("root", "local_vel", "foot_contact"):
        assert max(err[name]) < 1e-3, name
    for name in ("ric", "rot6d"):
        assert err[name][0] < 1e-4, name
    # The dataset smoothed the facing (sigma 20 frames) over one more frame than these joints hold, so
    # the last frames' facing differs slightly; measured 6.8e-3 (ric) and 1.32e-2 (rot6d, last frame).
    # test_extract_with_the_missing_frame_restored shows that frame is the whole difference.
    assert err["ric"][1] < 1e-2
    assert err["rot6d"][1] < 2e-2


def test_extract_with_the_missing_frame_restored(clip):
    # The dataset's features came from 171 frames of joints, its new_joints hold the first 170. The last
    # feature row's joint velocities give frame 171 back: p[T] = p[T-1] + facing[T-1]^-1 * local_vel[T-1].
    feats, joints = clip
    r_quat, _ = recover_root_rot_pos(feats)
    last_vel = feats[-1, LAYOUT.local_vel].reshape(22, 3)
    full = np.concatenate([joints, (joints[-1] + qrot(qinv(r_quat[-1]), last_vel))[None]])
    got = extract_features(full)
    assert got.shape == feats.shape
    err = {name: np.abs(got[:, s] - feats[:, s]).max() for name, s in LAYOUT.slices().items()}
    print("\nwith frame 171 restored, max |error| on every frame: "
          + ", ".join(f"{k} {v:.2g}" for k, v in err.items()))
    assert max(err.values()) < 1e-4


def _yaw(angle):
    return np.array([np.cos(angle / 2), 0.0, np.sin(angle / 2), 0.0])


def test_round_trip_is_invariant_to_placement(clip):
    _, joints = clip
    # the same clip turned, moved and lifted: extraction puts it back on the floor, at the origin, facing +z
    moved = qrot(_yaw(2.3), joints.astype(np.float64)) + np.array([1.5, 0.4, -2.0])
    back = recover_from_ric(extract_features(moved), 22)
    err = np.abs(back - joints[:-1]).max()
    print(f"\nextract -> recover of the moved clip vs the clip, frames 0..T-2: max |error| {err:.3g} m")
    assert err < 1e-4
    np.testing.assert_allclose(extract_features(moved), extract_features(joints), atol=1e-4)


def test_round_trip_on_kit_skeleton():
    # A made-up KIT clip: rest pose walking a curve while turning, arms swinging, one frame per step.
    t = np.arange(40)
    rest = np.zeros((21, 3))
    for chain in KIT.kinematic_chain:
        for parent, child in zip(chain[:-1], chain[1:]):
            rest[child] = rest[parent] + KIT.offsets[child]
    pose = np.repeat(rest[None], len(t), 0)
    for wrist in (7, 10):
        pose[:, wrist, 2] += 0.15 * np.sin(0.3 * t)
    yaw = np.stack([_yaw(a) for a in 0.05 * t])
    joints = qrot(yaw[:, None], pose) + np.stack([0.03 * t, 1.0 + 0 * t, 0.5 * np.sin(0.1 * t)], -1)[:, None]
    feats = extract_features(joints, skeleton=KIT, feet_thre=0.002)
    assert feats.shape == (39, 251)
    back = recover_from_ric(feats, 21)
    np.testing.assert_allclose(back, canonicalize(joints, KIT)[:-1], atol=1e-5)


def test_gaussian_filter_matches_scipy_definition():
    x = np.random.default_rng(0).normal(size=(50, 3))
    sigma = 4.0
    radius = int(4.0 * sigma + 0.5)
    w = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    w /= w.sum()
    # mode='nearest': indices past either end read the end sample
    want = np.stack([sum(w[k + radius] * x[min(max(i + k, 0), 49)] for k in range(-radius, radius + 1))
                     for i in range(50)])
    np.testing.assert_allclose(gaussian_filter1d(x, sigma), want, atol=1e-12)
    np.testing.assert_allclose(gaussian_filter1d(x.T, sigma, axis=1), want.T, atol=1e-12)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match=r"\(T, 22, 3\)"):
        extract_features(np.zeros((10, 21, 3)))
    with pytest.raises(ValueError, match="at least 2 frames"):
        extract_features(np.zeros((1, 22, 3)))
    bad = np.zeros((5, 22, 3))
    bad[2, 3, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        extract_features(bad)


# The quaternion helpers of extraction: conventions (w first, q*r applies r first) against rotation matrices.

_rng = np.random.default_rng(0)


def _rand_q(*shape):
    q = _rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def test_qmul_applies_right_operand_first_and_qinv_inverts():
    q, r, v = _rand_q(10), _rand_q(10), _rng.normal(size=(10, 3))
    np.testing.assert_allclose(qrot(qmul(q, r), v), qrot(q, qrot(r, v)), atol=1e-12)
    np.testing.assert_allclose(qmul(q, qinv(q)), np.tile([1.0, 0, 0, 0], (10, 1)), atol=1e-12)
    # broadcasting: one quaternion against many
    np.testing.assert_allclose(qmul(q[:1], r), qmul(np.repeat(q[:1], 10, 0), r), atol=1e-12)


def test_qbetween_rotates_v0_onto_v1_including_opposite():
    v0, v1 = _rng.normal(size=(50, 3)), _rng.normal(size=(50, 3))
    v1[0] = -3 * v0[0]  # antiparallel: HumanML3D would give NaN
    q = qbetween(v0, v1)
    assert np.all(np.isfinite(q)) and np.all(q[1:, 0] >= 0)
    unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(unit(qrot(q, v0)), unit(v1), atol=1e-9)


def test_cont6d_is_the_matrix_first_columns():
    q = _rand_q(200)
    m = quaternion_to_matrix(q)
    np.testing.assert_allclose(quaternion_to_cont6d(q), np.concatenate([m[..., :, 0], m[..., :, 1]], -1))


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        qmul(np.zeros(3), np.zeros(4))
