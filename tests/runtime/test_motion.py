"""Motion files read back by independent readers, and the streaming integrator equals recover_from_ric."""
import json
import os

import bvhio
import numpy as np
import pytest
from PIL import Image

from mogo_runtime.features import recover_from_ric
from mogo_runtime.motion import SAVE_FORMATS, Motion, OutputError, RootIntegrator, check_output_path
from mogo_runtime.skeleton import HUMANML3D


@pytest.fixture(scope="module")
def clip(humanml3d_fixture):
    """The real HumanML3D clip as a Motion (features, joints by recover_from_ric)."""
    feats = np.load(humanml3d_fixture / "new_joint_vecs" / "012314.npy").astype(np.float32)
    joints = recover_from_ric(feats, HUMANML3D.num_joints)
    tokens = np.zeros((len(feats) // 4, 2), np.int64)
    return Motion(text="a person walks", features=feats, joints=joints, fps=20.0, tokens=tokens,
                  skeleton=HUMANML3D, seed=3)


def test_integrator_equals_recover_from_ric_in_any_chunking(humanml3d_fixture):
    feats = np.load(humanml3d_fixture / "new_joint_vecs" / "012314.npy")        # (170, 263) float32
    want = recover_from_ric(feats.astype(np.float64), HUMANML3D.num_joints)
    assert np.ptp(want[:, 0, 0]) > 0.5 or np.ptp(want[:, 0, 2]) > 0.5           # the root really travels
    for chunk in (1, 4, 7):
        integ = RootIntegrator(HUMANML3D.num_joints)
        got = np.concatenate([integ.push(feats[i:i + chunk].astype(np.float64))
                              for i in range(0, len(feats), chunk)])
        assert got.shape == want.shape
        assert np.abs(got - want).max() < 1e-6, chunk


def test_integrator_follows_a_turning_root():
    # Constant yaw rate and forward speed: the root walks a circle; recover_from_ric is the reference.
    rng = np.random.default_rng(0)
    feats = rng.normal(scale=0.05, size=(60, 263))
    feats[:, 0] = 0.05
    feats[:, 2] = 0.04
    integ = RootIntegrator(22)
    got = np.concatenate([integ.push(feats[i:i + 4]) for i in range(0, 60, 4)])
    assert np.abs(got - recover_from_ric(feats, 22)).max() < 1e-9


def test_integrator_rejects_wrong_width():
    with pytest.raises(ValueError, match=r"\(n, 263\)"):
        RootIntegrator(22).push(np.zeros((3, 251)))


def test_seconds_and_json_readback(clip, tmp_path):
    assert clip.seconds == pytest.approx(170 / 20.0)
    path = clip.save(tmp_path / "walk.json")
    data = json.loads(path.read_text())
    assert data["fps"] == 20.0 and data["text"] == "a person walks" and data["seed"] == 3
    assert data["skeleton"]["joint_names"] == list(HUMANML3D.joint_names)
    assert data["skeleton"]["parents"] == list(HUMANML3D.parents)
    frames = np.array(data["frames"])
    assert frames.shape == (170, 22, 3) and data["num_frames"] == 170
    assert np.abs(frames - clip.joints).max() <= 0.5e-4 + 1e-7                 # rounded to 0.1 mm


def test_npy_readback(clip, tmp_path):
    back = np.load(clip.save(tmp_path / "walk.npy"))
    assert back.dtype == np.float32 and np.array_equal(back, clip.joints)


def test_bvh_reads_back_in_bvhio(clip, tmp_path):
    path = clip.save(tmp_path / "sub" / "walk.bvh")                            # missing folders are made
    root = bvhio.readAsHierarchy(str(path))
    assert root.getKeyframeRange()[1] + 1 == 170
    index = {name: i for i, name in enumerate(HUMANML3D.joint_names)}
    worst = 0.0
    for f in (0, 85, 169):
        root.loadPose(f)
        for joint, _, _ in root.layout():
            p = joint.PositionWorld
            got = np.array([p.x, p.y, p.z]) / 100.0                                 # centimetres in the file
            worst = max(worst, float(np.abs(got - clip.joints[f, index[joint.Name]]).max()))
    assert worst < 1e-3


def test_gif_has_one_frame_per_motion_frame(clip, tmp_path):
    short = Motion(clip.text, clip.features[:12], clip.joints[:12], clip.fps, clip.tokens[:3], HUMANML3D, 0)
    path = short.save(tmp_path / "walk.GIF")                                   # extension case is ignored
    with Image.open(path) as im:
        assert im.format == "GIF" and im.n_frames == 12


def test_unknown_extension_lists_the_supported_ones(clip, tmp_path):
    with pytest.raises(ValueError) as e:
        clip.save(tmp_path / "walk.fbx")
    for ext in SAVE_FORMATS:
        assert ext in str(e.value)
    assert not list(tmp_path.iterdir())


def test_unwritable_places_are_clear_errors(clip, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="cannot create its folder"):
        clip.save(blocker / "walk.npy")
    (tmp_path / "dir.json").mkdir()
    with pytest.raises(OutputError, match="is a folder"):
        check_output_path(tmp_path / "dir.json")
    if os.geteuid() != 0:   # root ignores permission bits
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(OutputError, match="not writable"):
            clip.save(locked / "walk.npy")


def test_failed_write_leaves_no_file_and_keeps_the_old_one(clip, tmp_path):
    target = tmp_path / "walk.bvh"
    target.write_text("old")
    bad = Motion(clip.text, clip.features[:4], np.full((4, 22, 3), np.nan, np.float32), 20.0, clip.tokens[:1],
                 HUMANML3D, 0)
    with pytest.raises(ValueError, match="NaN"):
        bad.save(target)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.bvh"]           # no temp file left behind


def test_mp4_is_written_with_the_wheels_ffmpeg(clip, tmp_path, monkeypatch):
    import imageio_ffmpeg

    monkeypatch.setenv("PATH", str(tmp_path))                             # no system ffmpeg to fall back on
    monkeypatch.delenv("IMAGEIO_FFMPEG_EXE", raising=False)
    short = Motion(clip.text, clip.features[:8], clip.joints[:8], clip.fps, clip.tokens[:2], HUMANML3D, 0)
    out = short.save(tmp_path / "walk.mp4")
    assert out.read_bytes()[4:8] == b"ftyp"
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(out))
    print(f"mp4: {frames} frames, {seconds:.2f} s")
    assert frames == 8 and seconds == pytest.approx(8 / clip.fps, abs=0.06)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.mp4"]       # no temp file left behind


def test_files_get_ordinary_permissions_and_no_temp_files_remain(clip, tmp_path):
    old = os.umask(0o022)
    try:
        for ext in (".npy", ".json"):
            path = clip.save(tmp_path / f"walk{ext}")
            assert path.stat().st_mode & 0o777 == 0o644, ext               # readable by a game running as another user
    finally:
        os.umask(old)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.json", "walk.npy"]
