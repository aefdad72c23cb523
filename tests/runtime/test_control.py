"""Control: the vector the step graph reads (one writer for training targets and the game's requests), the requests
themselves (goal, path, joystick, game-owned capsule), and controlled streams and crowds, on the tiny trained bundle
(whose model has control)."""
import math

import numpy as np
import pytest
from toy_bundle import toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import MotionGenerator
from mogo_runtime.control import FollowPath, GameRoot, Steer, WalkTo
from mogo_runtime.control.targets import ARRIVE
from mogo_runtime.control.vector import control_dim, decode, encode, root_poses, to_local, to_world, token_controls
from mogo_runtime.crowd import Crowd
from mogo_runtime.kinematics.frames import RootIntegrator
from mogo_runtime.kinematics.skeleton import HUMANML3D

TIMES = np.arange(1, 6) * 0.2


def walking_features(T=40, speed=1.2, turn=0.0, fps=20.0):
    """Features whose root walks forward at `speed` m/s, turning `turn` rad per frame (the rest zeros)."""
    f = np.zeros((T, 263), np.float32)
    f[:, 0] = -turn / 2          # the features' half-angle velocity: yaw = -2 * angle
    f[:, 2] = speed / fps        # forward, in the root's frame
    f[:, 3] = 0.9
    return f


def test_the_local_frame_is_the_features_frame():
    """A root that walks forward (feature z velocity) moves along its facing (sin yaw, cos yaw: the step into frame
    t along frame t's, as the features integrate), and left (+x) is to its left; to_world undoes to_local; decode
    undoes encode."""
    poses = root_poses(walking_features(turn=0.05))
    step = poses[11, :2] - poses[10, :2]
    assert np.allclose(step / np.linalg.norm(step), [math.sin(poses[11, 2]), math.cos(poses[11, 2])], atol=1e-6)
    now = np.array([1.0, -2.0, 0.7])
    pts = np.random.default_rng(0).normal(size=(5, 2))
    assert np.allclose(to_world(now, to_local(now, pts)), pts)
    assert np.allclose(to_local(np.array([0, 0, math.pi / 2]), [[1.0, 0.0]]), [[0.0, 1.0]])   # facing +x: +x is ahead
    future = np.concatenate([pts, np.random.default_rng(1).uniform(-3, 3, (5, 1))], axis=1)
    back = decode(now, encode(now, future))
    assert np.allclose(back[:, :2], future[:, :2], atol=1e-5)
    assert np.allclose(np.angle(np.exp(1j * (back[:, 2] - future[:, 2]))), 0, atol=1e-5)


def test_training_targets_are_the_clip_s_own_future():
    f = walking_features(T=41, speed=1.0)
    rows = token_controls(root_poses(f[:40]), downsample=4, horizon=5)
    assert rows.shape == (11, control_dim(5)) and (rows[:, 0] == 1).all()
    per_step = rows[0, 1:].reshape(5, 4)
    assert np.allclose(per_step[:, 0], 0, atol=1e-6)                      # straight ahead: no sideways
    assert np.allclose(per_step[:, 1], [0.2, 0.4, 0.6, 0.8, 1.0], atol=1e-5)   # 1 m/s, tokens of 0.2 s
    assert np.allclose(per_step[:, 3], 1)                                 # facing unchanged
    last = rows[-1, 1:].reshape(5, 4)                                     # past the end: stopped
    assert np.allclose(last[:, :2], 0, atol=1e-6)


def test_the_next_pose_of_a_stream_is_where_the_whole_motion_puts_it():
    f = walking_features(T=44, speed=1.4, turn=0.03)
    poses = root_poses(f)
    root = RootIntegrator(HUMANML3D)
    for i in range(0, 40, 4):
        root.push(f[i:i + 4])
        assert np.allclose(root.next_pose(), poses[i + 4], atol=1e-12)


def test_walk_to_goes_straight_then_stands():
    target = WalkTo((3.0, 4.0), speed=1.0)
    future = target.future(np.array([0.0, 0.0, 0.0]), TIMES)
    assert np.allclose(future[:, :2], np.outer(TIMES, [0.6, 0.8])) and np.allclose(future[:, 2], math.atan2(3, 4))
    near = np.array([3.0, 4.0 - 0.5, 1.0])
    assert np.allclose(target.future(near, TIMES)[-1, :2], [3.0, 4.0])          # stops at the goal
    assert not target.arrived
    there = np.array([3.0, 4.0 - ARRIVE / 2, 1.0])
    assert np.allclose(target.future(there, TIMES), there) and target.arrived  # stands where it is, as it faces
    assert np.allclose(target.future(there + [1.0, 0, 0], TIMES), there + [1.0, 0, 0])   # arrived stays arrived


def test_follow_path_leads_back_onto_the_path_and_only_forward():
    path = FollowPath([(0, 0), (0, 4), (4, 4)], speed=2.0)
    off = np.array([0.5, 1.0, 0.0])                    # half a metre beside the first leg, a metre along
    future = path.future(off, TIMES)
    assert np.allclose(future[:, 0], 0) and np.allclose(future[:, 1], 1.0 + 2.0 * TIMES)   # on the path, ahead
    assert path.progress == pytest.approx(1.0)
    corner = path.future(np.array([0.0, 3.5, 0.0]), TIMES)
    assert np.allclose(corner[-1, :2], [1.5, 4.0]) and corner[-1, 2] == pytest.approx(math.pi / 2)   # turns the corner
    path.future(np.array([0.0, 0.0, 0.0]), TIMES)     # back at the start: progress is kept
    assert path.progress == pytest.approx(3.5)
    end = path.future(np.array([3.9, 4.0, 1.0]), TIMES)
    assert path.arrived and np.allclose(end, [3.9, 4.0, 1.0])


def test_a_path_overshot_past_its_end_still_steers_to_the_end():
    """A character that runs past the end beside it (not within ARRIVE of it) makes the progress the whole length;
    the next token's nearest-point search must still search the last segment (it searched none: argmin of nothing)."""
    path = FollowPath([(0, 0), (0, 2)], speed=1.0)
    for now in ([0.5, 3.0, 0.0], [0.5, 3.2, 0.0]):
        future = path.future(np.array(now), TIMES)
        assert path.progress == pytest.approx(2.0) and not path.arrived
        assert np.allclose(future[:, :2], [0.0, 2.0])


def test_paths_searched_together_give_each_its_own_future():
    """FollowPath.future_many (a crowd's paths in one search) gives each path the bits, progress, arrival and
    reference its own future gives it alone: paths of 2 to 400 points, searched over 1 to ~80 segments, one overshot,
    one arrived, one so fast that its wanted points lie past the segments searched, the character wandering off and
    back."""
    rng = np.random.default_rng(5)
    points = [[(0, 0), (0, 2)], [(0, 0), (0, 4), (4, 4)], np.cumsum(rng.normal(0, 0.1, (400, 2)), axis=0),
              np.cumsum(rng.normal(0, 1.0, (30, 2)), axis=0), [(0, 0), (0.2, 0.1)], np.full((400, 2), 0.035).cumsum(0)]
    speeds = [1.0, 2.0, 3.0, 4.0, 5.0, 9.0]
    alone = [FollowPath(p, speed=v) for p, v in zip(points, speeds)]
    together = [FollowPath(p, speed=v) for p, v in zip(points, speeds)]
    for step in range(40):
        now = np.stack([np.array([*(p.points[min(step, len(p.points) - 1)] + rng.normal(0, 0.4, 2)),
                                  rng.uniform(-3, 3)]) for p in alone])
        want = np.stack([p.future(n, TIMES) for p, n in zip(alone, now)])
        got = FollowPath.future_many(together, now, TIMES)
        assert got.tobytes() == want.tobytes()
        assert [(p.progress, p.arrived) for p in together] == [(p.progress, p.arrived) for p in alone]
        assert [p.reference() for p in together] == [p.reference() for p in alone]      # read with the wanted points
    assert alone[0].progress == alone[0].total and alone[4].arrived and not alone[2].arrived


def test_steer_and_the_game_s_capsule():
    steer = Steer((1.0, 0.0), facing=(0.0, 1.0))       # strafing: moving +x, facing +z
    future = steer.future(np.array([0.0, 0.0, 0.3]), TIMES)
    assert np.allclose(future[:, 0], TIMES) and np.allclose(future[:, 2], 0.0)
    assert np.allclose(Steer((0.0, 2.0)).future(np.zeros(3), TIMES)[:, 2], 0.0)     # faces the way it moves
    capsule = GameRoot()
    capsule.place(0.0, 0.0, 0.0, frame=10)
    capsule.place(0.1, 0.0, 0.2, frame=12)             # 5 cm and 0.1 rad a frame
    assert np.allclose(capsule.at(16), [0.3, 0.0, 0.6])
    assert np.allclose(capsule.future(np.zeros(3), TIMES, fps=20.0, frame=12)[0], [0.3, 0.0, 0.6])   # 4 frames on


@pytest.mark.parametrize("make, message", [
    (lambda: WalkTo((float("nan"), 0)), "goal must be"), (lambda: WalkTo((1, 2, 3)), "goal must be"),
    (lambda: WalkTo((1, 2), speed=0), "speed must be"), (lambda: WalkTo((1, 2), speed=99), "speed must be"),
    (lambda: FollowPath([(0, 0)]), "path must be"), (lambda: FollowPath([(0, 0), (0, 0)]), "two distinct"),
    (lambda: FollowPath("abc"), "path must be"), (lambda: Steer((30, 0)), "at most"),
    (lambda: Steer((1, 0), facing=(0, 0)), "facing must be a direction"),
    (lambda: GameRoot().place(0, 0, float("inf"), 0), "heading must be")])
def test_bad_requests_are_refused_with_what_is_wrong(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def steered_frames(source, requests, ticks):
    """Joints (T, J, 3) of a stream or crowd character given `requests` {tick: callable(character)}."""
    out = []
    for t in range(ticks):
        if t in requests:
            requests[t](source["character"])
        out.append(source["next"]())
    return np.concatenate(out)


def test_a_crowd_character_goes_where_a_lone_stream_goes(tiny_bundle):
    """The same requests at the same tokens: the crowd's character and the lone stream give the same joints."""
    requests = {0: lambda c: c.walk_to((1.0, 2.0), 1.5), 7: lambda c: c.follow_path([(0, 0), (1, 1), (3, 0)], 2.0),
                15: lambda c: c.steer((0.5, -1.0), facing=(1.0, 0.0)), 22: lambda c: c.release(),
                26: lambda c: c.set_root(0.2, 0.1, 0.5)}
    gen = MotionGenerator(tiny_bundle, variant="portable")
    stream = gen.stream("a person walks forward", seed=3)
    per_token = lambda: np.stack([next(stream).joints for _ in range(gen.dims.downsample)])   # noqa: E731
    lone = steered_frames({"character": stream, "next": per_token}, requests, 30)
    crowd = Crowd(gen, chunk=1)
    other = crowd.add("a person waves", seed=9)
    other.walk_to((-2.0, 0.0))
    walker = crowd.add("a person walks forward", seed=3)
    ticked = steered_frames({"character": walker, "next": lambda: crowd.tick()[walker].joints}, requests, 30)
    assert len(ticked) == len(lone) and np.array_equal(ticked, lone)


def test_the_game_takes_the_root_between_two_frames_of_a_token(tiny_bundle):
    """A stream places a token's frames together when it hands out the first (the game does not own the root); a
    set_root before its second frame still puts that frame on the capsule, and leaves the frames shown before it as a
    stream never given the root shows them; given back, the stream goes on (finite, and elsewhere than before)."""
    gen = MotionGenerator(tiny_bundle, variant="portable")
    ds = gen.dims.downsample
    path = [(0.0, 0.0), (2.0, 1.0), (5.0, 1.0)]
    plain, taken = gen.stream("a person walks forward", seed=4), gen.stream("a person walks forward", seed=4)
    plain.follow_path(path)
    taken.follow_path(path)
    shown = []
    for f in range(12 * ds):
        frame = next(taken)
        shown.append(frame)
        assert np.array_equal(frame.joints, next(plain).joints)
    shown.append(next(taken))                             # the first frame of a token: all its frames placed
    next(plain)
    assert shown[-1].index % ds == 0 and ds > 1
    taken.set_root(0.5, -0.25, 0.3)
    frame = next(taken)                                   # the token's second
    assert frame.index % ds == 1 and np.allclose(frame.joints[0, [0, 2]], [0.5, -0.25], atol=1e-6)
    taken.release()
    rest = [next(taken).joints for _ in range(6 * ds + 1)]
    assert np.isfinite(rest).all() and not np.array_equal(rest[-1], next(plain).joints)


def test_the_game_owns_the_root(tiny_bundle):
    """set_root before every token: each frame's root is where the capsule is (extrapolated within a token)."""
    gen = MotionGenerator(tiny_bundle, variant="fp32")
    stream = gen.stream("a person walks forward", seed=1)
    ds = gen.dims.downsample
    capsule = lambda f: (0.03 * f, 0.01 * f, 0.02 * f)    # noqa: E731  straight at 0.6 m/s, turning
    frames = []
    for t in range(20):
        stream.set_root(*capsule(len(frames)))
        frames += [next(stream) for _ in range(ds)]
    roots = np.array([f.joints[0, [0, 2]] for f in frames])
    want = np.array([capsule(f.index)[:2] for f in frames])
    assert np.abs(roots[ds:] - want[ds:]).max() < 1e-5    # from the second placement on, the velocity is known


def test_requests_need_a_model_with_control_and_an_open_stream(tiny_bundle, toy_bundle):  # noqa: F811
    stream = MotionGenerator(toy_bundle).stream("a person walks", seed=0)     # the toy model has no control
    with pytest.raises(ValueError, match="trained without control"):
        stream.walk_to((1.0, 1.0))
    stream = MotionGenerator(tiny_bundle).stream("a person walks", seed=0)
    with pytest.raises(ValueError, match="goal must be"):
        stream.walk_to("there")
    stream.close()
    with pytest.raises(ValueError, match="closed"):
        stream.walk_to((1.0, 1.0))
    crowd = Crowd(MotionGenerator(tiny_bundle, variant="portable"))
    gone = crowd.add("a person walks")
    crowd.remove(gone)
    with pytest.raises(ValueError, match="not in this crowd"):
        gone.steer((1.0, 0.0))


# --------------------------------------------------------------------------------------------- requests as JSON lines

@pytest.mark.parametrize("line, prompt, control", [
    ("a person runs", "a person runs", None),
    ('{"prompt": "a person runs", "goal": [4, 2]}', "a person runs", {"goal": [4, 2]}),
    ('{"path": [[0, 0], [2, 1]], "speed": 2.5}', None, {"path": [[0, 0], [2, 1]], "speed": 2.5}),
    ('{"velocity": [0, 1.4], "facing": [1, 0]}', None, {"velocity": [0, 1.4], "facing": [1, 0]}),
    ('{"root": [1, 2, 0.5]}', None, {"root": [1, 2, 0.5]}),
    ('  {"release": true}', None, {"release": True}),
])
def test_a_request_line_is_a_prompt_or_a_json_object(line, prompt, control):
    from mogo_runtime.control.commands import parse_request

    r = parse_request(line)
    assert (r.prompt, r.control) == (prompt, control)


@pytest.mark.parametrize("line, message", [
    ('{"goal": [1, 2]', "not JSON"),
    ('{"goal": [1, 2]} {"goal": [3, 4]}', "not JSON"),          # one object per line
    ('{"gaol": [1, 2]}', r"unknown field\(s\) \['gaol'\]"),
    ('{"goal": [1, 2], "path": [[0, 0], [1, 1]]}', "one control at a time"),
    ('{"goal": [1, 2], "facing": [1, 0]}', "facing need velocity"),
    ('{"speed": 2}', "speed need goal or path"),
    ('{"release": 1}', "release must be true"),
    ('{"prompt": 5}', "prompt must be a string"),
    ('{"prompt": ""}', "empty"),
    ("{}", "needs a prompt or a control"),
    ("{" + '"goal":' + "[" * 100_000 + "]" * 100_000 + "}", "not JSON"),   # nested past the parser's depth
])
def test_a_bad_request_line_names_what_is_wrong(line, message):
    from mogo_runtime.control.commands import parse_request

    with pytest.raises(ValueError, match=message):
        parse_request(line)


@pytest.mark.parametrize("request_, message", [
    ({"goal": ["1", 2]}, r"goal must be \(x, z\) in metres \(numbers, not str\)"),
    ({"goal": [True, 2]}, "numbers, not bool"),
    ({"goal": [1, 2], "speed": 0}, "speed must be in m/s, from 0.05 to 10"),
    ({"path": [[0, 0]]}, "2 to 100000"),
    ({"path": "there"}, "path must be a list"),
    ({"velocity": [50, 0]}, "at most 10 m/s"),
    ({"root": [1, 2]}, r"root must be \[x, z, heading\]"),
    ({"root": [1, 2, "north"]}, "heading must be a number"),
])
def test_a_bad_control_changes_nothing(tiny_bundle, request_, message):
    from mogo_runtime.control.commands import Request

    stream = MotionGenerator(tiny_bundle).stream("a person walks", seed=0)
    stream.walk_to((3.0, 0.0))
    before = stream.steering.target
    with pytest.raises(ValueError, match=message):
        Request("a person jumps", request_).apply(stream)
    assert stream.steering.target is before and stream.text == "a person walks"


def test_cli_follow_reads_control_requests(tiny_bundle, toy_bundle, capsys, monkeypatch):  # noqa: F811
    import io
    import json

    from mogo_runtime.cli import main

    args = ["stream", "a person walks forward", "--bundle", str(tiny_bundle), "--seconds", "3", "--follow"]
    monkeypatch.setattr("sys.stdin", io.StringIO('{"goal": [0.0, 0.2], "speed": 1.0}\n'))
    assert main(args) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    events = [x for x in lines if "event" in x]
    assert [e["event"] for e in events] == ["control", "arrived"], events      # 0.2 m ahead: within ARRIVE at once
    assert events[0]["request"] == {"goal": [0.0, 0.2], "speed": 1.0} and events[0]["token"] == 1
    assert len([x for x in lines if "frame" in x and "event" not in x]) == 60

    monkeypatch.setattr("sys.stdin", io.StringIO('{"goal": [1, "x"]}\n'))
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "goal must be (x, z)" in err, err

    monkeypatch.setattr("sys.stdin", io.StringIO('{"prompt": "a person jumps", "goal": [1, 1]}\n'))
    assert main(args[:3] + [str(toy_bundle)] + args[4:]) == 2
    assert "trained without control" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------- the bounded correction

def test_the_correction_is_bounded_per_frame_and_closes_the_error():
    from mogo_runtime.control.warp import GAIN, MAX_SHIFT, MAX_TURN, RootWarp

    warp = RootWarp()
    body = np.random.default_rng(0).normal(size=(4, 22, 3)).astype(np.float32)
    body[:, 0, [0, 2]] = 0.0                                             # the root over the origin, where it turns
    assert warp.joints(0, body).tobytes() == body.tobytes()              # never planned: untouched, bit for bit
    pose = np.array([0.0, 0.0, 0.0])
    error, heading = np.array([1.0, 0.0]), math.radians(40)              # a metre beside the path, 40 degrees off
    shown, poses = [], []
    for token in range(30):
        start = 4 * token
        here = warp.pose(np.array([0.0, 0.0, 0.0]), start)               # the model stands still at the origin
        poses.append(here)
        warp.plan(start, 4, here, heading - here[2], error - here[:2])
        shown.append(warp.joints(start, np.repeat(body[:1], 4, axis=0)))
    shown = np.concatenate(shown).astype(np.float64)
    step = np.hypot(*(shown[1:, 0, [0, 2]] - shown[:-1, 0, [0, 2]]).T)  # the root: shifted only (turns about it)
    assert step.max() <= MAX_SHIFT + 1e-6
    toe = shown[:, 10]
    turned = np.degrees(np.abs(np.diff(np.arctan2(*(toe[:, [0, 2]] - shown[:, 0, [0, 2]]).T))))
    assert turned.max() <= math.degrees(MAX_TURN) + 1e-6
    assert np.allclose(poses[-1][:2], error, atol=0.02) and abs(poses[-1][2] - heading) < math.radians(1)
    assert GAIN < 1                                                      # a share per token: the loop reads again


def test_a_character_that_reached_its_goal_is_held_there(tiny_bundle):
    """A model that walks on after its walk_to goal is reached (here at 0.1 m/s, under the correction's bound) is
    pulled back to the goal by the correction, as a path holds its character: after 10 s it still stands within
    ARRIVE of the goal, where it would have drifted a metre."""
    from mogo_runtime.control.plant import legs_of
    from mogo_runtime.control.steering import Steering

    gen = MotionGenerator(tiny_bundle)
    ds = gen.dims.downsample

    class Context:
        def steer(self, vector):
            pass

    class Model:              # the root walks at 0.1 m/s along +x, whatever it is asked
        index = 0

        def next_pose(self):
            return np.array([0.1 * self.index / gen.dims.fps, 0.0, 0.0])

    steering, model = Steering(gen.backend.control, gen.dims, Context(), legs_of(gen.skeleton)), Model()
    goal = (0.05, 0.0)
    steering.request(lambda s: WalkTo(goal))
    for token in range(round(10 * gen.dims.fps / ds)):
        model.index = (token + 1) * ds
        steering.update(model.index, model)
    assert steering.target.arrived
    assert np.hypot(*(steering.pose[:2] - goal)) < ARRIVE
    assert model.next_pose()[0] > 0.9                       # where the model alone stands: a metre on


def test_a_frame_shown_after_the_next_plan_keeps_its_own_ease():
    from mogo_runtime.control.warp import RootWarp

    warp, body = RootWarp(), np.zeros((4, 22, 3), np.float32)
    warp.plan(0, 4, np.zeros(3), 0.0, np.array([0.04, 0.0]))
    before = warp.joints(0, body)
    warp.plan(4, 4, warp.pose(np.zeros(3), 4), 0.0, np.array([0.0, 0.04]))   # planned before frames 0-3 are shown
    assert np.array_equal(warp.joints(0, body), before)
    assert np.allclose(before[:, 0, 0], [0.005, 0.01, 0.015, 0.02])    # half of 4 cm, eased over 4 frames


def test_a_crowd_s_warps_and_poses_are_the_ones_read_one_by_one():
    """RootWarp.warps_many and poses_many (a crowd's, on lanes of numpy) give the bits that `_warp` and `pose` give on
    Python floats (a lone stream's pose, each plan's start): frames in the newest ease, across older ones, before the
    first correction and older than every ease kept."""
    from mogo_runtime.control.warp import RootWarp

    rng = np.random.default_rng(7)
    warps = [RootWarp() for _ in range(4)]
    for token in range(8):
        for k, w in enumerate(warps):
            if k and token % k == 0:                     # warp 0 is never planned
                w.plan(4 * token + 4, 4, rng.normal(0, 1, 2), rng.normal(0, 0.3), rng.normal(0, 0.05, 2))
    frames = [range(0, 40), range(0, 40), range(20, 26), range(35, 36)]   # warp 1 kept its last 3 eases only
    got = RootWarp.warps_many(warps, frames)
    assert got.tobytes() == np.array([w._warp(f) for w, r in zip(warps, frames) for f in r]).tobytes()
    assert len({tuple(row) for row in got[40:80]}) > 8        # the eases turn and shift it
    model, at = rng.normal(0, 2, (4, 3)), [3, 10, 27, 36]
    want = np.stack([w.pose(m, i) for w, m, i in zip(warps, model, at)])
    assert RootWarp.poses_many(warps, model, at).tobytes() == want.tobytes()
    assert np.array_equal(want[0], model[0]) and not np.array_equal(want[1], model[1])


def test_a_path_s_bisection_from_a_hint_is_the_bisection():
    from bisect import bisect_right

    from mogo_runtime.control.targets import _bisect

    rng = np.random.default_rng(8)
    for n in (1, 2, 5, 40):
        ordered = np.sort(rng.uniform(0, 10, n)).tolist()
        for value in [*rng.uniform(-1, 11, 30).tolist(), *ordered]:
            for hint in range(n + 1):
                assert _bisect(ordered, value, hint) == bisect_right(ordered, value), (n, value, hint)


def test_a_crowd_s_warps_give_each_stream_its_own_frames():
    """RootWarp.joints_many (a crowd's streams at once) gives each stream the bits its own joints gives it alone:
    a warp never planned and warps planned every token or every other, each plan for the token after the frames
    shown (as a stream's update plans before its frames are placed: the first frames of an active warp are not moved),
    with planted feet or without."""
    from test_plant import standing

    from mogo_runtime.control.plant import legs_of
    from mogo_runtime.control.warp import RootWarp

    rng = np.random.default_rng(6)
    for legs in (legs_of(HUMANML3D), None):
        alone, together = [RootWarp(legs) for _ in range(3)], [RootWarp(legs) for _ in range(3)]
        for token in range(12):
            body = np.stack([standing(4, rng) for _ in range(3)])         # both toes on the floor
            body[..., [0, 2]] += rng.normal(0, 0.02, (3, 4, 1, 2)).astype(np.float32)    # the body sways
            for k, (a, b) in enumerate(zip(alone, together)):
                if k and token % k == 0:      # stream 0 is never corrected; the next token's, as a stream plans
                    for w in (a, b):
                        w.plan(4 * token + 4, 4, w.pose(np.zeros(3), 4 * token + 4), 0.02 * k, (0.01, -0.02 * k))
            want = np.stack([w.joints(4 * token, body[k]) for k, w in enumerate(alone)])
            got = RootWarp.joints_many(together, [4 * token] * 3, body)
            assert got.tobytes() == want.tobytes()
        assert not alone[0].active and alone[1].active and not np.array_equal(want[1], body[1])
