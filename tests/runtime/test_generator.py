"""MotionGenerator on onnxruntime, end to end on real bundle files: determinism, batching, streaming, lengths.

Every behaviour test runs on two bundles: `toy_bundle` (hand-built graphs, tests/runtime/toy_bundle.py) and
`tiny_bundle` (a tiny trained-shape model exported by mogo_export, from tests/runtime/conftest.py).
"""
import itertools
import json
import math

import numpy as np
import pytest
from toy_bundle import toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import Bundle, Frame, Motion, MotionGenerator
from mogo_runtime.bundle.sampling import GREEDY, SamplingConfig
from mogo_runtime.engine import OrtBackend
from mogo_runtime.kinematics.features import recover_from_ric
from mogo_runtime.kinematics.frames import FootLock

PROMPTS = ["a person walks forward", "a person waves left hand", "kicks twice", "runs and then sits down",
           "turns around"]


@pytest.fixture(scope="module", params=["toy_bundle", "tiny_bundle"])
def bundle(request) -> Bundle:
    return Bundle.load(request.getfixturevalue(request.param))


@pytest.fixture(scope="module")
def gen(bundle) -> MotionGenerator:
    return MotionGenerator(bundle)


@pytest.fixture(scope="module")
def toy_gen(toy_bundle) -> MotionGenerator:  # noqa: F811
    return MotionGenerator(toy_bundle)


def seconds_of(gen: MotionGenerator, tokens: int) -> float:
    return tokens * gen.dims.downsample / gen.dims.fps


def assert_same_motion(a: Motion, b: Motion, tol: float = 1e-5) -> None:
    assert np.array_equal(a.tokens, b.tokens)
    assert a.features.shape == b.features.shape and a.joints.shape == b.joints.shape
    assert np.abs(a.features - b.features).max(initial=0) <= tol
    assert np.abs(a.joints - b.joints).max(initial=0) <= tol


def test_a_motion_is_consistent(gen):
    m = gen.generate(PROMPTS[0], seed=3)
    ds, K = gen.dims.downsample, gen.dims.codebook_size
    T = len(m.tokens)
    assert 1 <= T <= gen.max_tokens and m.tokens.shape == (T, gen.dims.num_levels)
    assert ((m.tokens >= 0) & (m.tokens < K)).all()                                # no END, BOS or PAD inside
    assert m.features.shape == (T * ds, gen.dims.feature_dim) and m.features.dtype == np.float32
    assert m.joints.shape == (T * ds, gen.skeleton.num_joints, 3)
    assert np.isfinite(m.joints).all()
    assert np.array_equal(m.joints, FootLock(gen.skeleton).push(
        recover_from_ric(m.features, gen.skeleton.num_joints), m.features))
    assert m.fps == gen.dims.fps and m.seconds == pytest.approx(T * ds / gen.dims.fps)
    assert (m.text, m.seed, m.skeleton) == (PROMPTS[0], 3, gen.skeleton)


def test_same_seed_same_motion_and_the_seed_matters(gen):
    a = gen.generate(PROMPTS[1], seed=7, sampling=SamplingConfig(temperature=1.0))
    b = gen.generate(PROMPTS[1], seed=7, sampling=SamplingConfig(temperature=1.0))
    assert_same_motion(a, b, tol=0.0)
    others = [gen.generate(PROMPTS[1], seed=s, sampling=SamplingConfig(temperature=1.0)) for s in (8, 9)]
    assert any(not np.array_equal(a.tokens, o.tokens) for o in others)


def test_greedy_ignores_the_seed(gen):
    a, b = (gen.generate(PROMPTS[2], seed=s, sampling=GREEDY) for s in (0, 5))
    assert_same_motion(a, b, tol=0.0)


@pytest.mark.parametrize("guidance", [1.0, 2.5])
def test_batch_of_n_equals_n_single_runs_with_seeds_s_to_s_plus_n(gen, guidance):
    batch = gen.generate(PROMPTS, seed=11, sampling=SamplingConfig(guidance=guidance))
    assert isinstance(batch, list) and [m.text for m in batch] == PROMPTS
    for i, text in enumerate(PROMPTS):
        single = gen.generate(text, seed=11 + i, sampling=SamplingConfig(guidance=guidance))
        assert batch[i].seed == 11 + i
        assert_same_motion(batch[i], single)


def test_explicit_seed_list(gen):
    batch = gen.generate(PROMPTS[:3], seed=[5, 0, 42])
    assert_same_motion(batch[2], gen.generate(PROMPTS[2], seed=42))
    assert [m.seed for m in batch] == [5, 0, 42]


@pytest.mark.parametrize("fixed,chunk", [(False, 4), (True, 4), (False, 1), (True, 3)])
def test_stream_equals_generate(gen, fixed, chunk):
    seconds = seconds_of(gen, 7) if fixed else None
    for seed in (0, 1):
        if fixed or not gen.endless:
            offline = gen.generate(PROMPTS[3], seconds=seconds, seed=seed)
            frames = list(gen.stream(PROMPTS[3], seconds=seconds, seed=seed, chunk=chunk))
        else:   # an endless stream: its first frames are those of a fixed-length motion
            offline = gen.generate(PROMPTS[3], seconds=seconds_of(gen, 7), seed=seed)
            frames = list(itertools.islice(gen.stream(PROMPTS[3], seed=seed, chunk=chunk), offline.num_frames))
        assert all(isinstance(f, Frame) for f in frames)
        assert [f.index for f in frames] == list(range(offline.num_frames))
        assert [f.time for f in frames] == pytest.approx([i / gen.dims.fps for i in range(offline.num_frames)])
        assert np.abs(np.stack([f.features for f in frames]) - offline.features).max() <= 1e-5
        assert np.abs(np.stack([f.joints for f in frames]) - offline.joints).max() <= 1e-5


def test_stream_yields_before_the_motion_is_finished(gen):
    # The first frames arrive after one step, not after the whole loop.
    steps = []
    backend_step = gen.backend.step
    gen.backend.step = lambda *a: (steps.append(1), backend_step(*a))[1]
    try:
        it = gen.stream(PROMPTS[0], seconds=seconds_of(gen, 5), seed=0)
        next(it)
        assert len(steps) == 1
        rest = list(it)
        restarts = it.restarts                                        # an endless stream restarts at END
        assert len(steps) == 5 + restarts and len(rest) == 5 * gen.dims.downsample - 1
    finally:
        del gen.backend.step


@pytest.mark.parametrize("tokens", [1, 3, "max"])
def test_fixed_seconds_gives_the_exact_frame_count(gen, tokens):
    n = gen.max_tokens if tokens == "max" else tokens
    m = gen.generate(PROMPTS[4], seconds=seconds_of(gen, n), seed=2)
    assert len(m.tokens) == n and m.num_frames == n * gen.dims.downsample
    assert m.seconds == pytest.approx(seconds_of(gen, n))


def test_seconds_round_to_the_nearest_token_half_up(gen):
    per_token = seconds_of(gen, 1)
    assert gen.tokens_for(2.49 * per_token) == 2
    assert gen.tokens_for(2.5 * per_token) == 3
    assert gen.tokens_for(0.5 * per_token) == 1


def test_none_means_the_bundles_sampling_defaults(gen, bundle):
    d = bundle.manifest.sampling_defaults
    written = json.loads((bundle.path / "manifest.json").read_text())["sampling_defaults"]
    assert d.to_dict() == written and d != SamplingConfig(temperature=1.0)
    a = gen.generate(PROMPTS[0], seed=4)
    b = gen.generate(PROMPTS[0], seed=4, sampling=SamplingConfig(**written))
    c = gen.generate(PROMPTS[0], seed=4, sampling=SamplingConfig(temperature=1.0))
    assert_same_motion(a, b, tol=0.0)
    assert not np.array_equal(a.tokens, c.tokens)               # the default's top_p is applied


def test_progress_is_reported_every_step(gen):
    calls = []
    m = gen.generate(PROMPTS[1], seconds=seconds_of(gen, 4), seed=0, progress=lambda t, n: calls.append((t, n)))
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)] and len(m.tokens) == 4


def test_int8_variant_generates(bundle):
    assert "int8" in bundle.variants
    m = MotionGenerator(bundle, variant="int8", threads=1).generate(PROMPTS[0], seconds=seconds_of_bundle(bundle, 3))
    assert m.num_frames == 3 * bundle.dims.downsample and np.isfinite(m.joints).all()


def test_int8_batch_equals_single_runs_too(bundle):
    # Dynamic int8 quantizes activations with one scale per tensor: batched rows would shift each other's
    # numbers, so quantized graphs run row by row and batching cannot change a prompt's motion.
    gen8 = MotionGenerator(bundle, variant="int8")
    assert "step" in gen8.backend.one_row
    batch = gen8.generate(PROMPTS[:3], seconds=seconds_of_bundle(bundle, 12), seed=20,
                          sampling=SamplingConfig(guidance=2.0))
    for i, text in enumerate(PROMPTS[:3]):
        assert_same_motion(batch[i], gen8.generate(text, seconds=seconds_of_bundle(bundle, 12), seed=20 + i,
                                                   sampling=SamplingConfig(guidance=2.0)), tol=0.0)


def seconds_of_bundle(bundle, tokens):
    return tokens * bundle.dims.downsample / bundle.dims.fps


def test_backend_cache_grows_by_one_step_and_is_fed_back_as_is(bundle):
    backend = OrtBackend(bundle, threads=1)
    model = bundle.dims
    emb = backend.encode_text(PROMPTS[:2])
    assert emb.shape == (2, bundle.dims.text_dim)
    past = backend.empty_past(2)
    assert len(past) == 2 * model.n_layers
    tokens = np.full((2, 1, bundle.dims.num_levels), bundle.dims.bos_id, np.int64)
    for t in range(1, 4):
        logits, presents = backend.step(emb, tokens, past)
        assert logits.shape == (2, 1, bundle.dims.num_levels, bundle.dims.codebook_size + 1)
        want = [2, model.num_levels * model.n_heads, t, model.head_dim]
        assert all(list(p.shape) == want for p in presents)
        # views of onnxruntime's own output buffers: nothing copied them on the way out (or back in)
        assert all(not p.flags["OWNDATA"] and p.flags["C_CONTIGUOUS"] and p.dtype == np.float32 for p in presents)
        past, tokens = presents, np.zeros_like(tokens)


def test_the_model_ends_a_motion_while_its_batchmates_go_on(toy_gen):
    # The toy model's END grows likelier every step, so some prompts end early and others run on.
    motions = toy_gen.generate(PROMPTS, seed=0)
    lengths = [len(m.tokens) for m in motions]
    assert min(lengths) < toy_gen.max_tokens and len(set(lengths)) > 1, lengths
    for m in motions:
        assert m.num_frames == len(m.tokens) * toy_gen.dims.downsample


# ---------------------------------------------------------------------------------------------------
# input checks: clear errors, raised before any work

@pytest.mark.parametrize("text, error, match", [
    ("", ValueError, "empty or whitespace"),
    ("   \t", ValueError, "empty or whitespace"),
    (["walks", " "], ValueError, "prompt 1 is empty"),
    ([], ValueError, "empty list"),
    (["walks", 3], ValueError, "prompt 1 is a int"),
])
def test_bad_text(toy_gen, text, error, match):
    with pytest.raises(error, match=match):
        toy_gen.generate(text)


@pytest.mark.parametrize("seconds", [0, -1.0, math.nan, math.inf, 1e6, "six"])
def test_bad_seconds_name_the_allowed_range(toy_gen, seconds):
    with pytest.raises(ValueError) as e:
        toy_gen.generate(PROMPTS[0], seconds=seconds)
    most = 3600 if toy_gen.endless else toy_gen.max_seconds      # endless bundles: any length up to an hour
    assert f"between {seconds_of(toy_gen, 1):g} and {most:g} seconds" in str(e.value)
    with pytest.raises(ValueError, match="between"):
        toy_gen.stream(PROMPTS[0], seconds=seconds)                       # raised at the call, not at next()


@pytest.mark.parametrize("sampling, match", [
    ({"top_k": -1}, "top_k must be an int >= 1"),
    ({"top_k": 2.5}, "top_k must be an int"),
    ({"top_k": True}, "top_k must be an int"),
    ({"top_p": 0.0}, r"top_p must be in \(0, 1\]"),
    ({"top_p": 1.5}, r"top_p must be in \(0, 1\]"),
    ({"temperature": -0.1}, r"temperature must be in \[0, 100\]"),
    ({"temperature": "hot"}, "temperature must be a number"),
    ({"guidance": -1.0}, r"guidance must be in \[0, 100\]"),
])
def test_bad_sampling(sampling, match):
    with pytest.raises(ValueError, match=match):
        SamplingConfig(**sampling)


@pytest.mark.parametrize("kwargs, match", [
    ({"seed": -1}, r"seeds must be ints in \[0, 2\*\*63\)"),
    ({"seed": 1.5}, "seed must be an int"),
    ({"seed": True}, "seed must be an int"),
    ({"seed": [1, 2]}, "got 2 seeds for 1 prompts"),
    ({"sampling": {"temperature": 0}}, "sampling must be a SamplingConfig"),
    ({"seconds": True}, "seconds must be a number"),
])
def test_bad_settings(toy_gen, kwargs, match):
    with pytest.raises(ValueError, match=match):
        toy_gen.generate(PROMPTS[0], **kwargs)


def test_unknown_variant_lists_the_available_ones(toy_bundle):  # noqa: F811
    with pytest.raises(ValueError, match=r"unknown variant 'fp16'.*fp32, int8"):
        MotionGenerator(toy_bundle, variant="fp16")


def test_bad_threads_and_stream_takes_one_prompt(toy_bundle, toy_gen):  # noqa: F811
    for threads in (0, 10 ** 6, True, 1.0):
        with pytest.raises(ValueError, match=r"threads must be an int in \[1, 64\]"):
            MotionGenerator(toy_bundle, threads=threads)
    with pytest.raises(ValueError, match="variant must be a variant name"):
        MotionGenerator(toy_bundle, variant="")
    with pytest.raises(ValueError, match="use generate"):
        toy_gen.stream(PROMPTS[:2])
