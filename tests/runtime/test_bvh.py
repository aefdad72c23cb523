"""BVH export: files read back by the independent `bvhio` library reproduce the input joint positions."""
import os

import bvhio
import numpy as np
import pytest

from mogo_runtime.kinematics.skeleton import HUMANML3D, KIT
from mogo_runtime.outputs.bvh import joints_to_bvh_text, rest_offsets, write_bvh

TOL_M = 1e-3  # 1 mm on every joint and frame


def bvhio_positions(path, skeleton, units) -> np.ndarray:
    """World joint positions (T, J, 3) in metres, by bvhio's own forward kinematics."""
    root = bvhio.readAsHierarchy(str(path))
    layout = root.layout()
    index = {name: i for i, name in enumerate(skeleton.joint_names)}
    assert sorted(j.Name for j, _, _ in layout) == sorted(skeleton.joint_names)
    frames = root.getKeyframeRange()[1] + 1
    out = np.zeros((frames, skeleton.num_joints, 3))
    for f in range(frames):
        root.loadPose(f)
        for joint, _, _ in layout:
            v = joint.PositionWorld
            out[f, index[joint.Name]] = (v.x, v.y, v.z)
    return out / {"cm": 100.0, "m": 1.0}[units]


def roundtrip_error(tmp_path, joints, skeleton=HUMANML3D, units="cm", name="clip") -> float:
    path = write_bvh(tmp_path / f"{name}_{units}.bvh", joints, skeleton, fps=20.0, units=units)
    back = bvhio_positions(path, skeleton, units)
    assert back.shape == joints.shape
    return float(np.abs(back - joints).max())


def euler_channels(text: str) -> np.ndarray:
    """(T, J, 3) rotation channels (degrees) from BVH text written by us (root has 3 position channels)."""
    motion = text.split("Frame Time:")[1].splitlines()[1:]
    rows = np.array([[float(v) for v in line.split()] for line in motion if line.strip()])
    return rows[:, 3:].reshape(len(rows), -1, 3)


# ---------------------------------------------------------------------------------------------------
# synthetic motions by our own tiny forward kinematics

def _rot(axis_angle: np.ndarray) -> np.ndarray:
    """(..., 3) axis-angle -> (..., 3, 3) by Rodrigues."""
    angle = np.linalg.norm(axis_angle, axis=-1, keepdims=True)
    axis = axis_angle / np.maximum(angle, 1e-12)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*x.shape, 3, 3)
    s, c = np.sin(angle)[..., None], np.cos(angle)[..., None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def forward_kinematics(local: np.ndarray, root_pos: np.ndarray, offsets: np.ndarray, parents) -> np.ndarray:
    T, J = local.shape[:2]
    glob = np.zeros((T, J, 3, 3))
    pos = np.zeros((T, J, 3))
    for j, p in enumerate(parents):  # parents come before children in both skeletons
        if p < 0:
            glob[:, j], pos[:, j] = local[:, j], root_pos
        else:
            glob[:, j] = glob[:, p] @ local[:, j]
            pos[:, j] = pos[:, p] + glob[:, p] @ offsets[j]
    return pos


def synthetic_motion(seed: int, skeleton=HUMANML3D, T: int = 120, max_angle_deg: float = 150.0,
                     root_turns: float = 2.0, scale: float = 1.0) -> np.ndarray:
    """Smooth random local rotations (up to `max_angle_deg` about random, drifting axes), a root that
    spins `root_turns` full turns about y while tilting, and a wandering root translation."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, T)[:, None, None]
    J = skeleton.num_joints
    freq = rng.uniform(0.3, 2.0, (1, J, 3))
    phase = rng.uniform(0, 2 * np.pi, (1, J, 3))
    amp = np.radians(max_angle_deg) * rng.uniform(0.4, 1.0, (1, J, 1)) / np.sqrt(3)
    aa = amp * np.sin(2 * np.pi * freq * t + phase)                   # (T, J, 3) axis-angle
    local = _rot(aa)
    yaw = _rot(np.array([0.0, 1.0, 0.0]) * (2 * np.pi * root_turns * t[:, 0]))
    tilt = _rot(np.array([1.0, 0.0, 0.3]) * np.radians(40) * np.sin(2 * np.pi * t[:, 0]))
    local[:, 0] = yaw @ tilt @ local[:, 0]
    root_pos = np.concatenate([np.sin(3 * t[:, 0]), 0.9 + 0.1 * np.cos(5 * t[:, 0]), 2 * t[:, 0]], -1)
    return forward_kinematics(local, root_pos, skeleton.offsets * scale, skeleton.parents)


# ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("units", ["cm", "m"])
def test_fixture_clip_roundtrips_through_bvhio(tmp_path, humanml3d_fixture, units):
    joints = np.load(humanml3d_fixture / "new_joints" / "012314.npy")
    err = roundtrip_error(tmp_path, joints.astype(np.float64), units=units)
    print(f"fixture 012314 ({len(joints)} frames, {units}): max joint error {err * 1000:.4f} mm")
    assert err < TOL_M


@pytest.mark.parametrize("seed,max_angle,turns,scale", [
    (0, 60.0, 0.5, 1.0),
    (1, 150.0, 2.0, 1.0),    # large rotations, root spinning two full turns
    (2, 175.0, -3.0, 1.3),   # near half-turns everywhere, taller skeleton, spinning the other way
])
def test_synthetic_motions_roundtrip(tmp_path, seed, max_angle, turns, scale):
    joints = synthetic_motion(seed, max_angle_deg=max_angle, root_turns=turns, scale=scale)
    for units in ("cm", "m"):
        err = roundtrip_error(tmp_path, joints, units=units, name=f"syn{seed}")
        print(f"synthetic seed {seed} (max {max_angle} deg, {turns} turns, x{scale}, {units}): "
              f"max joint error {err * 1000:.4f} mm")
        assert err < TOL_M


def test_kit_skeleton_roundtrips(tmp_path):
    joints = synthetic_motion(3, skeleton=KIT, max_angle_deg=120.0, root_turns=1.0)
    err = roundtrip_error(tmp_path, joints, skeleton=KIT, units="cm")
    print(f"synthetic KIT: max joint error {err * 1000:.4f} mm")
    assert err < TOL_M


def test_bone_lengths_are_measured_from_the_clip():
    joints = synthetic_motion(4, scale=1.25)
    offsets = rest_offsets(joints)
    lengths = np.linalg.norm(offsets, axis=-1)
    np.testing.assert_allclose(lengths[1:], HUMANML3D.bone_lengths[1:] * 1.25, rtol=1e-6)
    # Single-child bones keep the skeleton's rest direction.
    np.testing.assert_allclose(offsets[4] / lengths[4], HUMANML3D.raw_offsets[4], atol=1e-9)


def test_euler_angles_have_no_flips(humanml3d_fixture):
    joints = np.load(humanml3d_fixture / "new_joints" / "012314.npy")
    for name, clip in (("fixture", joints), ("synthetic", synthetic_motion(1, T=200, root_turns=2.0))):
        euler = euler_channels(joints_to_bvh_text(clip))
        jump = np.abs(np.diff(euler, axis=0)).max()
        print(f"{name}: largest frame-to-frame Euler change {jump:.2f} deg")
        assert jump < 90.0  # a branch flip or a wrap would be ~180 or 360 degrees


def test_arm_swinging_through_straight_up_stays_continuous(tmp_path):
    """The elbow bone passes exactly opposite its rest direction (arm straight up), where the plain swing
    from rest is undefined: the rotation must not flip there."""
    T, J = 100, HUMANML3D.num_joints
    local = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
    sweep = np.radians(np.linspace(0.0, 240.0, T))   # down -> sideways -> straight up -> over the head
    local[:, 16] = _rot(np.array([0.0, 0.0, 1.0]) * sweep[:, None])          # left shoulder about z
    local[:, 17] = _rot(np.array([1.0, 0.0, 0.0]) * -sweep[:, None] * 0.75)  # right arm forward and up
    joints = forward_kinematics(local, np.array([0.0, 0.9, 0.0]), HUMANML3D.offsets, HUMANML3D.parents)
    euler = euler_channels(joints_to_bvh_text(joints))
    jump = np.abs(np.diff(euler, axis=0)).max()
    print(f"arm overhead: largest Euler change {jump:.2f} deg per frame (input moves 2.4 deg per frame)")
    assert jump < 10.0
    assert roundtrip_error(tmp_path, joints) < TOL_M


def test_gimbal_lock_lying_flat_and_spinning(tmp_path):
    """Root pitched exactly 90 degrees (lying face down) while turning: the root's Euler order is at gimbal
    lock in every frame, where only heading + roll is defined; the file must still reproduce the pose."""
    T = 60
    local = np.broadcast_to(np.eye(3), (T, HUMANML3D.num_joints, 3, 3)).copy()
    spin = _rot(np.array([0.0, 1.0, 0.0]) * np.linspace(0.0, 3.0, T)[:, None])
    local[:, 0] = spin @ _rot(np.array([np.pi / 2, 0.0, 0.0]))
    local[:, 4] = _rot(np.array([1.0, 0.0, 0.0]) * np.linspace(0.0, 1.5, T)[:, None])  # bending a knee
    joints = forward_kinematics(local, np.array([0.0, 0.2, 0.0]), HUMANML3D.offsets, HUMANML3D.parents)
    euler = euler_channels(joints_to_bvh_text(joints))
    np.testing.assert_allclose(euler[:, 0, 1], 90.0, atol=1e-4)     # pitch
    assert np.abs(np.diff(euler, axis=0)).max() < 5.0               # input turns 2.9 deg per frame
    assert roundtrip_error(tmp_path, joints) < TOL_M


def test_root_spin_is_unwrapped_not_wrapped():
    joints = synthetic_motion(5, max_angle_deg=10.0, root_turns=3.0)
    text = joints_to_bvh_text(joints)
    assert "CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation" in text
    heading = euler_channels(text)[:, 0, 0]
    # three turns about y: the heading must travel ~1080 degrees, not wrap at +-180
    assert np.ptp(heading) > 900.0


def test_file_layout_and_atomic_write(tmp_path):
    joints = synthetic_motion(6, T=10)
    path = tmp_path / "out" / "m.bvh"
    path.parent.mkdir()
    path.write_text("old")
    write_bvh(path, joints, fps=30.0)
    text = path.read_text()
    assert text.startswith("HIERARCHY\nROOT pelvis\n")
    assert "Frames: 10\nFrame Time: 0.03333333\n" in text
    assert text.count("End Site") == 5  # head, two wrists, two feet
    assert text.count("CHANNELS 3 Zrotation Yrotation Xrotation") == 21
    assert os.listdir(path.parent) == ["m.bvh"]  # no temp files left behind
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    assert path.stat().st_mode == plain.stat().st_mode  # usual permissions, not a temp file's 0600


def test_bad_input_raises_clear_errors(tmp_path):
    good = synthetic_motion(7, T=5)
    with pytest.raises(ValueError, match=r"shape \(T, 22, 3\).*got \(5, 21, 3\)"):
        joints_to_bvh_text(good[:, :21])
    with pytest.raises(ValueError, match=r"got \(22, 3\)"):
        joints_to_bvh_text(good[0])
    bad = good.copy()
    bad[3, 7, 1] = np.nan
    with pytest.raises(ValueError, match="NaN.*frame 3 joint 7 \\(left_ankle\\)"):
        write_bvh(tmp_path / "x.bvh", bad)
    assert not (tmp_path / "x.bvh").exists()
    with pytest.raises(ValueError, match="units"):
        joints_to_bvh_text(good, units="mm")
    with pytest.raises(ValueError, match="fps"):
        joints_to_bvh_text(good, fps=0)
    squashed = good.copy()
    squashed[:, 4] = squashed[:, 1]  # knee on the hip
    with pytest.raises(ValueError, match="left_hip.*left_knee.*zero length"):
        joints_to_bvh_text(squashed)
