"""Endless, steerable streams: no end, a new prompt from the next token, a bounded context, timelines.

The toy bundle (tests/runtime/toy_bundle.py) declares window 5 + refresh 3, so a few dozen tokens already go
through many context compactions and rebuilds; its step graph sums every cached key, so a rebuild or a compaction that
kept the wrong tokens, or none, changes the logits.
"""
import itertools
import shutil

import numpy as np
import pytest
from toy_bundle import REFRESH, WINDOW, build_toy_bundle, toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.bundle.sections import StreamingSpec
from mogo_runtime.decoding import GenerationTask, generate_tokens
from mogo_runtime.endless import COMPACTIONS, EndlessLoop
from mogo_runtime.engine import OrtBackend
from mogo_runtime.policy import expand_seeds, make_rngs

WALK, JUMP = "a person walks forward", "a person jumps twice"
CIRCLE = "a person walks in a circle"          # the toy model ends it late (24 tokens greedy), the others soon
SPEC = StreamingSpec(WINDOW, REFRESH)


@pytest.fixture(scope="module")
def gen(toy_bundle) -> MotionGenerator:  # noqa: F811
    return MotionGenerator(toy_bundle)


def per_token(gen) -> float:
    return gen.dims.downsample / gen.dims.fps


def test_a_stream_has_no_end_and_its_start_is_a_fixed_length_motion(gen):
    assert gen.endless
    n = 20 * gen.max_tokens * gen.dims.downsample                      # far past max_tokens
    frames = list(itertools.islice(gen.stream(WALK, seed=3), n))
    assert [f.index for f in frames] == list(range(n)) and np.isfinite(np.stack([f.joints for f in frames])).all()
    within = WINDOW + REFRESH + 1                                      # tokens before the first rebuild
    m = gen.generate(WALK, seconds=within * per_token(gen), seed=3)
    assert np.abs(np.stack([f.joints for f in frames[:m.num_frames]]) - m.joints).max() <= 1e-5


class Recorded:
    """A backend whose step calls are recorded (input tokens, cache length before the call); `force_end` maps a
    step call's index to the level-0 END logit to use there (1e9: END is picked, -1e9: never)."""

    def __init__(self, backend, force_end=None):
        self.backend, self.dims, self.force_end, self.calls = backend, backend.dims, force_end or {}, []

    def __getattr__(self, name):
        return getattr(self.backend, name)

    def step(self, emb, tokens, past, control=None):
        logits, present = self.backend.step(emb, tokens, past, control)
        end = self.force_end.get(len(self.calls), self.force_end.get("all"))
        self.calls.append((tokens.copy(), past[0].shape[2]))
        if end is not None:
            logits = np.array(logits)
            logits[:, -1, 0, self.dims.end_id] = end
        return logits, present


def rebuilt(call, dims) -> bool:
    tokens, past = call
    return past == 0 and (tokens[:, 0] == dims.bos_id).all()


def test_a_full_context_is_compacted_then_rebuilt_and_stays_bounded(toy_bundle):  # noqa: F811
    backend = Recorded(OrtBackend(MotionGenerator(toy_bundle).bundle), {"all": -1e9})    # a model that never ends
    caches = []                                 # the cache each step call was given, and the one it returned
    step = backend.step

    def kept(emb, tokens, past, control=None):
        logits, present = step(emb, tokens, past, control)
        caches.append((past, present))
        return logits, present
    backend.step = kept
    loop = EndlessLoop(backend, backend.encode_text([WALK]), SamplingConfig(), [0], SPEC)
    for _ in range(200):
        loop.step()
    lengths = [past + tokens.shape[1] for tokens, past in backend.calls]
    # the cache holds the prompt prefix and at most window + refresh tokens, every step of a long stream
    assert max(lengths) == 1 + WINDOW + REFRESH and lengths[:3] == [1, 2, 3] and len(lengths) == 200
    full = [i for i, (a, b) in enumerate(zip(lengths, lengths[1:])) if b < a]
    assert len(full) >= (200 - WINDOW - REFRESH - 1) // (REFRESH + 1) and all(lengths[i + 1] == 1 + WINDOW for i in full)
    # COMPACTIONS times the newest pick is fed after the prefix and the last window - 1 cached steps, as they were
    # computed; then the context is rebuilt from [BOS, the last `window` tokens picked], oldest first
    rebuilt = [backend.calls[i + 1][1] == 0 for i in full]
    assert rebuilt == ([False] * COMPACTIONS + [True]) * (len(full) // (COMPACTIONS + 1)) + [False] * (len(full) % (COMPACTIONS + 1))
    picked = np.stack([tokens[0, -1] for tokens, _ in backend.calls[1:]])          # token t is fed at call t + 1
    first = REFRESH + 2                         # the slot of the last window - 1 steps of a full context
    for i, fresh in zip(full, rebuilt):
        tokens, past = backend.calls[i + 1]
        if fresh:
            assert (tokens[0, 0] == backend.dims.bos_id).all()
            assert np.array_equal(tokens[0, 1:], picked[i - WINDOW + 1:i + 1])
            continue
        assert past == WINDOW and np.array_equal(tokens[0], picked[i:i + 1])
        given, before = caches[i + 1][0], caches[i][1]
        for a, b in zip(given, before):
            assert np.array_equal(a[:, :, :1], b[:, :, :1]) and np.array_equal(a[:, :, 1:], b[:, :, first:first + WINDOW - 1])


def test_the_loop_equals_generate_tokens_until_its_first_end_or_refresh(gen):
    backend = gen.backend
    compared = 0
    for text, seed in ((CIRCLE, 4), (CIRCLE, 6), (JUMP, 5)):
        emb = backend.encode_text([text])
        for sampling in (SamplingConfig(temperature=0.0), SamplingConfig(temperature=1.0, top_p=0.9),
                         SamplingConfig(guidance=2.0)):
            want = [p for p, alive in generate_tokens(backend, emb, sampling, make_rngs([seed]), 64) if alive[0]]
            loop = EndlessLoop(backend, emb, sampling, [seed], SPEC)
            got = [loop.step() for _ in range(len(want) + 3)]
            same = min(len(want), WINDOW + REFRESH + 1)                  # then a refresh keeps only `window`
            assert all(np.array_equal(w, g) for w, g in zip(want[:same], got))
            assert loop.restarts >= (len(want) <= WINDOW + REFRESH)      # an END within reach restarts the motion
            assert all(g[0, 0] != gen.dims.end_id for g in got)
            compared += same
    assert compared > 30                      # long motions too, not only immediate ENDs


def test_end_restarts_the_prompt_with_nothing_kept(toy_bundle):  # noqa: F811
    # call 6 picks END (after 6 tokens): that call's draw is discarded, call 7 rebuilds [BOS] and picks again
    backend = Recorded(OrtBackend(MotionGenerator(toy_bundle).bundle), {"all": -1e9, 6: 1e9})
    loop = EndlessLoop(backend, backend.encode_text([JUMP]), SamplingConfig(), [3], SPEC)
    picked = [loop.step() for _ in range(12)]
    assert loop.restarts == 1 and len(backend.calls) == 13 and all(p[0, 0] != backend.dims.end_id for p in picked)
    assert [i for i, c in enumerate(backend.calls) if rebuilt(c, backend.dims)] == [0, 7]
    assert backend.calls[7][0].shape[1] == 1                          # nothing of the ended motion kept
    # after the restart the loop is a fresh motion of the same prompt, continuing the same random stream
    fresh = Recorded(backend.backend, {"all": -1e9})
    again = EndlessLoop(fresh, backend.encode_text([JUMP]), SamplingConfig(), [3], SPEC)
    for _ in range(7):                                                # the 7 draws the first loop consumed
        again.streams[0].rng.random(backend.dims.num_levels)
    assert all(np.array_equal(a, b) for a, b in zip(picked[6:], [again.step() for _ in range(6)]))


def test_a_new_prompt_starts_from_nothing_kept(toy_bundle):  # noqa: F811
    backend = Recorded(OrtBackend(MotionGenerator(toy_bundle).bundle), {"all": -1e9})
    loop = EndlessLoop(backend, backend.encode_text([WALK]), SamplingConfig(guidance=2.0), [3], SPEC)
    for t in range(10):
        if t == 4:
            loop.set_prompt(backend.encode_text([JUMP]))
        loop.step()
    assert [i for i, c in enumerate(backend.calls) if rebuilt(c, backend.dims)] == [0, 4]
    tokens, _ = backend.calls[4]
    assert tokens.shape == (2, 1, backend.dims.num_levels)           # both guidance rows, [BOS] only


def test_set_prompt_takes_effect_at_the_next_token(gen):
    a = gen.stream(WALK, seed=7, chunk=1)
    b = gen.stream(WALK, seed=7, chunk=1)
    fa = list(itertools.islice(a, 40))
    fb = list(itertools.islice(b, 40))
    k = b.tokens
    b.set_prompt(JUMP)
    assert b.text == JUMP and list(b.switches) == [(k, JUMP, None)]
    fa += list(itertools.islice(a, 60))
    fb += list(itertools.islice(b, 60))
    ja, jb = np.stack([f.joints for f in fa]), np.stack([f.joints for f in fb])
    assert np.array_equal(ja[:40], jb[:40])                            # nothing already decoded changes
    assert not np.allclose(ja[40:], jb[40:])                           # the new prompt steers what follows
    a.close()
    b.close()


def test_a_timeline_is_a_stream_with_prompt_switches(gen):
    pt = per_token(gen)
    m = gen.generate([(WALK, 0.0), (JUMP, 10 * pt), (WALK, 25 * pt)], seconds=40 * pt, seed=2)
    task = GenerationTask(gen.backend, gen.skeleton, gen.sampling_defaults, gen.max_tokens, None,
                          gen.bundle.manifest.streaming)
    loop = task.loop(gen.backend.encode_text([WALK]), [2])
    tokens = []
    for t in range(40):
        if t in (10, 25):
            loop.set_prompt(gen.backend.encode_text([JUMP if t == 10 else WALK]))
        tokens.append(loop.step())
    assert np.array_equal(m.tokens, np.concatenate(tokens)) and m.num_frames == 40 * gen.dims.downsample
    assert m.text == f"{WALK} | {JUMP} | {WALK}"


def test_long_fixed_lengths_and_batches(gen):
    m = gen.generate(WALK, seconds=600, seed=1)                        # a 10-minute motion in one call
    assert m.num_frames == 600 * gen.dims.fps and np.isfinite(m.joints).all()
    task = GenerationTask(gen.backend, gen.skeleton, SamplingConfig(), gen.max_tokens, 3 * gen.max_tokens,
                          gen.bundle.manifest.streaming)
    emb = gen.backend.encode_text([WALK, JUMP])
    batch = task.tokens(emb, expand_seeds(9, 2))
    for i, text in enumerate((WALK, JUMP)):                            # a batch is its rows run alone
        assert np.array_equal(batch[i], task.tokens(gen.backend.encode_text([text]), [9 + i])[0])


@pytest.mark.parametrize("timeline, seconds, match", [
    ([(WALK, 0.0), (JUMP, 1.0)], None, "needs seconds"),
    ([(WALK, 0.5), (JUMP, 1.0)], 4, "begin at 0 and increase"),
    ([(WALK, 0.0), (JUMP, 2.0), (WALK, 1.0)], 4, "begin at 0 and increase"),
    ([(WALK, 0.0), (JUMP, 5.0)], 4, "before the end"),
    ([(WALK, 0.0), (3, 1.0)], 4, "pairs"),
])
def test_bad_timelines(gen, timeline, seconds, match):
    with pytest.raises(ValueError, match=match):
        gen.generate(timeline, seconds=seconds)


def test_a_bundle_without_streaming_ends_its_streams_and_refuses_set_prompt(toy_bundle, tmp_path,  # noqa: F811
                                                                            humanml3d_fixture):
    plain = build_toy_bundle(tmp_path / "plain", np.load(humanml3d_fixture / "Mean.npy"), streaming=False)
    g = MotionGenerator(plain)
    assert not g.endless
    s = g.stream(WALK, seed=0)
    frames = list(s)                                                   # the model ends it
    assert 0 < len(frames) <= g.max_tokens * g.dims.downsample
    with pytest.raises(ValueError, match="not trained for endless streams"):
        s.set_prompt(JUMP)
    with pytest.raises(ValueError, match="between .* seconds for this bundle"):
        g.generate(WALK, seconds=600)
    shutil.rmtree(plain)


def test_cli_follow_reads_prompts_from_stdin(toy_bundle, capsys, monkeypatch):  # noqa: F811
    import io
    import json

    from mogo_runtime.cli import main

    args = ["stream", WALK, "--bundle", str(toy_bundle), "--seconds", "4", "--seed", "5"]
    assert main(args) == 0
    plain = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    monkeypatch.setattr("sys.stdin", io.StringIO(f"{JUMP}\n\n"))
    assert main(args + ["--follow"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    events = [x for x in lines if "event" in x]
    frames = [x for x in lines if "event" not in x]
    assert len(events) == 1 and events[0]["text"] == JUMP and events[0]["event"] == "prompt"
    assert events[0]["frame"] == 0 and events[0]["token"] == 1     # read while the bundle loaded
    assert len(frames) == len(plain) == 4 * 20 and [f["frame"] for f in frames] == list(range(80))
    assert frames != plain                                            # the stream followed the new prompt


def test_cli_follow_needs_an_endless_bundle(tmp_path, capsys, monkeypatch, humanml3d_fixture):
    import io

    from mogo_runtime.cli import main

    monkeypatch.setattr("sys.stdin", io.StringIO(""))

    plain = build_toy_bundle(tmp_path / "plain", np.load(humanml3d_fixture / "Mean.npy"), streaming=False)
    assert main(["stream", WALK, "--bundle", str(plain), "--follow"]) == 2
    assert "needs a bundle trained for endless streams" in capsys.readouterr().err
