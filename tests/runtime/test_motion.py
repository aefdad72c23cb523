"""Motion files read back by independent readers, the streaming integrator equals recover_from_ric, and the foot lock
holds planted toes in any chunking."""
import json
import os

import bvhio
import numpy as np
import pytest
from PIL import Image

from mogo_runtime.kinematics.features import recover_from_ric
from mogo_runtime.kinematics.frames import FootLock, FrameJoints, RootIntegrator
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.outputs.motion import SAVE_FORMATS, Motion, OutputError, check_output_path


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
        integ = RootIntegrator(HUMANML3D)
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
    integ = RootIntegrator(HUMANML3D)
    got = np.concatenate([integ.push(feats[i:i + 4]) for i in range(0, 60, 4)])
    assert np.abs(got - recover_from_ric(feats, 22)).max() < 1e-9


def test_many_streams_at_once_get_the_joints_each_gets_alone(humanml3d_fixture):
    # a crowd makes its characters' joints in one batch: each must be what its stream alone makes, bit for bit,
    # whatever its state (streams started at different frames, some with a held toe, one not started)
    feats = np.load(humanml3d_fixture / "new_joint_vecs" / "012314.npy")         # (170, 263) float32
    starts = [0, 13, 57, 101, 150]
    alone = [FrameJoints(HUMANML3D) for _ in starts]
    together = [FrameJoints(HUMANML3D) for _ in starts]
    for s, a, t in zip(starts, alone, together):
        if s:
            a.push(feats[:s])
            t.push(feats[:s])
    for step, n in enumerate((1, 4, 3, 4)):
        at = [s + sum((1, 4, 3, 4)[:step]) for s in starts]
        batch = np.stack([feats[i:i + n] for i in at])
        got = FrameJoints.push_many(together, batch)
        for b, (i, a) in enumerate(zip(at, alone)):
            want = a.push(feats[i:i + n])
            assert got[b].dtype == want.dtype and np.array_equal(got[b], want), (step, b)
    for a, t in zip(alone, together):
        assert np.array_equal(a.next_pose(), t.next_pose())
    # a crowd reads its steered characters' next poses at once: the bits each reads alone (numpy scalars)
    assert FrameJoints.next_poses(together).tobytes() == np.stack([a.next_pose() for a in alone]).tobytes()


def test_integrator_rejects_wrong_width():
    with pytest.raises(ValueError, match=r"\(n, 263\)"):
        RootIntegrator(HUMANML3D).push(np.zeros((3, 251)))


TOE_CHANNELS = (260, 262)          # left toe, right toe contact channels of the 263 features
TOES = (10, 11)


def sliding_feet(frames=40, seed=0):
    """Random joints whose body drifts along +x by 1 cm a frame, with random toe contacts."""
    rng = np.random.default_rng(seed)
    joints = rng.normal(scale=0.3, size=(frames, 22, 3)).astype(np.float32)
    joints[..., 0] += 0.01 * np.arange(frames, dtype=np.float32)[:, None]
    feats = rng.normal(size=(frames, 263)).astype(np.float32)
    feats[:, list(TOE_CHANNELS)] = rng.random((frames, 2)) > 0.4
    return joints, feats


def test_foot_lock_holds_a_single_planted_toe_still():
    joints, feats = sliding_feet()
    feats[:, list(TOE_CHANNELS)] = 0.0
    feats[10:20, TOE_CHANNELS[0]] = 1.0                  # only the left toe is planted, from frame 10 to 19
    got = FootLock(HUMANML3D).push(joints, feats)
    toe = got[10:20, TOES[0]][:, [0, 2]]
    assert np.abs(toe - toe[0]).max() < 1e-6, "the held toe moved"
    assert np.abs(np.diff(got[:, TOES[0], [0, 2]], axis=0)).max() > 0.05    # the unheld frames still move
    assert np.array_equal(got[..., 1], joints[..., 1])  # heights are never touched
    shift = got[:, :, [0, 2]] - joints[:, :, [0, 2]]    # one rigid xz shift per frame
    assert np.abs(shift - shift[:, :1]).max() < 1e-6
    assert np.array_equal(got[:11], joints[:11])         # nothing before the first held step


def test_foot_lock_takes_the_mean_slide_of_two_held_toes():
    joints, feats = sliding_feet()
    feats[:, list(TOE_CHANNELS)] = 1.0
    got = FootLock(HUMANML3D).push(joints, feats).astype(np.float64)
    mean_step = np.diff(got[:, list(TOES)][..., [0, 2]], axis=0).mean(1)    # (T - 1, 2): zero when locked
    assert np.abs(mean_step).max() < 1e-6


def test_foot_lock_without_contact_changes_nothing():
    joints, feats = sliding_feet()
    feats[:, list(TOE_CHANNELS)] = 0.0
    assert np.array_equal(FootLock(HUMANML3D).push(joints, feats), joints)


def test_foot_lock_is_the_same_in_any_chunking():
    joints, feats = sliding_feet(frames=97, seed=1)
    want = FootLock(HUMANML3D).push(joints, feats)
    assert not np.array_equal(want, joints)
    for chunk in (1, 4, 5, 96):
        lock = FootLock(HUMANML3D)
        got = np.concatenate([lock.push(joints[i:i + chunk], feats[i:i + chunk]) for i in range(0, 97, chunk)])
        assert np.array_equal(got, want), chunk
    assert FootLock(HUMANML3D).push(joints[:0], feats[:0]).shape == (0, 22, 3)


def grounded_toe_sliding(joints):
    """(frames where a toe below 5 cm moves more than 2.5 cm, metres such toes travel) of a (T, 22, 3) motion."""
    feet = joints[:, list(TOES)].astype(np.float64)
    grounded = (feet[:-1, :, 1] < 0.05) & (feet[1:, :, 1] < 0.05)
    step = np.linalg.norm(np.diff(feet[..., [0, 2]], axis=0), axis=-1)
    return int((grounded & (step > 0.025)).any(-1).sum()), float((grounded * step).sum())


def test_foot_lock_on_real_data_slides_less(clip):
    # HumanML3D marks a foot in contact when it moves under ~4.5 cm a frame, so the lock also takes away slow
    # slides of a foot about to lift: the body moves a little, and grounded toes slide less than before.
    got = FootLock(HUMANML3D).push(clip.joints, clip.features)
    before, after = grounded_toe_sliding(clip.joints), grounded_toe_sliding(got)
    moved = np.linalg.norm(got[:, 0, [0, 2]] - clip.joints[:, 0, [0, 2]], axis=-1).max()
    print(f"\nfoot lock on HumanML3D 012314: sliding frames {before[0]} -> {after[0]}, grounded toe travel "
          f"{before[1]:.2f} -> {after[1]:.2f} m; body shifted at most {moved * 100:.1f} cm over {len(got)} frames")
    assert after[0] <= before[0] and after[1] < before[1] and moved > 0


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
