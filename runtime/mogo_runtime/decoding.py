"""The autoregressive generation loop, written once for every backend (torch reference, onnxruntime).

A backend computes; this module decides. Per step the backend's transformer step emits the logits of every
quantizer level for the next time step (all L level streams in one pass); the sampler picks the tokens; the
level-0 stream choosing END stops a prompt. Frames come from the causal motion decoder, either once at the end
(`decode_tokens`) or window by window as tokens arrive (`FrameStreamer`), with identical results because a
frame depends only on the last `receptive_field + 1` tokens.

`GenerationTask` is the whole recipe (seeds -> token loop -> tokens -> features -> joints): the Python API,
the torch reference, the parity verifier and evaluation all run it, so they cannot drift apart.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable, Iterator, Protocol

import numpy as np

from .features import recover_from_ric
from .manifest import ModelDims, StreamingSpec
from .motion import FootLock, RootIntegrator
from .sampling import SamplingConfig, apply_guidance, sample


class Backend(Protocol):
    """What the loop needs from an inference engine. Arrays are numpy; past is opaque to the loop."""

    dims: ModelDims

    def encode_text(self, texts: list[str]) -> np.ndarray: ...                 # (B, text_dim) float32

    def empty_past(self, rows: int): ...                                          # rows = prompts in the batch

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past):             # tokens (B, S, L) int64
        """-> (logits (B, S, L, K + 1) float32, new past)."""

    def decode(self, tokens: np.ndarray) -> np.ndarray:                         # (B, T, L) int64
        """Codebook lookup + causal decoder: -> de-normalised features (B, T * downsample, feature_dim)."""


def expand_seeds(seed: int | list[int], batch: int) -> list[int]:
    """One seed per prompt: prompt i of a batch with seed s draws exactly what a lone run with s + i does."""
    if isinstance(seed, (list, tuple)):
        seeds = list(seed)
    elif isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be an int >= 0 or a list of them, got {seed!r}")
    else:
        seeds = [int(seed) + i for i in range(batch)]
    if len(seeds) != batch:
        raise ValueError(f"got {len(seeds)} seeds for {batch} prompts")
    for s in seeds:
        if isinstance(s, (bool, np.bool_)) or not isinstance(s, (int, np.integer)) or not 0 <= s < 2 ** 63:
            raise ValueError(f"seeds must be ints in [0, 2**63), got {s!r}")
    return [int(s) for s in seeds]


def make_rngs(seeds: list[int]) -> list[np.random.Generator]:
    """The random stream of each prompt: numpy's PCG64 seeded with the prompt's seed."""
    return [np.random.Generator(np.random.PCG64(s)) for s in seeds]


def generate_tokens(backend: Backend, text_emb: np.ndarray, sampling: SamplingConfig,
                    rngs: list[np.random.Generator], max_tokens: int, fixed_tokens: int | None = None,
                    min_tokens: int = 1) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield (tokens (B, L), alive (B,) bool) once per time step, until every prompt has ended.

    `alive[b]` is False from the step where prompt b chose END (its tokens that step are meaningless).
    With `fixed_tokens` END is forbidden and every prompt runs exactly that many steps.
    """
    dims = backend.dims
    B = text_emb.shape[0]
    limit = fixed_tokens if fixed_tokens is not None else max_tokens
    guided = sampling.guidance != 1.0
    if guided:  # the unconditional branch: the all-zero text embedding the model was trained to see
        text_emb = np.concatenate([text_emb, np.zeros_like(text_emb)], axis=0)
    rows = text_emb.shape[0]
    tokens = np.full((rows, 1, dims.num_levels), dims.bos_id, dtype=np.int64)
    past = backend.empty_past(rows)
    alive = np.ones(B, dtype=bool)
    for t in range(limit):
        logits, past = backend.step(text_emb, tokens, past)
        logits = logits[:, -1]                                                  # (rows, L, K + 1)
        if guided:
            logits = apply_guidance(logits[:B], logits[B:], sampling.guidance)
        logits = np.array(logits, dtype=np.float32)                             # own copy: masked below
        logits[:, 1:, dims.end_id] = -np.inf      # only the coarsest stream may end the motion
        if fixed_tokens is not None or t < min_tokens:
            logits[:, 0, dims.end_id] = -np.inf
        picked = sample(logits, sampling, rngs)                                 # (B, L)
        alive &= picked[:, 0] != dims.end_id
        yield picked, alive.copy()
        if not alive.any():
            return
        # Ended prompts keep feeding a valid code; their rows are independent and their output is ignored.
        feed = np.where(alive[:, None], picked, 0)
        tokens = np.concatenate([feed, feed], axis=0)[:, None] if guided else feed[:, None]


class EndlessLoop:
    """The token loop of endless streams: never ends by itself, follows a new prompt from the next token, and
    keeps a bounded context (docs/bundle.md, "Endless streams").

    Each stream's context is its prompt's prefix (BOS) plus motion tokens, rebuilt (one step call with an empty
    cache on [BOS, kept tokens]) on three events:
    - a new prompt: nothing kept, so the prompt starts a motion as it would alone, from the next token; the
      causal decoder joins it to the frames before. Kept tokens of the old action are continued, not left: on
      `base`, keeping 1 or 2 tokens gave per-segment accuracy 0.87 or 0.78, keeping none 0.95 (README,
      "Endless streams, measured").
    - END picked by the coarsest level, where `generate` would end the motion: the same prompt starts again,
      nothing kept, and the step picks again from the rebuilt context (END forbidden there), so an action is
      held by repeating it as the model ends it instead of running past the lengths it was trained on (per-segment
      accuracy 0.51 -> 0.78 on an earlier `base`).
    - window + refresh tokens since the last rebuild: the last `window` are kept (a motion longer than that goes
      on from its recent past), so a step at minute 10 costs what it costs at minute 1.
    So up to its first END a stream computes exactly what `generate_tokens` computes: same tokens, same draws.
    Streams of a batch are independent (their contexts rebuild at different steps): each runs its own calls.
    """

    def __init__(self, backend: Backend, text_emb: np.ndarray, sampling: SamplingConfig, seeds: list[int],
                 window: int, refresh: int, min_tokens: int = 1):
        self.backend, self.sampling, self.window, self.refresh = backend, sampling, window, refresh
        self.min_tokens = min_tokens   # END allowed once a motion has this many tokens, as in generate_tokens
        self.rngs = make_rngs(seeds)
        self.batch = len(seeds)
        self.guided = sampling.guidance != 1.0
        # a ring of the last window + refresh picked tokens: token t sits at t % (window + refresh)
        self.history = np.zeros((self.batch, window + refresh, backend.dims.num_levels), np.int64)
        self.count = 0                            # tokens picked so far (every stream picks one per step)
        self.cached = [0] * self.batch            # motion tokens in each stream's cache (after the prefix)
        self.motion = [0] * self.batch            # tokens since each stream's motion (re)started
        self.past: list = [None] * self.batch     # None: the stream's next step rebuilds with nothing kept
        self.restarts = 0                         # motions ended by END and started again, over all streams
        self.set_prompt(text_emb)

    def set_prompt(self, text_emb: np.ndarray) -> None:
        """(B, text_dim) embeddings to follow from the next token on."""
        if text_emb.shape != (self.batch, self.backend.dims.text_dim):
            raise ValueError(f"expected ({self.batch}, {self.backend.dims.text_dim}) text embeddings, got "
                             f"{text_emb.shape}")
        # the unconditional branch is the all-zero text embedding the model was trained to see
        self.rows_emb = [np.concatenate([e, np.zeros_like(e)]) if self.guided else e for e in text_emb[:, None]]
        self.past = [None] * self.batch

    def step(self) -> np.ndarray:
        """-> the next tokens (B, L) of every stream."""
        picked = np.stack([self._step(b) for b in range(self.batch)])
        self.history[:, self.count % self.history.shape[1]] = self.last = picked
        self.count += 1
        return picked

    def _step(self, b: int) -> np.ndarray:
        dims = self.backend.dims
        for retry in (False, True):
            tokens, self.cached[b], fresh = context_tokens(
                self.history[b], self.count, self.cached[b], self.past[b] is None, self.window, self.refresh,
                dims.bos_id, self.last[b] if self.count else None)
            tokens = tokens[None]
            if fresh:
                if self.cached[b] == 0:
                    self.motion[b] = 0
                self.past[b] = self.backend.empty_past(len(self.rows_emb[b]))
            if self.guided:
                tokens = np.concatenate([tokens, tokens])
            logits, self.past[b] = self.backend.step(self.rows_emb[b], tokens, self.past[b])
            logits = logits[:, -1]                                              # (rows, L, K + 1)
            if self.guided:
                logits = apply_guidance(logits[:1], logits[1:], self.sampling.guidance)
            logits = np.array(logits, dtype=np.float32)                         # own copy: masked below
            logits[:, 1:, dims.end_id] = -np.inf      # only the coarsest stream may end the motion
            if retry or self.motion[b] < self.min_tokens:
                logits[:, 0, dims.end_id] = -np.inf
            picked = sample(logits, self.sampling, self.rngs[b:b + 1])[0]       # (L,)
            if picked[0] != dims.end_id:
                self.motion[b] += 1
                return picked
            self.past[b] = None                       # the motion ended: start the prompt again
            self.restarts += 1
        raise AssertionError("unreachable: END is forbidden on the retry")


def context_tokens(history: np.ndarray, count: int, cached: int, restart: bool, window: int, refresh: int,
                   bos_id: int, last: np.ndarray | None) -> tuple[np.ndarray, int, bool]:
    """What an endless stream feeds next (docs/bundle.md, "Endless streams"): -> (tokens (S, L), motion tokens
    cached after them, whether they start a fresh context). A fresh context is BOS and the last n picked tokens
    (`history`: a ring, token t at t % len): n = 0 after a new prompt or END (`restart`), `window` once the context
    holds window + refresh; otherwise the stream feeds its last pick."""
    if restart or cached == window + refresh:
        n = 0 if restart else window
        ring = (count - n + np.arange(n)) % len(history)                       # the last n, oldest first
        bos = np.full((1, history.shape[1]), bos_id, np.int64)
        return np.concatenate([bos, history[ring]]), n, True
    return last[None], cached + 1, False


def collect_tokens(steps: Iterator[tuple[np.ndarray, np.ndarray]], batch: int, num_levels: int):
    """Run the loop to the end: -> list of (T_b, L) token arrays, one per prompt."""
    out: list[list[np.ndarray]] = [[] for _ in range(batch)]
    for picked, alive in steps:
        for b in np.flatnonzero(alive):
            out[b].append(picked[b])
    return [np.stack(o) if o else np.zeros((0, num_levels), np.int64) for o in out]


def decode_tokens(backend: Backend, token_seqs: list[np.ndarray]) -> list[np.ndarray]:
    """All prompts through the decoder in one batch; the decoder is causal, so right padding is harmless."""
    T = max(len(s) for s in token_seqs)
    if T == 0:
        return [np.zeros((0, backend.dims.feature_dim), np.float32) for _ in token_seqs]
    batch = np.zeros((len(token_seqs), T, backend.dims.num_levels), np.int64)
    for b, seq in enumerate(token_seqs):
        batch[b, :len(seq)] = seq
    feats = backend.decode(batch)                                               # (B, T * ds, D)
    ds = backend.dims.downsample
    return [feats[b, :len(seq) * ds] for b, seq in enumerate(token_seqs)]


MAX_CHUNK = 1024   # tokens per decode; more only delays frames (and the window is allocated up front)


class FrameStreamer:
    """Turns tokens into frames as they arrive, decoding only the window the new frames depend on.

    The first token is decoded at once (time to first frame); later tokens are decoded `chunk` at a time,
    each decode reading receptive_field + chunk tokens. With chunk=1 every token re-decodes its whole
    receptive field (18 tokens for 4 new frames on `base`); chunk=4 measured 343 -> 217 ms for a 196-frame
    stream (benchmarks/NOTES.md, idea 3), its frames coming in bursts of chunk * downsample, well ahead of
    real time. Holds a fixed (B, window, L) ring of recent tokens: nothing the size of the motion.
    """

    def __init__(self, backend: Backend, batch: int, chunk: int = 1):
        if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or not 1 <= chunk <= MAX_CHUNK:
            raise ValueError(f"chunk must be an int in [1, {MAX_CHUNK}], got {chunk!r}")
        chunk = int(chunk)
        self.backend, self.chunk = backend, chunk
        self.window = backend.dims.receptive_field + chunk
        self.tokens = np.zeros((batch, self.window, backend.dims.num_levels), np.int64)
        self.count = 0    # tokens pushed
        self.pending = 0  # tokens pushed whose frames were not returned yet
        self._none = np.zeros((batch, 0, backend.dims.feature_dim), np.float32)  # "no frames yet", made once

    def push(self, picked: np.ndarray) -> np.ndarray:
        """picked (B, L) of the newest step -> features (B, n * downsample, D) of the frames now ready
        (n = 0 while a chunk fills up)."""
        self.tokens[:, :-1] = self.tokens[:, 1:]
        # A prompt that just ended carries END; decode a valid code in its place (its frames are dropped).
        self.tokens[:, -1] = np.where(picked < self.backend.dims.codebook_size, picked, 0)
        self.count += 1
        self.pending += 1
        if self.count > 1 and self.pending < self.chunk:
            return self._none
        return self.flush()

    def flush(self) -> np.ndarray:
        """The frames of every token pushed and not yet returned: call once the motion has ended."""
        if not self.pending:
            return self._none
        n = min(self.count, self.backend.dims.receptive_field + self.pending)
        feats = self.backend.decode(self.tokens[:, self.window - n:])           # (B, n * ds, D)
        out = feats[:, -self.pending * self.backend.dims.downsample:]
        self.pending = 0
        return out


@dataclass
class Generated:
    """One prompt's result: its tokens, their decoded features and the joints they give."""

    tokens: np.ndarray      # (T, L) int64
    features: np.ndarray    # (T * downsample, D) de-normalised
    joints: np.ndarray      # (T * downsample, J, 3) metres, y up


@dataclass
class GenerationTask:
    """The generation recipe for one backend and one set of settings: prompts' embeddings and seeds in,
    tokens, features and joints out, all at once (`run`, `timeline`) or frame by frame (`stream`).

    `fixed_tokens` fixes the length; None lets the model end each motion, at most `max_tokens`. Without
    `streaming` a fixed length never chooses END. With it (a bundle trained for endless streams), fixed lengths
    and streams run the EndlessLoop: any length, bounded context, END restarts the prompt.
    """

    backend: Backend
    sampling: SamplingConfig
    max_tokens: int
    fixed_tokens: int | None = None
    streaming: StreamingSpec | None = None

    @property
    def num_joints(self) -> int:
        return (self.backend.dims.feature_dim + 1) // 12     # HumanML3D layout: D = 12 J - 1

    def loop(self, text_emb: np.ndarray, seeds: list[int]) -> EndlessLoop:
        if self.streaming is None:
            raise ValueError("this bundle was not trained for endless streams (its manifest has no 'streaming' "
                             "section): re-export it from checkpoints trained on data with timed captions")
        return EndlessLoop(self.backend, text_emb, self.sampling, seeds, self.streaming.window, self.streaming.refresh)

    def steps(self, text_emb: np.ndarray, seeds: list[int],
              loop: EndlessLoop | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        if loop is None and self.streaming is not None and self.fixed_tokens is not None:
            loop = self.loop(text_emb, seeds)
        if loop is None:
            return generate_tokens(self.backend, text_emb, self.sampling, make_rngs(seeds), self.max_tokens,
                                   self.fixed_tokens)
        alive = np.ones(len(seeds), bool)
        return ((loop.step(), alive) for _ in (itertools.count() if self.fixed_tokens is None
                                               else range(self.fixed_tokens)))

    def tokens(self, text_emb: np.ndarray, seeds: list[int],
               progress: Callable[[int, int], None] | None = None) -> list[np.ndarray]:
        """-> one (T_b, L) token array per prompt. `progress(step, limit)` is called after every step."""
        return self._collect(self.steps(text_emb, seeds), len(seeds), progress)

    def _collect(self, steps, batch: int, progress) -> list[np.ndarray]:
        if progress is not None:
            steps = _report(steps, progress, self.fixed_tokens or self.max_tokens)
        return collect_tokens(steps, batch, self.backend.dims.num_levels)

    def run(self, text_emb: np.ndarray, seeds: list[int],
            progress: Callable[[int, int], None] | None = None) -> list[Generated]:
        return self._decoded(self.tokens(text_emb, seeds, progress))

    def timeline(self, text_embs: np.ndarray, starts: list[int], seed: int,
                 progress: Callable[[int, int], None] | None = None) -> Generated:
        """One character following prompt i (text_embs[i]) from token starts[i] on (starts[0] = 0)."""
        loop = self.loop(text_embs[:1], [seed])
        switch_at = dict(zip(starts[1:], range(1, len(starts))))

        def steps():
            for t, item in enumerate(self.steps(text_embs[:1], [seed], loop)):
                yield item
                if t + 1 in switch_at:
                    loop.set_prompt(text_embs[switch_at[t + 1]][None])
        return self._decoded(self._collect(steps(), 1, progress))[0]

    def _decoded(self, token_seqs: list[np.ndarray]) -> list[Generated]:
        return [Generated(tok, f, FootLock(self.num_joints).push(recover_from_ric(f, self.num_joints), f))
                for tok, f in zip(token_seqs, decode_tokens(self.backend, token_seqs))]

    def stream(self, text_emb: np.ndarray, seed: int, chunk: int = 4,
               loop: EndlessLoop | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """One prompt's frames as its tokens are sampled: yields (features (n, D), joints (n, J, 3)), n >= 1.
        With `loop` (an EndlessLoop of this prompt) the stream follows that loop's prompt changes."""
        streamer = FrameStreamer(self.backend, 1, chunk)     # checks chunk now, not at the first frame
        return self._stream(self.steps(text_emb, [seed], loop), streamer)

    def _stream(self, steps, streamer: FrameStreamer):
        integrator, lock = RootIntegrator(self.num_joints), FootLock(self.num_joints)
        for picked, alive in steps:
            if not alive[0]:
                break
            features = streamer.push(picked)[0]
            if len(features):
                yield features, lock.push(integrator.push(features), features)
        features = streamer.flush()[0]
        if len(features):
            yield features, lock.push(integrator.push(features), features)


def _report(steps, progress: Callable[[int, int], None], limit: int):
    for t, item in enumerate(steps):
        yield item
        progress(t + 1, limit)
