"""The portable variant in the runtime (torch-free): its fixed-capacity step computes what the dynamic step computes,
the generation loop runs on it unchanged (clips, batches, guidance, timelines, streams that switch prompts) with
the tokens of fp32, a full cache is an error, and the ORT-format variants load (hashed) and run.

The toy bundle checks the mechanics; the tiny trained bundle (a real transformer, exported by mogo-export) checks
that greedy tokens stay identical to fp32 over many prompts and a long endless stream with switches.
"""
import itertools
import shutil

import numpy as np
import pytest
from toy_bundle import CAPACITY, portable_toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import Bundle, BundleError, MotionGenerator, SamplingConfig
from mogo_runtime.bundle.sampling import GREEDY
from mogo_runtime.cli import main
from mogo_runtime.decoding import GenerationTask
from mogo_runtime.engine import FixedCache, FixedCacheBackend, OrtBackend, open_backend

PROMPTS = ["a person walks forward", "a person jumps twice", "a person walks in a circle", "a person waves"]
SAMPLINGS = [GREEDY, SamplingConfig(temperature=1.0, top_p=0.8), SamplingConfig(temperature=0.9, guidance=2.0)]


@pytest.fixture(scope="module")
def generators(portable_toy_bundle):  # noqa: F811
    return {v: MotionGenerator(portable_toy_bundle, variant=v) for v in ("fp32", "portable", "portable_ort")}


def test_the_fixed_cache_step_computes_the_dynamic_step(portable_toy_bundle):  # noqa: F811
    """Token by token and in rebuilds of several tokens (one call each), up to the full capacity: the same
    logits, and the cache's filled slots are the dynamic step's presents."""
    bundle = Bundle.load(portable_toy_bundle)
    dynamic, fixed = OrtBackend(bundle, "fp32"), open_backend(bundle, "portable")
    assert isinstance(fixed, FixedCacheBackend) and fixed.capacity == CAPACITY == bundle.manifest.portable.capacity
    rng = np.random.default_rng(0)
    rows = 3
    emb = dynamic.encode_text(PROMPTS[:rows])
    tokens = rng.integers(0, bundle.dims.codebook_size, (rows, CAPACITY, bundle.dims.num_levels))
    tokens[:, 0] = bundle.dims.bos_id
    past_d, past_f, t, worst = dynamic.empty_past(rows), fixed.empty_past(rows), 0, 0.0
    for n in itertools.cycle([1, 3, 1, 5, 2]):
        n = min(n, CAPACITY - t)
        logits_d, past_d = dynamic.step(emb, tokens[:, t:t + n], past_d)
        logits_f, past_f = fixed.step(emb, tokens[:, t:t + n], past_f)
        t += n
        assert logits_f.shape[1] == n and past_f.length == t
        worst = max(worst, float(np.abs(logits_f[:, -1] - logits_d[:, -1]).max()))
        for f, d in zip(past_f.arrays, past_d):
            assert f.shape[2] == CAPACITY and np.array_equal(f[:, :, :t], d)
        if t == CAPACITY:
            break
    print(f"fixed vs dynamic step, {CAPACITY} steps: max abs logits difference {worst:.2e}")
    assert worst < 1e-5


def test_a_full_cache_is_an_error_not_an_overwrite(portable_toy_bundle):  # noqa: F811
    fixed = open_backend(Bundle.load(portable_toy_bundle), "portable")
    emb = fixed.encode_text(PROMPTS[:1])
    full = FixedCache(fixed.empty_past(1).arrays, CAPACITY)
    tokens = np.zeros((1, 1, fixed.dims.num_levels), np.int64)
    with pytest.raises(ValueError, match=f"holds {CAPACITY} steps; {CAPACITY} are cached and 1 more"):
        fixed.step(emb, tokens, full)
    with pytest.raises(ValueError, match="holds"):
        fixed.step(emb, np.zeros((1, 2, fixed.dims.num_levels), np.int64), FixedCache(full.arrays, CAPACITY - 1))


def test_the_loop_runs_unchanged_with_the_tokens_of_fp32(generators):
    """Clips the model ends, fixed lengths through the endless loop (rebuilds every 8 tokens on the toy), batches,
    guidance, timelines, and a stream that switches prompts: the tokens of fp32, the frames to float rounding."""
    fp32 = generators["fp32"]
    for variant in ("portable", "portable_ort"):
        gen = generators[variant]
        for sampling, seed in itertools.product(SAMPLINGS, (0, 7)):
            for seconds in (None, 6.0):
                want = fp32.generate(PROMPTS, seconds=seconds, seed=seed, sampling=sampling)
                got = gen.generate(PROMPTS, seconds=seconds, seed=seed, sampling=sampling)
                for w, g in zip(want, got):
                    assert np.array_equal(w.tokens, g.tokens), (variant, sampling, seed, seconds, w.text)
                    assert np.abs(w.joints - g.joints).max() < 1e-4
        timeline = [(PROMPTS[0], 0.0), (PROMPTS[1], 1.0), (PROMPTS[2], 2.2)]
        assert np.array_equal(fp32.generate(timeline, seconds=4.0, seed=3).tokens,
                              gen.generate(timeline, seconds=4.0, seed=3).tokens)
        streams = [g.stream(PROMPTS[0], seed=5) for g in (fp32, gen)]
        frames = [[], []]
        for k, s in enumerate(streams):
            for i, frame in enumerate(itertools.islice(s, 400)):
                if i in (60, 200):
                    s.set_prompt(PROMPTS[1 if i == 60 else 3])
                frames[k].append(frame.joints)
            assert s.tokens >= 100
        assert np.abs(np.stack(frames[0]) - np.stack(frames[1])).max() < 1e-4


def test_the_portable_graph_has_fixed_shapes_but_the_batch(portable_toy_bundle):  # noqa: F811
    backend = open_backend(Bundle.load(portable_toy_bundle), "portable")
    for io in (*backend.step_session.get_inputs(), *backend.step_session.get_outputs()):
        assert isinstance(io.shape[0], str) and all(isinstance(d, int) for d in io.shape[1:]), (io.name, io.shape)
    assert [i.name for i in backend.step_session.get_inputs()][:3] == ["text_embedding", "tokens", "position"]


def test_ort_variants_are_hashed_checked_and_run(portable_toy_bundle, tmp_path, capsys):  # noqa: F811
    bundle = Bundle.load(portable_toy_bundle)
    assert set(bundle.variants) == {"fp32", "int8", "portable", "int8_fixed", "compact", "int8_ort", "portable_ort"}
    int8, int8_ort = (MotionGenerator(bundle, variant=v) for v in ("int8", "int8_ort"))
    for seed in (0, 1):
        want, got = (g.generate(PROMPTS[2], seed=seed).tokens for g in (int8, int8_ort))
        assert np.array_equal(want, got)
    assert main(["info", str(portable_toy_bundle)]) == 0
    out = capsys.readouterr().out
    assert f"fixed cache of {CAPACITY} steps, opset 17" in out and "int8_ort, portable_ort" in out
    copy = tmp_path / "bundle"
    shutil.copytree(portable_toy_bundle, copy)
    data = bytearray((copy / "step.portable.ort").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (copy / "step.portable.ort").write_bytes(bytes(data))
    with pytest.raises(BundleError, match="step.portable.ort: sha256"):
        MotionGenerator(copy, variant="portable_ort")
    MotionGenerator(copy, variant="portable")              # the other variants do not read that file
    # a graph whose capacity is not the manifest's is refused when the generator opens it
    shutil.copy(portable_toy_bundle / "step.portable.ort", copy / "step.portable.ort")
    import json

    m = json.loads((copy / "manifest.json").read_text())
    m["portable"]["capacity"] += 1
    for spec in m["portable"]["step"]["inputs"][3:] + m["portable"]["step"]["outputs"][1:]:
        spec["shape"][2] += 1
    (copy / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match=rf"past_key_values.0.key' has shape \['batch', 2, {CAPACITY}, 4\], "
                                          rf"manifest portable.step says \['batch', 2, {CAPACITY + 1}, 4\]"):
        MotionGenerator(copy, variant="portable")


def test_greedy_tokens_of_the_trained_tiny_bundle_are_those_of_fp32(tiny_bundle):
    """A real transformer: clips of many prompts, and an endless stream with a switch every 23 tokens and context
    rebuilds (one call per token on the portable step), token for token."""
    bundle = Bundle.load(tiny_bundle)
    assert {"portable", "portable_ort"} <= set(bundle.variants)
    backends = {v: open_backend(bundle, v) for v in ("fp32", "portable", "portable_ort")}
    words = ["walks forward", "jumps", "waves with the right hand", "kicks with the left leg", "turns around",
             "squats down", "runs in a circle", "sits down"]
    prompts = [f"a person {a}" for a in words] + [f"a person {a} and then {b}" for a, b in zip(words, words[3:])]
    emb = backends["fp32"].encode_text(prompts)
    seeds = list(range(len(prompts)))
    tokens = {v: GenerationTask(b, bundle.skeleton, GREEDY, bundle.dims.max_tokens).tokens(emb, seeds) for v, b in backends.items()}
    streaming = bundle.manifest.streaming
    assert streaming is not None                                        # the tiny preset trains for streams
    starts = list(range(0, 600, 23))
    cycle = emb[np.arange(len(starts)) % len(emb)]                     # prompt k from token starts[k] on
    stream = {v: GenerationTask(b, bundle.skeleton, GREEDY, 600, 600, streaming).timeline(cycle, starts, seed=0).tokens
              for v, b in backends.items()}
    for v in ("portable", "portable_ort"):
        same = sum(np.array_equal(a, b) for a, b in zip(tokens["fp32"], tokens[v]))
        steps = int(np.all(stream["fp32"] == stream[v], axis=1).sum())
        print(f"{v}: {same}/{len(prompts)} clips and {steps}/600 stream steps identical to fp32 "
              f"({sum(len(t) for t in tokens[v])} clip tokens)")
        assert same == len(prompts) and steps == 600
