"""The generation recipe, written once for every backend (torch reference, onnxruntime) and every caller (the API,
the parity verifier, evaluation).

A backend computes; the loop decides. Per step the backend's transformer step emits the logits of every
quantizer level for the next time step (all L level streams in one pass); the step policy (policy.py) picks the
tokens; the level-0 stream choosing END stops a clip (`generate_tokens`), or restarts an endless stream's prompt
(endless.py). Frames come from the causal motion decoder, either once at the end (`decode_tokens`) or as tokens
arrive (`FrameMaker`): from the decoder's state (a bundle's decoder_step graph) or, without one, by decoding a window
of the last `receptive_field + 1` tokens, on which a frame alone depends; the same frames within float32 rounding.

`GenerationTask` is the whole recipe (seeds -> token loop -> tokens -> features -> joints), at once or as a stream.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable, Iterator, Protocol

import numpy as np

from .bundle.sampling import SamplingConfig
from .bundle.sections import ModelDims, StreamingSpec
from .checks import as_int
from .clock import NO_CLOCK, StageClock
from .control.steering import Steering
from .endless import EndlessLoop
from .kinematics.features import recover_from_ric
from .kinematics.frames import FootLock, FrameJoints
from .kinematics.skeleton import Skeleton
from .policy import StepPolicy, make_rngs

MAX_CHUNK = 1024   # tokens per decode; more only delays frames (and the window is allocated up front)


class Backend(Protocol):
    """What the loop needs from an inference engine (engine.py; mogo_export.reference for torch). Arrays are numpy;
    past is opaque to the loop. step: tokens (B, S, L) -> (logits (B, S, L, K + 1), new past); decode: tokens
    (B, T, L) -> de-normalised features (B, T * downsample, feature_dim), codebook lookup and causal decoder."""

    dims: ModelDims

    def encode_text(self, texts: list[str]) -> np.ndarray: ...                 # (B, text_dim) float32

    def empty_past(self, rows: int): ...                                          # rows: step rows of the batch

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past): ...

    def compact(self, past, first: int, count: int): ...    # past with slots first.. moved to 1..count (endless.py)

    def decode(self, tokens: np.ndarray) -> np.ndarray: ...

    # with a decoder_step graph: its state's [reach, channels] shapes, and decode_step (engine.MotionDecoder); the
    # torch reference has None and decodes windows
    decoder_state: tuple[tuple[int, int], ...] | None


def generate_tokens(backend: Backend, text_emb: np.ndarray, sampling: SamplingConfig,
                    rngs: list[np.random.Generator], max_tokens: int, fixed_tokens: int | None = None,
                    clock: StageClock = NO_CLOCK) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield (tokens (B, L), alive (B,) bool) once per time step, until every prompt has ended.

    `alive[b]` is False from the step where prompt b chose END (its tokens that step are meaningless).
    With `fixed_tokens` END is forbidden and every prompt runs exactly that many steps.
    """
    dims, policy = backend.dims, StepPolicy(sampling, backend.dims)
    B = len(text_emb)
    rows_emb = policy.condition(text_emb)
    tokens = np.full((B * policy.rows, 1, dims.num_levels), dims.bos_id, dtype=np.int64)
    past = backend.empty_past(B * policy.rows)
    alive = np.ones(B, dtype=bool)
    for t in range(fixed_tokens if fixed_tokens is not None else max_tokens):
        with clock("step"):
            logits, past = backend.step(rows_emb, tokens, past)
        with clock("sample"):
            picked = policy.pick(logits[:, -1], np.full(B, fixed_tokens is None and t >= 1), rngs)    # (B, L)
        alive &= picked[:, 0] != dims.end_id
        yield picked, alive.copy()
        if not alive.any():
            return
        # Ended prompts keep feeding a valid code; their rows are independent and their output is ignored.
        tokens = policy.feed(np.where(alive[:, None], picked, 0)[:, None])


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


def check_chunk(chunk: int) -> int:
    """Tokens per decode: an int in [1, MAX_CHUNK], else ValueError."""
    return as_int("chunk", chunk, f"an int in [1, {MAX_CHUNK}]", 1, MAX_CHUNK)


@dataclass
class Frames:
    """A stream's new frames: frame numbers index .. index + n - 1 of its motion."""

    index: int
    features: np.ndarray     # (n, D) de-normalised
    joints: np.ndarray       # (n, J, 3) metres, y up


class FrameMaker:
    """One stream's tokens -> its frames as they come: the causal decoder, then joints integrated frame by frame
    (kinematics.frames.FrameJoints).

    The first token is decoded at once (time to first frame); later tokens `chunk` at a time. With `decoder_state`
    (the shapes of a decoder_step graph's state) each decode feeds the new tokens alone and carries the decoder's
    state: a token's frames cost the same at any chunk, and are the same bits at any chunk. Without it, each decode
    reads a window of receptive_field + chunk tokens: with chunk=1 every token re-decodes its whole receptive field
    (18 tokens for 4 new frames on `base`), chunk=4 measured 343 -> 217 ms for a 196-frame stream
    (benchmarks/NOTES.md, idea 3). Holds a fixed window of recent tokens: nothing the size of the motion. The caller
    runs the decoder (`decode_due`), so a crowd decodes many streams in one call.
    """

    def __init__(self, dims: ModelDims, skeleton: Skeleton, chunk: int = 1,
                 decoder_state: tuple[tuple[int, int], ...] | None = None):
        self.dims, self.chunk = dims, check_chunk(chunk)
        # the decoder_step graph's state, zeros at a motion's start (the left padding of a whole-motion decode), as
        # (arrays, row): row `row` of the state arrays of a decode of many streams (its outputs, kept as they are: a
        # crowd that decodes the same streams in the same order next passes them back without a copy)
        self._shapes = decoder_state
        self._state = None if decoder_state is None else ([np.zeros((1, *s), np.float32) for s in decoder_state], 0)
        self.tokens = np.zeros((dims.receptive_field + self.chunk, dims.num_levels), np.int64)
        self.count = 0      # tokens pushed
        self.pending = 0    # tokens pushed whose frames were not made yet
        self.frames = 0     # frames made
        self.joints = FrameJoints(skeleton)

    @property
    def state(self) -> list[np.ndarray] | None:
        """The decoder_step graph's state (one array per state input, [reach, channels]), or None without one."""
        if self._state is None:
            return None
        arrays, row = self._state
        return [a[row] for a in arrays]

    @state.setter
    def state(self, arrays: list[np.ndarray]) -> None:
        sizes = [r * c for r, c in self._shapes or ()]
        if self._state is None or [np.size(a) for a in arrays] != sizes:
            raise ValueError(f"a decoder state of {len(sizes)} arrays of {sizes} values, got "
                             f"{[np.size(a) for a in arrays]}")
        self._state = ([np.asarray(a, np.float32).reshape(1, *s).copy() for a, s in zip(arrays, self._shapes)], 0)

    def push(self, picked: np.ndarray) -> int:
        """The stream's next token (L,) -> how many tokens to decode now (`due`)."""
        self.tokens[:-1] = self.tokens[1:]
        self.tokens[-1] = picked
        self.count += 1
        self.pending += 1
        return self.due()

    def due(self, final: bool = False) -> int:
        """Tokens to decode for the frames now ready, 0 while a chunk fills up; `final`: the stream ends, so every
        pending token's frames are due."""
        if not self.pending or not (final or self.count == 1 or self.pending >= self.chunk):
            return 0
        return self.pending if self._state is not None else min(self.count, self.dims.receptive_field + self.pending)

    def window(self, n: int) -> np.ndarray:
        """The last n tokens (n, L), oldest first: the decoder's input for the frames due."""
        return self.tokens[len(self.tokens) - n:]

    def frames_from(self, features: np.ndarray, clock: StageClock = NO_CLOCK) -> Frames:
        """The decoder's features for the n tokens due (`decode_due`) -> the new frames (the pending tokens')."""
        return FrameMaker.frames_many([self], features[None], clock)[0]

    @staticmethod
    def frames_many(makers: list["FrameMaker"], features: np.ndarray, clock: StageClock = NO_CLOCK) -> list[Frames]:
        """`frames_from` for many streams at once (decode_due's features (B, n * downsample, D)), their joints in
        one batch per number of pending tokens: the same numbers as one by one."""
        out: list[Frames | None] = [None] * len(makers)
        ds = makers[0].dims.downsample
        groups: dict[int, list[int]] = {}
        for b, m in enumerate(makers):
            groups.setdefault(m.pending, []).append(b)
        for pending, members in groups.items():
            new = features[members, features.shape[1] - pending * ds:]
            with clock("joints"):
                joints = FrameJoints.push_many([makers[b].joints for b in members], new)
            for k, b in enumerate(members):
                m = makers[b]
                out[b] = Frames(m.frames, new[k], joints[k])
                m.frames += len(new[k])
                m.pending = 0
        return out


def decode_due(decoder: Backend, makers: list[FrameMaker], n: int) -> np.ndarray:
    """The features of the `n` tokens due (FrameMaker.due) of each of `makers`, in one decoder call: (B, n *
    downsample, D). From each maker's decoder state, which moves on (decoder_step), else from its window."""
    tokens = np.stack([m.window(n) for m in makers])
    if makers[0]._state is None:
        return decoder.decode(tokens)
    last = makers[0]._state[0]
    if len(last[0]) == len(makers) and all(m._state[0] is last and m._state[1] == b for b, m in enumerate(makers)):
        state = last        # the streams of the last call, in its order: its outputs are the inputs
    else:
        state = [np.stack([m._state[0][i][m._state[1]] for m in makers]) for i in range(len(last))]
    features, state = decoder.decode_step(tokens, state)
    for b, m in enumerate(makers):
        m._state = (state, b)
    return features


@dataclass
class Generated:
    """One prompt's result: its tokens, their decoded features and the joints they give."""

    tokens: np.ndarray      # (T, L) int64
    features: np.ndarray    # (T * downsample, D) de-normalised
    joints: np.ndarray      # (T * downsample, J, 3) metres, y up
    starts: list[int] | None = None     # a prompt of several actions: the token each started at


@dataclass
class GenerationTask:
    """The generation recipe for one backend and one set of settings: prompts' embeddings and seeds in,
    tokens, features and joints out, all at once (`run`, `timeline`) or frame by frame (`stream`).

    `fixed_tokens` fixes the length; None lets the model end each motion, at most `max_tokens`. Without
    `streaming` a fixed length never chooses END. With it (a bundle trained for endless streams), fixed lengths
    and streams run the EndlessLoop: any length, bounded context, END restarts the prompt. `clock` adds up the
    time of each stage (clock.py).
    """

    backend: Backend
    skeleton: Skeleton
    sampling: SamplingConfig
    max_tokens: int
    fixed_tokens: int | None = None
    streaming: StreamingSpec | None = None
    clock: StageClock = NO_CLOCK

    def loop(self, text_emb: np.ndarray, seeds: list[int]) -> EndlessLoop:
        if self.streaming is None:
            raise ValueError("this bundle was not trained for endless streams (its manifest has no 'streaming' "
                             "section): re-export it from checkpoints trained on data with timed captions")
        return EndlessLoop(self.backend, text_emb, self.sampling, seeds, self.streaming, self.clock)

    def steps(self, text_emb: np.ndarray, seeds: list[int],
              loop: EndlessLoop | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        if loop is None and self.streaming is not None and self.fixed_tokens is not None:
            loop = self.loop(text_emb, seeds)
        if loop is None:
            return generate_tokens(self.backend, text_emb, self.sampling, make_rngs(seeds), self.max_tokens,
                                   self.fixed_tokens, self.clock)
        alive = np.ones(len(seeds), bool)
        return ((loop.step(), alive) for _ in (itertools.count() if self.fixed_tokens is None
                                               else range(self.fixed_tokens)))

    def tokens(self, text_emb: np.ndarray, seeds: list[int],
               progress: Callable[[int, int], None] | None = None) -> list[np.ndarray]:
        """-> one (T_b, L) token array per prompt. `progress(step, limit)` is called after every step."""
        return self._collect(self.steps(text_emb, seeds), len(seeds), progress)

    def _collect(self, steps, batch: int, progress, most: int | None = None) -> list[np.ndarray]:
        most = most or self.fixed_tokens or self.max_tokens
        if progress is not None:        # called as each step's tokens are handed on
            steps = (progress(t + 1, most) or item for t, item in enumerate(steps))
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

    def actions(self, text_embs: np.ndarray, limits: list[int | None], seed: int,
                progress: Callable[[int, int], None] | None = None) -> Generated:
        """One character playing the actions of text_embs (P, text_dim) in order (endless.StreamContext.condition):
        until the last one ends (END, or its stated length; at most as long as every action's limit, or the model's
        longest motion, added up), or for `fixed_tokens` exactly (the last action held)."""
        loop = self.loop(text_embs[:1], [seed])
        loop.set_actions(text_embs, limits)
        stream, alive = loop.streams[0], np.ones(1, bool)
        most = self.fixed_tokens or sum(n or self.max_tokens for n in limits)

        def steps():
            for _ in range(most):
                picked = loop.step()
                if self.fixed_tokens is None and stream.finished and stream.count > stream.finished_at:
                    return          # the last action ended (END) and this pick started it again
                yield picked, alive
                if self.fixed_tokens is None and stream.finished:
                    return
        out = self._decoded(self._collect(steps(), 1, progress, most))[0]
        out.starts = [t for t in stream.starts if t < len(out.tokens)]
        return out

    def _decoded(self, token_seqs: list[np.ndarray]) -> list[Generated]:
        with self.clock("decode"):
            features = decode_tokens(self.backend, token_seqs)
        J = self.skeleton.num_joints
        with self.clock("joints"):
            return [Generated(tok, f, FootLock(self.skeleton).push(recover_from_ric(f, J), f))
                    for tok, f in zip(token_seqs, features)]

    def stream(self, text_emb: np.ndarray, seed: int, chunk: int = 4, loop: EndlessLoop | None = None,
               steering: Steering | None = None) -> Iterator[Frames]:
        """One prompt's frames as its tokens are sampled, a chunk at a time. With `loop` (an EndlessLoop of this
        prompt) the stream follows that loop's prompt changes; with `steering` (of that loop's stream) it goes where
        the steering's target leads, and makes its frames every token while it has a target."""
        # checks chunk now, not at the first frame
        maker = FrameMaker(self.backend.dims, self.skeleton, chunk, self.backend.decoder_state)
        return self._stream(self.steps(text_emb, [seed], loop), maker, steering)

    def _stream(self, steps, maker: FrameMaker, steering: Steering | None = None) -> Iterator[Frames]:
        for picked, alive in steps:
            if not alive[0]:
                break
            if steering is not None and steering.target is not None:
                maker.chunk = 1             # the next token's control reads the pose the frames so far fix
            n = maker.push(picked[0])
            if n:
                yield self._frames(maker, n, steering)
        n = maker.due(final=True)
        if n:
            yield self._frames(maker, n, steering)

    def _frames(self, maker: FrameMaker, n: int, steering: Steering | None = None) -> Frames:
        with self.clock("decode"):
            features = decode_due(self.backend, [maker], n)[0]
        frames = maker.frames_from(features, self.clock)
        if steering is not None:
            steering.update(frames.index + len(frames.joints), maker.joints)
        return frames

