"""A crowd: characters stepped together in batched calls move exactly as each would alone (tokens and frames bit for
bit), whoever joins, switches prompt, restarts at END or leaves; variants that cannot batch are refused."""
import numpy as np
import pytest
from toy_bundle import portable_toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.crowd import Crowd

PROMPTS = ["a person walks forward", "a person waves with the right hand", "a person jumps in place",
           "a person turns left", "a person kicks"]
# (prompt, seed, tick it joins at, seconds or None, (token, new prompt) or None)
PLAN = [(PROMPTS[0], 1, 0, None, (9, PROMPTS[3])), (PROMPTS[1], 2, 0, 6.0, None), (PROMPTS[2], 3, 3, None, None),
        (PROMPTS[4], 7, 5, 4.0, None), (PROMPTS[3], 11, 2, None, (17, PROMPTS[1])), (PROMPTS[0], 2 ** 63 - 1, 1, None, None),
        # a prompt of several actions (plan.py), one with a stated duration
        ("a person jumps in place for 2 seconds, then turns left and then waves with the right hand", 5, 4, None, None)]
TICKS = 60


@pytest.fixture(scope="module", params=["portable", "int8_fixed", "compact"])
def gen(portable_toy_bundle, request):  # noqa: F811
    return MotionGenerator(portable_toy_bundle, variant=request.param)


def run_crowd(gen, sampling, plan=PLAN, ticks=TICKS, leave=None):
    """-> per plan row: (joints (T, J, 3), features (T, D), the Character). `leave`: {row: tick it is removed at}."""
    crowd = Crowd(gen, sampling=sampling)
    chars, joints, features = {}, {}, {}
    for t in range(ticks):
        for i, (prompt, seed, start, seconds, _) in enumerate(plan):
            if t == start:
                chars[i] = crowd.add(prompt, seed=seed, seconds=seconds)
                joints[i], features[i] = [], []
        for i, c in list(chars.items()):
            if leave and leave.get(i) == t and c in crowd.characters:
                crowd.remove(c)
        row = {c: i for i, c in chars.items()}
        for c, frames in crowd.tick().items():
            assert frames.index == sum(len(j) for j in joints[row[c]])
            joints[row[c]].append(frames.joints)
            features[row[c]].append(frames.features)
        for i, c in chars.items():
            switch = plan[i][4]
            if switch and c.count == switch[0] and c in crowd.characters:
                c.set_prompt(switch[1])
    return {i: (np.concatenate(joints[i]), np.concatenate(features[i]), chars[i]) for i in chars}


def run_alone(gen, sampling, prompt, seed, seconds, switch, frames):
    """The same character through gen.stream, switching at the same token; its first `frames` frames."""
    stream = gen.stream(prompt, seed=seed, seconds=seconds, sampling=sampling)
    joints, features = [], []
    for frame in stream:
        joints.append(frame.joints)
        features.append(frame.features)
        if switch and stream.tokens == switch[0] and len(joints) == switch[0] * gen.dims.downsample:
            stream.set_prompt(switch[1])
        if len(joints) == frames:
            break
    stream.close()
    return np.stack(joints), np.stack(features), stream


@pytest.mark.parametrize("sampling", [None, SamplingConfig(temperature=1.0, top_k=20), SamplingConfig(temperature=0.0)],
                         ids=["bundle-defaults", "top-k", "greedy"])
def test_a_character_in_a_crowd_moves_as_it_would_alone(gen, sampling):
    crowd = run_crowd(gen, sampling)
    restarts = switched = 0
    for i, (prompt, seed, start, seconds, switch) in enumerate(PLAN):
        joints, features, character = crowd[i]
        want_frames = (gen.tokens_for(seconds) if seconds else TICKS - start) * gen.dims.downsample
        assert len(joints) <= want_frames and (seconds is None or len(joints) == want_frames)
        alone_joints, alone_features, stream = run_alone(gen, sampling, prompt, seed, seconds, switch, len(joints))
        assert np.array_equal(alone_features, features), f"character {i}: features differ from its lone stream"
        assert np.array_equal(alone_joints, joints), f"character {i}: joints differ from its lone stream"
        assert [t for t, _ in character.switches] == [t for t, _, _ in stream.switches]
        restarts += character.restarts
        switched += len(character.switches)
    print(f"\n{gen.variant}: {len(PLAN)} characters, {sum(len(c[0]) for c in crowd.values())} frames identical to their lone streams; "
          f"{switched} prompt switches, {restarts} END restarts")
    assert switched == 2
    if sampling is None or not sampling.greedy:
        assert restarts > 0, "the plan never exercised an END restart"


def test_who_leaves_does_not_change_who_stays(gen):
    everyone = run_crowd(gen, None)
    fewer = run_crowd(gen, None, leave={0: 12, 2: 20})
    for i in (1, 3, 4, 5):
        assert np.array_equal(everyone[i][0], fewer[i][0]), f"character {i} changed when others left"
    assert len(fewer[0][0]) < len(everyone[0][0])
    assert np.array_equal(fewer[0][0], everyone[0][0][:len(fewer[0][0])])


def test_characters_with_seconds_leave_by_themselves(gen):
    crowd = Crowd(gen)
    a, b = crowd.add(PROMPTS[0], seconds=1.0), crowd.add(PROMPTS[1])
    frames = {a: 0, b: 0}
    for _ in range(gen.tokens_for(1.0)):
        for c, f in crowd.tick().items():
            frames[c] += len(f.joints)
    assert crowd.characters == [b] and len(crowd) == 1
    assert frames[a] == gen.tokens_for(1.0) * gen.dims.downsample


def test_a_recorded_character_gives_its_motion(gen):
    """Character.motion(): the tokens, features and joints it made, those of a lone fixed-length run."""
    crowd = Crowd(gen)
    kept, unkept = crowd.add(PROMPTS[2], seed=4, seconds=3.0, record=True), crowd.add(PROMPTS[0], seed=5)
    assert kept.motion().num_frames == 0 and kept.motion().tokens.shape == (0, gen.dims.num_levels)
    while kept in crowd.characters:
        crowd.tick()
    motion, alone = kept.motion(), gen.generate(PROMPTS[2], seed=4, seconds=3.0)
    assert np.array_equal(motion.tokens, alone.tokens) and motion.num_frames == alone.num_frames
    streamed = np.stack([f.joints for f in gen.stream(PROMPTS[2], seed=4, seconds=3.0)])
    assert np.array_equal(motion.joints, streamed) and motion.seed == 4 and motion.text == PROMPTS[2]
    with pytest.raises(ValueError, match="record=True"):
        unkept.motion()


def test_variants_that_cannot_batch_are_refused(portable_toy_bundle):  # noqa: F811
    for variant in ("fp32", "int8", "int8_ort"):
        with pytest.raises(ValueError, match="fixed-capacity step graph"):
            Crowd(MotionGenerator(portable_toy_bundle, variant=variant))


def test_bad_arguments_are_refused(gen):
    crowd = Crowd(gen)
    with pytest.raises(ValueError, match="one prompt"):
        crowd.add(["a", "b"])
    with pytest.raises(ValueError, match="seed"):
        crowd.add("a person walks", seed=-1)
    with pytest.raises(ValueError, match="seconds"):
        crowd.add("a person walks", seconds=0)
    with pytest.raises(ValueError, match="chunk"):
        Crowd(gen, chunk=0)
    with pytest.raises(ValueError, match="SamplingConfig"):
        Crowd(gen, sampling={"temperature": 1.0})
    other = Crowd(gen).add("a person walks")
    with pytest.raises(ValueError, match="not in this crowd"):
        crowd.remove(other)
    assert crowd.tick() == {} and len(crowd) == 0


def test_mogo_crowd_writes_each_characters_lone_stream(portable_toy_bundle, tmp_path, capsys):  # noqa: F811
    from mogo_runtime.cli import main

    args = ["crowd", PROMPTS[0], PROMPTS[1], "-n", "3", "--seconds", "2", "--seed", "5", "--bundle",
            str(portable_toy_bundle), "-o", str(tmp_path), "--format", "npy"]
    assert main(args) == 0
    assert "3 characters x 2.00 s" in capsys.readouterr().err
    gen = MotionGenerator(portable_toy_bundle, variant="int8_fixed")
    for i in range(3):
        alone = np.stack([f.joints for f in gen.stream(PROMPTS[i % 2], seed=5 + i, seconds=2)])
        assert np.array_equal(np.load(tmp_path / f"character_{i}.npy"), alone), i
    for bad, message in ((["--rig", "mixamo"], "--rig applies"), (["--variant", "fp32"], "fixed-capacity"),
                         (["-n", "0"], "--characters")):
        assert main(args + bad) == 2
        err = capsys.readouterr().err
        assert err.startswith("mogo: error:") and message in err and err.count("\n") == 1, err


def test_a_prompt_embedded_alone_is_kept_and_gives_the_same_bits(portable_toy_bundle):  # noqa: F811
    """Characters share prompts: the second add of a prompt runs no text encoder, with the embedding the first got;
    a batch of prompts is neither served from nor added to what is kept (padding could change its last bits)."""
    gen = MotionGenerator(portable_toy_bundle, variant="fp32")
    calls = []
    encode = gen.backend.text.encode
    gen.backend.text.encode = lambda texts, *a, **k: calls.append(list(texts)) or encode(texts, *a, **k)
    first = gen.backend.encode_text([PROMPTS[0]])
    again = gen.backend.encode_text([PROMPTS[0]])
    assert np.array_equal(first, again) and calls == [[PROMPTS[0]]]
    again[0, 0] += 1.0                                                    # a caller's copy: what is kept is not
    assert np.array_equal(gen.backend.encode_text([PROMPTS[0]]), first)
    batch = gen.backend.encode_text([PROMPTS[1], PROMPTS[2]])
    assert len(calls) == 2
    fresh = MotionGenerator(portable_toy_bundle, variant="fp32").backend.encode_text([PROMPTS[1]])
    assert np.array_equal(gen.backend.encode_text([PROMPTS[1]]), fresh)   # alone: a lone call's bits
    assert batch.shape == (2, fresh.shape[1])


def test_a_rebuilds_scratch_cache_is_given_back_when_far_too_large(portable_toy_bundle):  # noqa: F811
    """A restored crowd resumes every context in one tick (a scratch of all its rows); once the last 64 rebuilds
    asked for 8 times fewer rows, the scratch is made again at their size, and rows are never short."""
    from mogo_runtime.crowd import SCRATCH_CALLS, SCRATCH_SLACK

    crowd = Crowd(MotionGenerator(portable_toy_bundle, variant="portable"))
    assert len(crowd._scratch(800)[0]) == 800
    for _ in range(SCRATCH_CALLS - 1):
        assert len(crowd._scratch(10)[0]) == 10 and len(crowd._spare[0]) == 800    # 800 within the last calls
    crowd._scratch(10)
    assert len(crowd._spare[0]) == 10 < 800 / SCRATCH_SLACK
    assert len(crowd._scratch(30)[0]) == 30 and len(crowd._scratch(12)[0]) == 12 and len(crowd._spare[0]) == 30


def test_characters_that_rebuild_together_do_it_a_few_rows_a_call(portable_toy_bundle, monkeypatch):  # noqa: F811
    """Characters that start together rebuild their contexts in the same ticks (a restored server's all do): their
    rebuilds (and retries after END) go SCRATCH_ROWS rows a call, so the scratch cache stays that small, and every
    token and frame is what one call over all of them gives."""
    import mogo_runtime.crowd as crowd_module

    plan = [(PROMPTS[i % len(PROMPTS)], 40 + i, 0, None, None) for i in range(9)]
    gen = MotionGenerator(portable_toy_bundle, variant="int8_fixed")
    rows = []
    scratch = Crowd._scratch
    monkeypatch.setattr(Crowd, "_scratch", lambda self, n: rows.append(n) or scratch(self, n))
    monkeypatch.setattr(crowd_module, "SCRATCH_ROWS", 10 ** 6)
    whole = run_crowd(gen, None, plan, ticks=30)
    assert max(rows) >= 4              # several rebuilt in one call (ends at END part them)
    rows.clear()
    monkeypatch.setattr(crowd_module, "SCRATCH_ROWS", 2)
    split = run_crowd(gen, None, plan, ticks=30)
    assert max(rows) == 2
    for i in whole:
        assert np.array_equal(whole[i][0], split[i][0]) and np.array_equal(whole[i][1], split[i][1]), i
        assert whole[i][2].count == split[i][2].count == 30
