"""A prompt of several actions ("walks forward and then jumps"): split the same way in every runtime
(tests/golden/plans.json), then played one after another, each until the model ends it or for its stated duration."""
import json
import itertools
from pathlib import Path

import numpy as np
import pytest
from test_endless import Recorded, rebuilt
from toy_bundle import REFRESH, WINDOW, build_toy_bundle, toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.endless import EndlessLoop
from mogo_runtime.bundle.sections import StreamingSpec
from mogo_runtime.engine import OrtBackend
from mogo_runtime.plan import plan_actions

TABLE = json.loads((Path(__file__).parents[1] / "golden" / "plans.json").read_text())["cases"]
SPEC = StreamingSpec(WINDOW, REFRESH)
WALK, JUMP, WAVE = "a person walks forward", "a person jumps twice", "a person waves with the right hand"


@pytest.fixture(scope="module")
def gen(toy_bundle) -> MotionGenerator:  # noqa: F811
    return MotionGenerator(toy_bundle)


@pytest.mark.parametrize("prompt, want", TABLE, ids=[c[0][:40] for c in TABLE])
def test_a_prompt_splits_into_the_actions_it_names(prompt, want):
    if isinstance(want, str):
        with pytest.raises(ValueError, match=want):
            plan_actions(prompt)
    else:
        assert [[a.text, a.seconds] for a in plan_actions(prompt)] == want


def test_each_action_plays_until_the_model_ends_it_then_the_next(gen):
    for seed in range(6):
        walk = gen.generate(WALK, seed=seed)                 # a lone action: the model ends it
        both = gen.generate(f"{WALK} and then jumps twice", seed=seed)
        n = len(walk.tokens)
        # up to its END the first action is exactly the lone motion; then the second one plays, and ends the motion
        assert np.array_equal(both.tokens[:n], walk.tokens) and n < len(both.tokens) <= n + gen.max_tokens
        assert both.aligned_text == f"{WALK} | {JUMP}" and walk.actions is None
        assert both.actions == [(WALK, 0), (JUMP, n * gen.dims.downsample)]
    backend = Recorded(OrtBackend(gen.bundle), {"all": -1e9, 4: 1e9, 9: 1e9})   # END at calls 4 and 9
    loop = EndlessLoop(backend, backend.encode_text([WALK]), SamplingConfig(), [3], SPEC)
    loop.set_actions(backend.encode_text([WALK, JUMP]), [None, None])
    stream = loop.streams[0]
    for _ in range(12):
        loop.step()
    # END at call 4 starts the jump from [BOS] (not a restart of the walk); END at call 9 restarts the jump
    assert [i for i, c in enumerate(backend.calls) if rebuilt(c, backend.dims)] == [0, 5, 10]
    assert stream.part == 1 and stream.restarts == 1 and stream.finished_at == 8
    np.testing.assert_array_equal(stream.rows_emb, loop.policy.condition(backend.encode_text([WALK, JUMP])[1:]))


def test_an_action_that_never_ends_gives_way_after_the_longest_motion(gen):
    backend = Recorded(OrtBackend(gen.bundle), {"all": -1e9})         # a model that never picks END
    loop = EndlessLoop(backend, backend.encode_text([WALK]), SamplingConfig(), [3], SPEC)
    loop.set_actions(backend.encode_text([WALK, JUMP, WAVE]), [None, 3, None])
    stream = loop.streams[0]
    parts = []
    for _ in range(gen.max_tokens + 10):
        loop.step()
        parts.append(stream.part)
    assert parts.index(1) == gen.max_tokens - 1 and parts.index(2) == gen.max_tokens + 2   # the walk, then 3 jumps
    assert not stream.finished


def test_a_stated_duration_holds_the_action_that_long(gen):
    for seed in range(4):
        held = gen.generate(WALK, seconds=2, seed=seed)          # endless: END restarts the walk, 2 s exactly
        k = len(held.tokens)
        motion = gen.generate(f"{WALK} for 2 seconds, then jumps twice for 1.2 s", seed=seed)
        assert np.array_equal(motion.tokens[:k], held.tokens) and len(motion.tokens) == k + gen.tokens_for(1.2)
        fixed = gen.generate(f"{WALK} for 2 seconds, then jumps twice for 1.2 s", seconds=6, seed=seed)
        assert np.array_equal(fixed.tokens[:len(motion.tokens)], motion.tokens)       # then the jump is held
        assert len(fixed.tokens) == gen.tokens_for(6)


def test_a_list_of_prompts_gets_what_each_gets_alone(gen):
    prompts = [WALK, f"{JUMP}, then walks forward", WAVE]
    together = gen.generate(prompts, seed=5)
    for i, (p, m) in enumerate(zip(prompts, together)):
        assert np.array_equal(gen.generate(p, seed=5 + i).tokens, m.tokens)
    assert [m.aligned_text for m in together] == [None, f"{JUMP} | a person walks forward", None]


def test_a_stream_follows_a_prompt_of_several_actions(gen):
    s = gen.stream(WALK, seed=2, chunk=1)
    list(itertools.islice(s, 3 * gen.dims.downsample))
    s.set_prompt("a person jumps twice and then waves with the right hand")
    assert s.aligned_text == f"{JUMP} | {WAVE}" and len(s._loop.streams[0].parts) == 2
    assert s.switches[-1][2] == s.aligned_text
    frames = list(itertools.islice(s, 40 * gen.dims.downsample))       # the last action is held: no end
    assert len(frames) == 40 * gen.dims.downsample and s._loop.streams[0].part == 1
    with pytest.raises(ValueError, match="at most 8 actions"):
        s.set_prompt(", then ".join([WALK] * 9))


def test_on_a_bundle_of_single_clips_a_prompt_is_one_conditioning(tmp_path, humanml3d_fixture):
    clips = MotionGenerator(build_toy_bundle(tmp_path / "clips", np.load(humanml3d_fixture / "Mean.npy"), streaming=False))
    whole = f"{WALK} and then jumps twice"
    m = clips.generate(whole, seed=1)
    assert m.aligned_text is None and np.array_equal(m.tokens, clips.generate(whole, seed=1, align=False).tokens)
