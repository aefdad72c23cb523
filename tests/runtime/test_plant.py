"""Planted feet (control/plant.py): a toe on the floor stays where it touched down while the steering moves the body,
the leg reaches it with its bone lengths kept, a foot out of reach slides only as far as it must, a lifted foot goes
back to the motion's own path, and a stream gets the same joints whatever its chunks."""
import numpy as np

from mogo_runtime.control.plant import PLANT_HEIGHT, REACH, FootPlant, legs_of
from mogo_runtime.kinematics.skeleton import HUMANML3D, KIT

LEGS = legs_of(HUMANML3D)
LEFT_HIP, LEFT_KNEE, LEFT_ANKLE, LEFT_TOE = LEGS[0]


def test_a_leg_runs_from_hip_to_toe_on_both_skeletons():
    assert LEGS == ((1, 4, 7, 10), (2, 5, 8, 11))
    assert legs_of(KIT) == ((16, 17, 18, 19, 20), (11, 12, 13, 14, 15))


def standing(frames: int, rng) -> np.ndarray:
    """A person standing (joints (frames, 22, 3) float32), both toes on the floor, a little noise on the upper body."""
    offsets = np.zeros((22, 3))
    for j, p in enumerate(HUMANML3D.parents):
        if p >= 0:
            offsets[j] = HUMANML3D_OFFSETS.get(j, (0.0, 0.1, 0.0))
    pose = np.zeros((22, 3))
    for j in HUMANML3D.depth_first():
        p = HUMANML3D.parents[j]
        pose[j] = offsets[j] + (pose[p] if p >= 0 else np.array([0.0, 0.90, 0.0]))
    out = np.repeat(pose[None], frames, 0)
    out[:, 12:] += rng.normal(0, 0.01, (frames, 10, 3))
    return out.astype(np.float32)


# hips 10 cm to the side and a little down, thigh and shin 0.40 m with the knees bent forward (the ankle 0.76 m
# below the hip: 0.23 m of slack), the foot forward on the floor
HUMANML3D_OFFSETS = {1: (0.1, -0.05, 0.0), 2: (-0.1, -0.05, 0.0), 4: (0.0, -0.38, 0.12), 5: (0.0, -0.38, 0.12),
                     7: (0.0, -0.38, -0.12), 8: (0.0, -0.38, -0.12), 10: (0.0, -0.06, 0.12), 11: (0.0, -0.06, 0.12)}


def bone(joints, a, b):
    return np.linalg.norm(joints[:, a] - joints[:, b], axis=-1)


def test_a_planted_toe_stays_while_the_body_moves_and_the_leg_keeps_its_length():
    rng = np.random.default_rng(0)
    joints = standing(20, rng)
    assert (joints[:, LEFT_TOE, 1] < PLANT_HEIGHT).all()
    moved = joints.copy()
    moved[..., 0] += 0.01 * np.arange(20)[:, None]         # the body shifted 1 cm a frame, as the warp does
    out = FootPlant(LEGS).apply(moved, True)
    toes = out[:, [LEFT_TOE, LEGS[1][3]]][..., [0, 2]]
    np.testing.assert_allclose(toes, np.repeat(toes[:1], 20, 0), atol=1e-6)     # planted
    np.testing.assert_array_equal(out[:, 0], moved[:, 0])                        # the body goes where it was moved
    np.testing.assert_array_equal(out[:, 12:], moved[:, 12:])
    for a, b in ((LEFT_HIP, LEFT_KNEE), (LEFT_KNEE, LEFT_ANKLE)):
        np.testing.assert_allclose(bone(out, a, b), bone(moved, a, b), atol=1e-5)
    # a knee bent the way it was (forward, +z here), not flipped
    assert (out[:, LEFT_KNEE, 2] - out[:, LEFT_HIP, 2] > 0).all()


def test_a_foot_out_of_reach_slides_only_as_far_as_the_leg_cannot_stretch():
    joints = standing(40, np.random.default_rng(1))
    moved = joints.copy()
    moved[..., 0] += 0.05 * np.arange(40)[:, None]         # 2 m in 2 s: no leg reaches that far
    out = FootPlant(LEGS).apply(moved, True)
    reach = np.linalg.norm(out[:, LEFT_ANKLE] - out[:, LEFT_HIP], axis=-1)
    legs = bone(moved, LEFT_HIP, LEFT_KNEE) + bone(moved, LEFT_KNEE, LEFT_ANKLE)
    assert (reach <= REACH * legs + 1e-5).all()
    step = np.linalg.norm(np.diff(out[:, LEFT_TOE, [0, 2]], axis=0), axis=-1)
    assert step[:3].max() < 1e-6 and step.max() <= 0.05 + 1e-6 and step[-10:].min() > 0.04   # held, then slides


def test_a_lifted_foot_goes_back_to_the_motion_s_path_and_unmoved_frames_are_untouched():
    joints = standing(30, np.random.default_rng(2))
    moved = joints.copy()
    moved[:10, :, 0] += 0.02 * np.arange(10)[:, None]
    moved[10:, :, 0] += 0.18
    moved[12:, [LEFT_ANKLE, LEFT_TOE], 1] += 0.1           # the left foot lifts at frame 12
    plant = FootPlant(LEGS)
    out = plant.apply(moved, True)
    offset = out[:, LEFT_TOE, 0] - moved[:, LEFT_TOE, 0]
    assert abs(offset[11]) > 0.1 and abs(offset[-1]) < 1e-3 and (np.abs(np.diff(offset[12:])) > 0).all()
    # a stream never steered: its frames as they are, the same array
    fresh = FootPlant(LEGS)
    assert fresh.apply(joints, False) is joints


def test_chunks_give_the_same_joints_and_the_state_restores():
    rng = np.random.default_rng(3)
    joints = standing(48, rng)
    moved = joints + np.stack([np.cumsum(rng.normal(0, 0.01, 48)), np.zeros(48), np.cumsum(rng.normal(0, 0.01, 48))],
                              -1)[:, None].astype(np.float32)
    moved[20:30, list(LEGS[1][2:]), 1] += 0.08
    whole = FootPlant(LEGS).apply(moved, True)
    plant, parts = FootPlant(LEGS), []
    for a, b in ((0, 1), (1, 5), (5, 21), (21, 48)):
        if a == 21:              # saved and restored on the way
            saved, plant = plant.state(), FootPlant(LEGS)
            plant.load(*saved)
        parts.append(plant.apply(moved[a:b], True))
    np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_a_stream_s_feet_are_the_same_alone_and_in_a_crowd():
    """apply_many (a crowd's streams at once, each leg a lane of numpy arithmetic) gives each stream the bits that
    apply gives it alone (Python floats, as the JavaScript runtime computes), whatever its neighbours: planted,
    lifted, out of reach and unmoved frames, chunk by chunk."""
    rng = np.random.default_rng(4)
    streams, frames = 6, 40
    joints = np.stack([standing(frames, rng) for _ in range(streams)])
    drift = rng.normal(0, 1, (streams, 1, 1, 1)) * 0.03          # up to ~8 cm a frame: some feet out of reach
    joints[..., [0, 2]] += (drift * np.arange(frames)[None, :, None, None]).astype(np.float32)
    lifted = rng.random((streams, frames)) < 0.25
    joints[..., list(LEGS[0][2:]), 1] += np.where(lifted, 0.08, 0.0)[..., None].astype(np.float32)
    moved = rng.random((streams, frames)) < 0.8
    moved[0] = False                                             # a stream never steered beside steered ones
    alone, together = [FootPlant(LEGS) for _ in range(streams)], [FootPlant(LEGS) for _ in range(streams)]
    a = 0
    for b in (1, 4, 5, 13, 20, 40):
        want = np.stack([p.apply(joints[s, a:b], moved[s, a:b].tolist()) for s, p in enumerate(alone)])
        got = FootPlant.apply_many(together, joints[:, a:b], moved[:, a:b])
        np.testing.assert_array_equal(got, want)
        assert [p.state() for p in together] == [p.state() for p in alone]
        a = b
    assert any(p.pinned[0] for p in alone) and not np.array_equal(want, joints[:, a - 20:a])   # it planted feet
