"""Stick-figure previews: frame count and timing, a figure that moves, is upright and not mirrored."""
import os
import stat
import time

import numpy as np
import pytest
from PIL import Image

from mogo_runtime.outputs import preview
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.outputs.preview import HEAD, LEFT, RIGHT, SHADOW, render_frames, render_gif, render_grid_gif, render_mp4


def fixture_joints(humanml3d_fixture) -> np.ndarray:
    return np.load(humanml3d_fixture / "new_joints" / "012314.npy")


def rest_pose(T: int = 20, raise_left_arm: bool = True) -> np.ndarray:
    """HumanML3D rest pose standing on the floor, facing +z; optionally the left arm swings up sideways."""
    offsets, parents = HUMANML3D.offsets, HUMANML3D.parents
    pos = np.zeros((T, 22, 3))
    angle = np.linspace(0.0, 2.5, T) if raise_left_arm else np.zeros(T)
    c, s = np.cos(angle), np.sin(angle)
    rot_z = np.zeros((T, 3, 3))
    rot_z[:, 0, 0], rot_z[:, 0, 1], rot_z[:, 1, 0], rot_z[:, 1, 1], rot_z[:, 2, 2] = c, -s, s, c, 1
    for j, p in enumerate(parents):
        if p < 0:
            pos[:, j] = [0.0, 0.93, 0.0]
        elif j in (18, 20):  # left elbow and wrist hang from the rotated left shoulder
            pos[:, j] = pos[:, p] + rot_z @ offsets[j]
        else:
            pos[:, j] = pos[:, p] + offsets[j]
    return pos


def pixels(img: Image.Image, index: int) -> np.ndarray:
    """(N, 2) (row, col) of pixels drawn in palette colour `index`."""
    return np.argwhere(np.asarray(img) == index)


def test_gif_has_one_frame_per_pose_at_the_motion_fps(tmp_path, humanml3d_fixture):
    joints = fixture_joints(humanml3d_fixture)
    path = render_gif(tmp_path / "clip.gif", joints, title="fixture")
    with Image.open(path) as im:
        assert im.size == (320, 320)
        assert im.n_frames == len(joints)
        durations = []
        for t in range(im.n_frames):
            im.seek(t)
            durations.append(im.info["duration"])
        im.seek(60)
        from_file = np.asarray(im.convert("RGB"))
    assert set(durations) == {50}  # 20 fps
    assert np.array_equal(from_file, np.asarray(render_frames(joints, title="fixture")[60].convert("RGB")))
    slow = render_gif(tmp_path / "slow.gif", joints[:10], fps=12.5)
    with Image.open(slow) as im:
        assert im.n_frames == 10 and im.info["duration"] == 80
    assert sorted(os.listdir(tmp_path)) == ["clip.gif", "slow.gif"]  # no temp files left
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    assert path.stat().st_mode == plain.stat().st_mode  # usual permissions, not a temp file's 0600


def test_figure_moves_for_a_moving_clip_and_not_for_a_still_one(humanml3d_fixture):
    moving = render_frames(fixture_joints(humanml3d_fixture))
    figure = lambda img: np.concatenate([pixels(img, LEFT), pixels(img, RIGHT)])
    shift = np.abs(figure(moving[0]).mean(0) - figure(moving[60]).mean(0)).max()
    print(f"figure centroid moved {shift:.1f} px between frames 0 and 60")
    assert shift > 10
    changed = [(np.asarray(a) != np.asarray(b)).sum() for a, b in zip(moving[:-1], moving[1:])]
    assert min(changed) > 0 and np.median(changed) > 200  # the clip ends nearly still, it moves before
    still = render_frames(rest_pose(5, raise_left_arm=False))
    assert np.array_equal(figure(still[0]), figure(still[4]))


def test_person_is_upright_and_not_mirrored():
    """Camera in front of a body facing +z: the head is above the feet, and the person's left side (blue)
    appears on the viewer's right; the raised left arm ends up high on the right of the picture."""
    frames = render_frames(rest_pose(20), size=(200, 200))
    first, last = frames[0], frames[-1]
    head, shadow = pixels(first, HEAD), pixels(first, SHADOW)
    assert head[:, 0].mean() < shadow[:, 0].mean() - 50
    left, right = pixels(first, LEFT), pixels(first, RIGHT)
    assert left[:, 1].mean() > right[:, 1].mean() + 5
    raised = pixels(last, LEFT)
    assert raised[:, 0].min() < head[:, 0].min() + 10   # hand at about head height or above
    assert raised[:, 1].max() > left[:, 1].max() + 10   # and out to the viewer's right


def test_grid_places_motions_side_by_side(tmp_path, humanml3d_fixture):
    joints = fixture_joints(humanml3d_fixture)
    motions = [("walk", joints[:40]), ("stand", rest_pose(25)), ("short", joints[:5])]
    path = render_grid_gif(tmp_path / "grid.gif", motions, size=(96, 96), columns=2)
    with Image.open(path) as im:
        assert im.size == (192, 192)
        assert im.n_frames == 40  # the longest; shorter clips hold their last pose
        assert im.info["duration"] == 50
    with pytest.raises(ValueError, match="at least one"):
        render_grid_gif(tmp_path / "g.gif", [])
    with pytest.raises(ValueError, match=r"motions\[1\] joints must have shape"):
        render_grid_gif(tmp_path / "g.gif", [("a", joints), ("b", joints[:, :5])])
    with pytest.raises(ValueError, match=r"motions\[0\] must be a \(title, joints\) pair"):
        render_grid_gif(tmp_path / "g.gif", [joints])


def test_200_frame_gif_is_fast(tmp_path, humanml3d_fixture):
    joints = fixture_joints(humanml3d_fixture)
    joints = np.concatenate([joints, joints[:30]])
    start = time.perf_counter()
    render_gif(tmp_path / "long.gif", joints, title="two hundred frames")
    seconds = time.perf_counter() - start
    print(f"200-frame 320x320 GIF: {seconds:.2f} s")
    assert seconds < 2.0


def test_mp4_with_a_missing_ffmpeg_raises(tmp_path, monkeypatch):
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(tmp_path / "no-such-ffmpeg"))   # the user's choice, not there
    with pytest.raises(RuntimeError, match="cannot run ffmpeg .*no-such-ffmpeg"):
        render_mp4(tmp_path / "x.mp4", rest_pose(3))
    assert not list(tmp_path.iterdir())


def test_mp4_pipes_raw_frames_to_ffmpeg(tmp_path, monkeypatch):
    """A stand-in ffmpeg that records its arguments and copies stdin to the output path."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "ffmpeg"
    fake.write_text('#!/bin/sh\necho "$@" > "$(dirname "$0")/args"\nfor a; do out=$a; done\ncat > "$out"\n')
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(fake))      # imageio-ffmpeg's way to name another ffmpeg
    path = render_mp4(tmp_path / "out" / "clip.mp4", rest_pose(7), fps=25.0, size=(100, 80))
    assert path.stat().st_size == 7 * 100 * 80 * 3
    args = (bin_dir / "args").read_text().split()
    assert args[args.index("-s") + 1] == "100x80" and args[args.index("-r") + 1] == "25"
    assert os.listdir(path.parent) == ["clip.mp4"]
    fake.write_text("#!/bin/sh\necho boom >&2\nexit 3\n")
    with pytest.raises(RuntimeError, match="exit 3.*boom"):
        render_mp4(tmp_path / "out" / "bad.mp4", rest_pose(3))
    assert os.listdir(path.parent) == ["clip.mp4"]


def test_bad_input_raises_clear_errors(tmp_path):
    good = rest_pose(4)
    with pytest.raises(ValueError, match=r"shape \(T, 22, 3\).*got \(4, 22\)"):
        render_gif(tmp_path / "x.gif", good[..., 0])
    with pytest.raises(ValueError, match=r"got \(0, 22, 3\)"):
        render_gif(tmp_path / "x.gif", good[:0])
    bad = good.copy()
    bad[2, 15, 0] = np.inf
    with pytest.raises(ValueError, match=r"NaN or inf.*frame 2 joint 15 \(head\)"):
        render_gif(tmp_path / "x.gif", bad)
    with pytest.raises(ValueError, match="fps"):
        render_gif(tmp_path / "x.gif", good, fps=-1)
    with pytest.raises(ValueError, match="size"):
        render_gif(tmp_path / "x.gif", good, size=(10, 10))
    assert not (tmp_path / "x.gif").exists()
    assert preview.render_frames(good, size=(64, 64))[0].size == (64, 64)
