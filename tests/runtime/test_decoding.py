"""The generation loop and sampling policy, driven by a small numpy backend with known behaviour."""
import numpy as np
import pytest

from mogo_runtime import SamplingConfig
from mogo_runtime.bundle.sections import ModelDims
from mogo_runtime.decoding import FrameMaker, collect_tokens, decode_tokens, generate_tokens
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.policy import best_first, expand_seeds, make_rngs, sample

DIMS = ModelDims(num_levels=3, codebook_size=7, n_layers=1, n_heads=1, head_dim=4, text_dim=5, max_rel_dist=8,
                 downsample=2, fps=20.0, receptive_field=2, feature_dim=263, latent_dim=4, max_tokens=12)


def rngs_for(seed, batch):
    return make_rngs(expand_seeds(seed, batch))


class ToyBackend:
    """Rows are independent; logits depend on the text, the last tokens and the position; END forced at `end_at`."""

    def __init__(self, end_at=None, seed=0):
        rng = np.random.default_rng(seed)
        self.dims, self.control = DIMS, None
        V = DIMS.codebook_size + 1
        self.w_text = rng.normal(size=(DIMS.text_dim, DIMS.num_levels * V))
        self.w_tok = rng.normal(size=(DIMS.codebook_size + 3, DIMS.num_levels * V))
        self.codes = rng.normal(size=(DIMS.num_levels, DIMS.codebook_size, DIMS.feature_dim))
        self.end_at = end_at
        self.rows_seen = []

    def empty_past(self, rows):
        return np.zeros(rows, np.int64)

    def step(self, text_emb, tokens, past, control=None):
        self.rows_seen.append(text_emb.copy())
        R, S, L = tokens.shape
        V = DIMS.codebook_size + 1
        h = text_emb @ self.w_text + self.w_tok[tokens[:, -1]].sum(1) + 0.3 * past[:, None]
        logits = h.reshape(R, 1, L, V).astype(np.float32)
        logits[..., DIMS.end_id] = -5.0
        if self.end_at is not None:
            logits[np.asarray(self.end_at)[:R] == past, :, 0, DIMS.end_id] = 1e3
        return logits, past + S

    def compact(self, past, first, count):
        return np.full_like(past, 1 + count)

    def decode(self, tokens):
        # latent of a token = sum of its level codes; a frame = sum of its token's latent and the 2 before.
        lat = sum(self.codes[l][tokens[..., l]] for l in range(DIMS.num_levels))   # (B, T, D)
        out = lat.copy()
        for k in range(1, DIMS.receptive_field + 1):
            out[:, k:] += lat[:, :-k] * (0.5 ** k)
        return np.repeat(out, DIMS.downsample, axis=1).astype(np.float32)


def run(backend, emb, sampling, seed, **kw):
    rngs = rngs_for(seed, len(emb))
    return collect_tokens(generate_tokens(backend, emb, sampling, rngs, max_tokens=kw.pop("max_tokens", 12), **kw),
                          len(emb), DIMS.num_levels)


def test_same_seed_same_tokens_and_seed_matters():
    emb = np.random.default_rng(1).normal(size=(2, DIMS.text_dim)).astype(np.float32)
    s = SamplingConfig(temperature=1.0)
    a, b, c = run(ToyBackend(), emb, s, 3), run(ToyBackend(), emb, s, 3), run(ToyBackend(), emb, s, 4)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))


def test_batch_equals_single_runs_with_the_same_seeds():
    emb = np.random.default_rng(2).normal(size=(3, DIMS.text_dim)).astype(np.float32)
    s = SamplingConfig(temperature=0.8, top_k=4, top_p=0.9)
    batch = run(ToyBackend(end_at=[4, 9, 6]), emb, s, 10)
    for i in range(3):
        single = run(ToyBackend(end_at=[[4, 9, 6][i]]), emb[i:i + 1], s, 10 + i)
        assert np.array_equal(batch[i], single[0])
    assert [len(x) for x in batch] == [4, 9, 6]


def test_end_token_only_from_level_zero_and_fixed_length_forbids_it():
    emb = np.ones((1, DIMS.text_dim), np.float32)
    toks = run(ToyBackend(end_at=[5]), emb, SamplingConfig(temperature=0.0), 0)
    assert len(toks[0]) == 5 and (toks[0] < DIMS.codebook_size).all()
    fixed = run(ToyBackend(end_at=[5]), emb, SamplingConfig(temperature=0.0), 0, fixed_tokens=9)
    assert len(fixed[0]) == 9 and (fixed[0] < DIMS.codebook_size).all()


def test_top_k_one_and_tiny_top_p_are_greedy():
    logits = np.random.default_rng(5).normal(size=(4, 3, 11)).astype(np.float32)
    greedy = sample(logits, SamplingConfig(temperature=0.0), rngs_for(0, 4))
    assert np.array_equal(greedy, logits.argmax(-1))
    assert np.array_equal(sample(logits, SamplingConfig(temperature=1.5, top_k=1), rngs_for(0, 4)), greedy)
    assert np.array_equal(sample(logits, SamplingConfig(temperature=1.5, top_p=1e-6), rngs_for(0, 4)), greedy)


def test_the_sampler_orders_codes_as_one_stable_sort_ties_included():
    # sample() sorts unstably and sorts tied rows again: its order must be the stable sort's, ties broken by code
    rng = np.random.default_rng(3)
    cases = [rng.normal(size=(6, 4, 513)).astype(np.float32),                # no ties
             rng.integers(-3, 3, size=(6, 4, 40)).astype(np.float32),         # ties everywhere
             (np.round(rng.normal(size=(6, 4, 300)) * 20) / 7).astype(np.float32),   # a few ties
             np.nextafter(np.ones((6, 4, 30)), 2) ** np.arange(30)]           # float64 logits 1 ulp apart
    cases[0][:, 1:, 0] = -np.inf
    ties = 0
    for logits in cases:
        for temperature in (1.0, 0.7, 0.37, 1.3):
            z = logits.astype(np.float64) / temperature
            order, z_sorted = best_first(logits, z)
            want = np.argsort(-z, axis=-1, kind="stable")
            assert np.array_equal(order, want), (logits.dtype, temperature)
            assert np.array_equal(z_sorted, np.take_along_axis(z, want, axis=-1))
            ties += int((np.diff(np.sort(z, -1), axis=-1) == 0).any())
    assert ties >= 8       # tied rows in most cases (1 ulp apart ties after dividing), or the re-sort goes untested


def test_sampling_follows_the_distribution():
    logits = np.log(np.array([[[0.7, 0.2, 0.1]]], np.float32))
    rngs = rngs_for(0, 1)
    picks = np.array([sample(logits, SamplingConfig(temperature=1.0), rngs)[0, 0] for _ in range(4000)])
    freq = np.bincount(picks, minlength=3) / len(picks)
    assert np.allclose(freq, [0.7, 0.2, 0.1], atol=0.03), freq
    top2 = np.array([sample(logits, SamplingConfig(temperature=1.0, top_k=2), rngs)[0, 0] for _ in range(2000)])
    assert set(top2.tolist()) <= {0, 1}


def test_guidance_runs_an_unconditional_branch_with_zero_text():
    backend = ToyBackend()
    emb = np.ones((2, DIMS.text_dim), np.float32)
    run(backend, emb, SamplingConfig(temperature=0.0, guidance=2.0), 0, max_tokens=3)
    seen = backend.rows_seen[0]                       # each prompt's row, then its unconditional row
    assert seen.shape == (4, DIMS.text_dim) and np.all(seen[1::2] == 0) and np.all(seen[0::2] == 1)


def frames_of(backend, maker, n):
    """The features of the frames `maker` has due, decoded from its window of n tokens (nothing when n is 0)."""
    if not n:
        return np.zeros((0, DIMS.feature_dim), np.float32)
    return maker.frames_from(backend.decode(maker.window(n)[None])[0]).features


def test_streamed_frames_equal_offline_decode():
    backend = ToyBackend(end_at=[7, 10])
    emb = np.random.default_rng(3).normal(size=(2, DIMS.text_dim)).astype(np.float32)
    rngs = rngs_for(9, 2)
    makers = [FrameMaker(DIMS, HUMANML3D, 1) for _ in range(2)]
    frames = [[], []]
    for picked, alive in generate_tokens(backend, emb, SamplingConfig(temperature=1.0), rngs, max_tokens=12):
        for b in np.flatnonzero(alive):
            frames[b].append(frames_of(backend, makers[b], makers[b].push(picked[b])))
    offline = decode_tokens(backend, run(ToyBackend(end_at=[7, 10]), emb, SamplingConfig(temperature=1.0), 9))
    for b in range(2):
        assert np.allclose(np.concatenate(frames[b]), offline[b], atol=1e-6)


@pytest.mark.parametrize("chunk", [1, 2, 4, 5])
def test_chunked_streaming_returns_every_frame_once_and_exactly(chunk):
    backend = ToyBackend(end_at=[9])
    emb = np.random.default_rng(4).normal(size=(1, DIMS.text_dim)).astype(np.float32)
    maker = FrameMaker(DIMS, HUMANML3D, chunk)
    pieces, ready_after = [], []
    for picked, alive in generate_tokens(backend, emb, SamplingConfig(temperature=1.0), rngs_for(5, 1), 12):
        if not alive[0]:
            break
        pieces.append(frames_of(backend, maker, maker.push(picked[0])))
        ready_after.append(len(pieces[-1]) // DIMS.downsample)
    pieces.append(frames_of(backend, maker, maker.due(final=True)))
    assert maker.due(final=True) == 0  # nothing is returned twice
    offline = decode_tokens(backend, run(ToyBackend(end_at=[9]), emb, SamplingConfig(temperature=1.0), 5))[0]
    np.testing.assert_allclose(np.concatenate(pieces), offline, atol=1e-6)
    assert ready_after[0] == 1  # the first token's frames come at once
    assert all(n in (0, chunk) for n in ready_after[1:])
    assert maker.frames == len(offline)


def test_bad_chunk_is_refused():
    with pytest.raises(ValueError, match="chunk"):
        FrameMaker(DIMS, HUMANML3D, 0)


def test_bad_sampling_options_are_refused():
    for kw in ({"temperature": -1}, {"top_k": -1}, {"top_p": 0.0}, {"top_p": 1.5}, {"guidance": -2},
               {"temperature": True}, {"top_k": 2.5}, {"top_p": "0.9"}, {"guidance": float("nan")},
               {"temperature": 1e308}):
        with pytest.raises(ValueError):
            SamplingConfig(**kw)
    # numpy scalars are numbers; top_k 0 means no top-k cut, like None
    s = SamplingConfig(temperature=np.float32(0.5), top_k=np.int64(0), top_p=np.float64(0.9), guidance=np.float32(2))
    assert (s.temperature, s.top_k, s.top_p, s.guidance) == (0.5, None, 0.9, 2.0)
    assert type(s.temperature) is float and type(s.top_p) is float
    with pytest.raises(ValueError, match="seeds"):
        rngs_for([1, 2], 3)


class StateDecoder:
    """A decoder_step stand-in whose state counts what it has seen: state i += (i + 1) * the tokens' sum."""

    dims = DIMS

    def decode_step(self, tokens, state):
        seen = tokens.sum(axis=(1, 2)).astype(np.float32)[:, None, None]
        features = np.repeat(seen[:, :, :1], tokens.shape[1] * DIMS.downsample, axis=1) * np.ones(DIMS.feature_dim)
        return features.astype(np.float32), [s + (i + 1) * seen for i, s in enumerate(state)]


def test_a_decoder_state_is_each_stream_s_own_alone_or_batched():
    from mogo_runtime.decoding import decode_due

    shapes = ((2, 3), (1, 3))
    alone, together = ([FrameMaker(DIMS, HUMANML3D, 1, shapes) for _ in range(3)] for _ in range(2))
    rng = np.random.default_rng(6)
    for _ in range(4):
        picked = rng.integers(0, DIMS.codebook_size, (3, DIMS.num_levels))
        for makers in (alone, together):
            for m, p in zip(makers, picked):
                m.push(p)
        batched = decode_due(StateDecoder(), together, 1)
        for b, m in enumerate(alone):
            assert np.array_equal(decode_due(StateDecoder(), [m], 1)[0], batched[b])
            m.pending = together[b].pending = 0
    for a, t in zip(alone, together):
        assert [s.tobytes() for s in a.state] == [s.tobytes() for s in t.state]
        assert [s.shape for s in t.state] == list(shapes) and t.state[1][0, 0] == 2 * t.state[0][0, 0] > 0
    maker = together[0]
    maker.state = [np.ones((2, 3)), np.full(3, 2.0)]            # any arrays of each state's size, as a SYNC has them
    assert maker.state[0].tolist() == [[1.0] * 3] * 2 and maker.state[1].dtype == np.float32
    with pytest.raises(ValueError, match=r"2 arrays of \[6, 3\] values, got \[6, 4\]"):
        maker.state = [np.ones(6), np.ones(4)]
    assert FrameMaker(DIMS, HUMANML3D, 1).state is None
