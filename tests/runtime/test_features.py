"""mogo_runtime.features: layout, features -> joints on the real HumanML3D clip, normalisation."""
import numpy as np
import pytest

from mogo_runtime.kinematics.features import FeatureLayout, recover_from_ric
from mogo_runtime.kinematics.skeleton import HUMANML3D, KIT


@pytest.fixture(scope="module")
def clip(humanml3d_fixture):
    feats = np.load(humanml3d_fixture / "new_joint_vecs" / "012314.npy")
    joints = np.load(humanml3d_fixture / "new_joints" / "012314.npy")
    return feats, joints


def test_layout_matches_humanml3d_and_kit():
    h, k = FeatureLayout.for_skeleton(HUMANML3D), FeatureLayout.for_skeleton(KIT)
    assert (h.dim, k.dim) == (263, 251)
    assert (h.root_rot_vel, h.root_lin_vel, h.root_y) == (slice(0, 1), slice(1, 3), slice(3, 4))
    assert (h.ric, h.rot6d, h.local_vel, h.foot_contact) == (slice(4, 67), slice(67, 193), slice(193, 259),
                                                             slice(259, 263))
    stops = [s.stop for s in k.slices().values()]
    starts = [s.start for s in k.slices().values()]
    assert starts == [0] + stops[:-1] and stops[-1] == 251  # contiguous, covers the vector
    assert h.to_dict()["slices"]["foot_contact"] == [259, 263] and k.to_dict()["dim"] == 251


def test_recover_from_ric_reproduces_dataset_joints(clip):
    feats, joints = clip
    t = min(len(feats), len(joints))
    got = recover_from_ric(feats, 22)
    err = np.abs(got[:t] - joints[:t]).max()
    print(f"\nrecover_from_ric: features {feats.shape}, joints {joints.shape}; max |error| {err:.3g} m over {t} frames")
    assert got.shape == (len(feats), 22, 3) and got.dtype == np.float32
    assert err < 1e-4


def test_recover_from_ric_batched_and_float64(clip):
    feats, joints = clip
    batch = np.stack([feats, feats[::-1]]).astype(np.float64)  # (2, T, 263)
    got = recover_from_ric(batch, 22)
    assert got.shape == (2, len(feats), 22, 3) and got.dtype == np.float64
    np.testing.assert_allclose(got[0], joints, atol=1e-4)
    np.testing.assert_allclose(got[1], recover_from_ric(feats[::-1], 22), atol=1e-5)


def test_skeleton_bone_lengths_are_the_fixture_clips(clip):
    """HUMANML3D.bone_lengths were measured on this clip: every frame has them (HumanML3D retargets all clips)."""
    _, joints = clip
    lengths = np.linalg.norm(joints[:, 1:] - joints[:, list(HUMANML3D.parents[1:])], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(HUMANML3D.bone_lengths[1:], lengths.shape), atol=2e-6)


def test_recover_rejects_mismatched_dim(clip):
    feats, _ = clip
    with pytest.raises(ValueError, match="251"):
        recover_from_ric(feats, 21)
    with pytest.raises(ValueError, match="263"):
        recover_from_ric(feats[0], 22)  # a single frame, no time axis


