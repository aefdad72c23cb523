"""Endless streams: the token state of a stream that never ends by itself, follows a new prompt from the next
token and keeps a bounded context (docs/bundle.md, "Endless streams"), and `EndlessLoop`, a batch of them.

A stream's context is its prompt's prefix (BOS) plus motion tokens, rebuilt (fed from an empty cache as
[BOS, kept tokens]) on three events:
- a new prompt: nothing kept, so the prompt starts a motion as it would alone, from the next token; the causal
  decoder joins it to the frames before. Kept tokens of the old action are continued, not left: on `base`, keeping
  1 or 2 tokens gave per-segment accuracy 0.87 or 0.78, keeping none 0.95 (README, "Endless streams, measured").
- END picked by the coarsest level, where `generate` would end the motion: the same prompt starts again, nothing
  kept, and the step picks again from the rebuilt context (END cannot be picked as a motion's first token), so an
  action is held by repeating it as the model ends it instead of running past the lengths it was trained on
  (per-segment accuracy 0.51 -> 0.78 on an earlier `base`).
- a full context (window + refresh motion tokens) already compacted COMPACTIONS times since it was last rebuilt: the
  last `window` are kept (a motion longer than that goes on from its recent past), so a step at minute 10 costs
  what it costs at minute 1.
Before that, a full context is **compacted** instead: its prefix and its last window - 1 cached steps stay in the
cache as they were computed (moved to slots 1 .. window - 1) and the newest pick is fed at slot `window`, one step
row where a rebuild feeds window + 1. Kept slots were computed attending to the steps dropped,
as Transformer-XL's memory is; on `base` that changed neither the control benchmark nor endless single-prompt
accuracy (0.8209 / 0.8203 rebuilt / compacted over 2-minute streams), and took a steady crowd's step rows from
1.25 to 1.03 a character-token (benchmarks/NOTES.md, "compacting the context"). After COMPACTIONS of them the next
full context is rebuilt, so a restored stream (state.py) replays at most `keep` tokens to reach the same numbers.
So up to its first END or compaction a stream computes exactly what `decoding.generate_tokens` computes: same tokens,
same draws.
`StreamContext` is one stream's state; the loop that feeds it is `EndlessLoop` (each stream its own step calls, on
any backend) or a crowd (every character's step in one call, crowd.py).
"""
from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np

from .bundle.sections import StreamingSpec
from .clock import NO_CLOCK
from .policy import StepPolicy

COMPACTIONS = 3     # compactions of a full context before it is rebuilt (module docstring)


class Feed(NamedTuple):
    """What a stream's next step feeds: `tokens` (S, L) and their `controls` (S, control_dim) or None without control,
    written at cache `slots` (S,), on an empty cache when `fresh`; `compact` (S,) says where the cache is compacted
    (`StreamContext.compaction`) before that position is fed."""
    tokens: np.ndarray
    controls: np.ndarray | None
    fresh: bool
    slots: np.ndarray
    compact: np.ndarray


class StreamContext:
    """One endless stream's token state: the step rows it is conditioned on, its random generator, its recent
    tokens, and what its next step feeds (`plan`), given the pick it then `accept`s."""

    def __init__(self, policy: StepPolicy, emb: np.ndarray, seed: int, spec: StreamingSpec, control_dim: int = 0,
                 limits: list[int | None] | None = None):
        self.policy, self.window, self.span = policy, spec.window, spec.window + spec.refresh
        # the tokens a context's numbers depend on, plus the newest pick: what a restored stream replays at most
        self.keep = self.span + COMPACTIONS * (spec.refresh + 1)
        self.rng = np.random.Generator(np.random.PCG64(seed))
        self.history = np.zeros((self.keep, policy.dims.num_levels), np.int64)   # token t at t % keep
        # with control (a model that has it): the control each token was picked with, as the history holds tokens,
        # so a rebuilt context reads what it read the first time; and the control of the next token (`steer`)
        self.controls = np.zeros((self.keep, control_dim), np.float32) if control_dim else None
        self.control = np.zeros(control_dim, np.float32) if control_dim else None
        self.last: np.ndarray | None = None      # the last token picked
        self.count = 0                           # tokens picked
        self.cached = 0                          # motion tokens in the context after its prefix
        self.compactions = 0                     # of the context since it was last fed from an empty cache
        self.motion = 0                          # tokens since the motion (re)started
        self.restarts = 0                        # motions ended by END and started again
        self.resume = False                      # a restored stream (state.py): its next step feeds its context again
        self.condition(emb, limits)

    def condition(self, emb: np.ndarray, limits: list[int | None] | None = None) -> None:
        """Follow the prompt of embeddings `emb` (P, text_dim) from the next token on; nothing is kept. P > 1: a
        prompt of several actions (plan.py), played in order, action i for limits[i] tokens, or (None) until the model
        ends it, at most the longest motion the model was trained on; the last one is then held as a prompt of one
        action is: by restarting it at END."""
        limits = list(limits or [None] * len(emb))
        if len(limits) != len(emb) or not len(emb):
            raise ValueError(f"{len(emb)} actions but {len(limits)} limits")
        self.parts, self.limits = list(emb), limits
        self.part, self.finished_at = 0, None   # the action played; the token count when the last one first ended
        self.starts = [self.count]              # the token each action started at
        self._start_part()

    def _start_part(self) -> None:
        self.rows_emb = self.policy.condition(self.parts[self.part][None])     # (rows, text_dim)
        self.restart, self.in_part = True, 0

    def _part_over(self) -> bool:
        """The action played has run its course (stated duration, or as long as the model's longest motion);
        a lone action runs until the model ends it."""
        limit = self.limits[self.part]
        if limit is None and self.part + 1 < len(self.parts):
            limit = self.policy.dims.max_tokens
        return limit is not None and self.in_part >= limit

    def _next_part(self) -> None:
        if self.part + 1 < len(self.parts):
            self.part += 1
            self.starts.append(self.count)
        elif self.finished_at is None:
            self.finished_at = self.count
        self._start_part()

    @property
    def finished(self) -> bool:
        """Whether the last action has ended once (it is then held, started again as the model ends it)."""
        return self.finished_at is not None

    @property
    def may_end(self) -> bool:
        """END may be picked once the motion has a token: never as a motion's first, so never twice in a row."""
        return self.motion >= 1

    def steer(self, control: np.ndarray) -> None:
        """The control vector (control_dim,) the next token is picked with (mogo_runtime/control)."""
        self.control = np.asarray(control, np.float32)

    @property
    def compaction(self) -> tuple[int, int]:
        """(first, count): a compaction moves cache slots first .. first + count - 1 (the last window - 1 of a full
        context) to slots 1 .. count; slot 0, the prefix, stays."""
        return self.span - self.window + 2, self.window - 1

    def plan(self) -> Feed:
        """What the next step feeds. A new context is BOS and the last n picked tokens: n = 0 after a new prompt or
        END, `window` once the context holds window + refresh tokens for the COMPACTIONS + 1-th time; otherwise the
        step feeds the last pick, after compacting a full context. Position i of a new context picks token
        count - n + i, so it reads that token's control (the last: `control`). The last token fed sits in cache slot
        `self.cached`. A restored stream (`resume`) replays the tokens its context's numbers came from, from an empty
        cache and compacting where it did, to where the step it would have made puts it: the same slots, the same
        numbers."""
        resume, self.resume = self.resume and not self.restart, False
        rebuild = self.restart or (self.cached == self.span and self.compactions == COMPACTIONS)
        if not (resume or rebuild):
            slot, compact = self._advance()
            return Feed(self.last[None], None if self.control is None else self.control[None], False,
                        np.array([slot]), np.array([compact]))
        if rebuild:
            n = 0 if self.restart else self.window
            self.cached, self.compactions, self.restart = n, 0, False
            if n == 0:
                self.motion = 0
            slots, compact = np.arange(n + 1), np.zeros(n + 1, bool)
        else:       # replay: every token since the context was last new, then the last pick
            n = self.cached + self.compactions * (self.span - self.window + 1) + 1
            self.cached, self.compactions = 0, 0
            slots, compact = np.zeros(n + 1, np.int64), np.zeros(n + 1, bool)
            for i in range(1, n + 1):
                slots[i], compact[i] = self._advance()
        ring = (self.count - n + np.arange(n)) % self.keep                     # the last n, oldest first
        bos = np.full((1, self.history.shape[1]), self.policy.dims.bos_id, np.int64)
        controls = None if self.control is None else np.concatenate([self.controls[ring], self.control[None]])
        return Feed(np.concatenate([bos, self.history[ring]]), controls, True, slots, compact)

    def _advance(self) -> tuple[int, bool]:
        """One more token fed to the context -> (its slot, whether the context is compacted first)."""
        if self.cached == self.span:
            self.cached, self.compactions = self.window, self.compactions + 1
            return self.cached, True
        self.cached += 1
        return self.cached, False

    def accept(self, picked: np.ndarray) -> bool:
        """The step's pick (L,) -> whether it is the stream's next token. END (level 0) is not: the motion ended, the
        prompt starts again with nothing kept, and the stream's step plans and picks again."""
        if picked[0] == self.policy.dims.end_id:
            if self.limits[self.part] is None and self.part + 1 < len(self.parts):
                self._next_part()               # the action ended: the next one starts
            else:                               # the last action, or one held for its stated duration, starts again
                self.restarts += 1
                self.restart = True
                if self.part + 1 == len(self.parts) and self.finished_at is None and self.limits[self.part] is None:
                    self.finished_at = self.count
            return False
        self.history[self.count % self.keep] = self.last = picked
        if self.controls is not None:
            self.controls[self.count % self.keep] = self.control
        self.count += 1
        self.motion += 1
        self.in_part += 1
        if self._part_over():
            self._next_part()
        return True


class EndlessLoop:
    """A batch of endless streams, each stepped with its own calls (their contexts rebuild at different steps), on
    any backend: `step()` gives every stream its next token."""

    def __init__(self, backend, text_emb: np.ndarray, sampling, seeds: list[int], spec: StreamingSpec,
                 clock=None):
        self.backend, self.policy, self.clock = backend, StepPolicy(sampling, backend.dims), clock or NO_CLOCK
        control_dim = backend.control.dim if backend.control else 0
        self.streams = [StreamContext(self.policy, e[None], s, spec, control_dim) for e, s in zip(text_emb, seeds)]
        self.past: list = [None] * len(self.streams)
        self._lock = threading.Lock()     # a step and a prompt switch never interleave

    @property
    def count(self) -> int:
        """Tokens picked so far by each stream."""
        return self.streams[0].count

    @property
    def restarts(self) -> int:
        """Motions ended by END and started again, over all streams."""
        return sum(s.restarts for s in self.streams)

    def set_prompt(self, text_emb: np.ndarray) -> int:
        """(B, text_dim) embeddings to follow from the next token on; -> that token's index. Called from another
        thread while a step runs, it waits for the step: the switch lands at the next token either way."""
        if text_emb.shape != (len(self.streams), self.backend.dims.text_dim):
            raise ValueError(f"expected ({len(self.streams)}, {self.backend.dims.text_dim}) text embeddings, got "
                             f"{text_emb.shape}")
        with self._lock:
            for stream, emb in zip(self.streams, text_emb):
                stream.condition(emb[None])
            return self.count

    def set_actions(self, text_emb: np.ndarray, limits: list[int | None]) -> int:
        """A one-stream loop's stream plays the actions of embeddings (P, text_dim) in order from the next token on,
        action i for limits[i] tokens or (None) until the model ends it (StreamContext.condition); -> that token's
        index. Thread-safe as set_prompt."""
        if len(self.streams) != 1:
            raise ValueError(f"set_actions() steers a loop of one stream, this one has {len(self.streams)}")
        with self._lock:
            self.streams[0].condition(text_emb, limits)
            return self.count

    def step(self) -> np.ndarray:
        """-> the next tokens (B, L) of every stream."""
        with self._lock:
            return np.stack([self._step(b, s) for b, s in enumerate(self.streams)])

    def _step(self, b: int, stream: StreamContext) -> np.ndarray:
        for _ in range(2):             # a pick of END is picked again from the restarted context, END forbidden
            feed = stream.plan()        # a loop's streams are never restored: a compaction comes only before one token
            if feed.fresh:
                self.past[b] = self.backend.empty_past(self.policy.rows)
            elif feed.compact[0]:
                self.past[b] = self.backend.compact(self.past[b], *stream.compaction)
            controls = None if feed.controls is None else self.policy.feed(feed.controls[None])
            with self.clock("step"):
                logits, self.past[b] = self.backend.step(stream.rows_emb, self.policy.feed(feed.tokens[None]),
                                                         self.past[b], controls)
            with self.clock("sample"):
                picked = self.policy.pick(logits[:, -1], np.array([stream.may_end]), [stream.rng])[0]
            if stream.accept(picked):
                return picked
        raise AssertionError("unreachable: END is forbidden as a motion's first token")
