"""Many characters, one loop: a crowd steps every character's endless stream with one batched step call per tick.

    gen = MotionGenerator("bundles/base", variant="portable")
    crowd = Crowd(gen)
    walker = crowd.add("a person walks forward", seed=1)
    waver = crowd.add("a person waves", seed=2, seconds=12)        # leaves the crowd after 12 s of motion
    while crowd:
        for character, frames in crowd.tick().items():             # each character's new frames, if any
            send_to_game(character.id, frames.joints)              # (n, J, 3) metres, y up
        if some_event:
            walker.set_prompt("a person turns left")                # from this character's next token
    crowd.remove(walker)

A tick gives every character one more token. Each character runs the endless-stream recipe of
`decoding.EndlessLoop` (context rebuilds, END restarting the prompt, a prompt switch keeping nothing, one draw per
level from its own generator) and decodes in the windows of `decoding.FrameStreamer`, so its tokens and frames are
bit for bit what `gen.stream(prompt, seed=seed)` gives it alone, whoever else is in the crowd
(tests/runtime/test_crowd.py). That rests on the graphs computing each row on its own, which was checked on
`base`: a row's logits and decoded features are identical alone and in a batch of 24.

The step graph must be the fixed-capacity one (variant `portable`, or `int8_fixed`: the same graph in int8 with one
activation scale per row, where per-tensor int8 would make a character's numbers depend on its neighbours): each
row carries its own `position`, so characters at different points of their contexts share one call. A context rebuild (every `refresh` tokens, at END
and at a prompt switch) feeds its tokens one call each; the characters rebuilding in the same tick share those
calls, and every character's last token of the tick goes into one final call over the whole crowd.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .decoding import context_tokens, expand_seeds, make_rngs
from .engine import FixedCacheBackend
from .motion import FootLock, RootIntegrator
from .sampling import SamplingConfig, apply_guidance, sample
from .text import check_texts

if TYPE_CHECKING:
    from .generator import MotionGenerator

SWITCH_HISTORY = 10_000   # prompt switches kept per character, as FrameStream keeps them


@dataclass
class Frames:
    """One character's frames from one tick: frame numbers index .. index + n - 1 of its motion."""

    index: int
    features: np.ndarray     # (n, D) de-normalised
    joints: np.ndarray       # (n, J, 3) metres, y up


class Character:
    """One member of a crowd: its prompt, generator and the state of its stream. Made by `Crowd.add`."""

    def __init__(self, crowd: "Crowd", ident: int, text: str, emb: np.ndarray, seed: int, limit: int | None):
        dims = crowd.dims
        self.crowd, self.id, self.text, self.seed, self.limit = crowd, ident, text, seed, limit
        self.slot: int | None = None        # its place in the crowd (rows slot * per ...), None once removed
        self.rng = make_rngs([seed])[0]
        self._condition(emb)
        span = crowd.window + crowd.refresh
        self.history = np.zeros((span, dims.num_levels), np.int64)   # token t at t % span, as EndlessLoop
        self.last = np.zeros(dims.num_levels, np.int64)
        self.count = 0            # tokens picked
        self.motion = 0           # tokens since the motion (re)started
        self.cached = 0           # motion tokens in the context after its prefix
        self.length = 0           # steps in the cache (the next one is written at slot `length`)
        self.rebuild = True       # the next token starts a context with nothing kept
        self.restarts = 0
        self.decoded = np.zeros((crowd.decode_window, dims.num_levels), np.int64)  # FrameStreamer's ring
        self.pending = 0          # tokens whose frames were not returned yet
        self.frames = 0           # frames returned
        self.integrator, self.lock = RootIntegrator(crowd.num_joints), FootLock(crowd.num_joints)
        self.switches: deque[tuple[int, str]] = deque(maxlen=SWITCH_HISTORY)

    def _condition(self, emb: np.ndarray) -> None:
        # the unconditional branch is the all-zero text embedding the model was trained to see
        self.rows_emb = np.concatenate([emb, np.zeros_like(emb)]) if self.crowd.guided else emb

    @property
    def done(self) -> bool:
        return self.limit is not None and self.count >= self.limit

    def set_prompt(self, text: str) -> None:
        """Follow `text` from this character's next token on (frames already decoded are not changed)."""
        if not isinstance(text, str):
            raise ValueError(f"set_prompt() takes one prompt (str), got {type(text).__name__}")
        self._condition(self.crowd.backend.encode_text(check_texts([text])))
        self.text, self.rebuild = text, True
        self.switches.append((self.count, text))

    def __repr__(self) -> str:
        return f"Character({self.id}, {self.text!r}, seed={self.seed}, tokens={self.count})"


class Crowd:
    """Characters that come and go, stepped together: `tick()` advances every one by a token.

    `sampling`: one SamplingConfig for the crowd (default the bundle's). `chunk`: tokens per decode after the
    first, as `MotionGenerator.stream`'s.
    """

    def __init__(self, gen: "MotionGenerator", sampling: SamplingConfig | None = None, chunk: int = 4):
        fixed = getattr(gen.backend, "inner", gen.backend)        # under RowByRow when the text encoder is int8
        if not isinstance(fixed, FixedCacheBackend) or "step" in getattr(gen.backend, "graphs", ()):
            raise ValueError(f"a crowd steps its characters together through the fixed-capacity step graph, and "
                             f"variant {gen.variant!r} has the growing cache (whose rows must share one length) or "
                             f"runs one row per call (per-tensor int8): use MotionGenerator(..., variant='portable') "
                             f"or variant='int8_fixed' (per-row int8)")
        if not gen.endless:
            raise ValueError("this bundle was not trained for endless streams (its manifest has no 'streaming' "
                             "section): a crowd's characters stream without end")
        if sampling is None:
            sampling = gen.sampling_defaults
        elif not isinstance(sampling, SamplingConfig):
            raise ValueError(f"sampling must be a SamplingConfig or None (the bundle's defaults), got {sampling!r}")
        if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or not 1 <= chunk <= 1024:
            raise ValueError(f"chunk must be an int in [1, 1024], got {chunk!r}")
        self.gen, self.backend, self.fixed, self.dims, self.sampling = gen, gen.backend, fixed, gen.dims, sampling
        spec = gen.bundle.manifest.streaming
        self.window, self.refresh, self.chunk = spec.window, spec.refresh, int(chunk)
        self.guided = sampling.guidance != 1.0
        self.per_character = 2 if self.guided else 1        # rows: the prompt, and the unconditional branch
        self.num_joints = (self.dims.feature_dim + 1) // 12
        self.decode_window = self.dims.receptive_field + self.chunk
        self.characters: list[Character] = []             # characters[i].slot == i owns rows [i * per, (i + 1) * per)
        # the cache of every row, allocated for more characters than there are (doubling as they come), so adding
        # one copies nothing; the rows in use are the first len(characters) * per
        cache_shape = (0, fixed.cache_heads, fixed.capacity, self.dims.head_dim)
        self._cache = [np.zeros(cache_shape, np.float32) for _ in fixed.past_names]
        self._spare = [np.zeros(cache_shape, np.float32) for _ in fixed.past_names]
        self._next_id = 0

    def __len__(self) -> int:
        return len(self.characters)

    def add(self, text: str, seed: int = 0, seconds: float | None = None) -> Character:
        """A new character following `text`, from the next tick; `seconds`: it leaves after that much motion."""
        if not isinstance(text, str):
            raise ValueError(f"add() takes one prompt (str), got {type(text).__name__}")
        limit = self.gen.tokens_for(seconds)
        (seed,) = expand_seeds(seed, 1)
        emb = self.backend.encode_text(check_texts([text]))       # one prompt per call: padding never mixes
        character = Character(self, self._next_id, text, emb, seed, limit)
        self._next_id += 1
        rows = (len(self.characters) + 1) * self.per_character
        if rows > len(self._cache[0]):          # its rows may hold a departed character's cache: finite, masked
            grown = [np.zeros((max(rows, 2 * len(c)),) + c.shape[1:], np.float32) for c in self._cache]
            for new, old in zip(grown, self._cache):
                new[:len(old)] = old
            self._cache = grown
        character.slot = len(self.characters)
        self.characters.append(character)
        return character

    def remove(self, character: Character) -> None:
        """Take a character out; its frames not yet decoded are dropped (as closing a stream drops them). The last
        character moves into its rows."""
        slot, per = self._slot(character), self.per_character
        last = self.characters.pop()
        if last is not character:
            for c in self._cache:
                c[slot * per:(slot + 1) * per] = c[last.slot * per:(last.slot + 1) * per]
            last.slot, self.characters[slot] = slot, last
        character.slot = None

    @property
    def cache(self) -> list[np.ndarray]:
        """The rows in use of every past/present array, [characters * per, L * n_heads, capacity, head_dim]."""
        return [c[:len(self.characters) * self.per_character] for c in self._cache]

    def _slot(self, character: Character) -> int:
        if getattr(character, "crowd", None) is not self or character.slot is None:
            raise ValueError(f"{character!r} is not in this crowd")
        return character.slot

    # ------------------------------------------------------------------------------------------ the tick

    def tick(self) -> dict[Character, Frames]:
        """Every character one token further; -> the frames each character got this tick (decoded `chunk`
        tokens at a time). Characters whose `seconds` are done get their last frames and leave."""
        if not self.characters:
            return {}
        plans = [self._plan(c) for c in self.characters]
        picked = self._pick(self.characters, plans, retry=False)
        ended = [i for i, c in enumerate(self.characters) if picked[i, 0] == self.dims.end_id]
        if ended:       # END: the prompt starts again with nothing kept, and picks again with END forbidden
            again = [self.characters[i] for i in ended]
            for c in again:
                c.rebuild, c.restarts = True, c.restarts + 1
            picked[ended] = self._pick(again, [self._plan(c) for c in again], retry=True)
        for c, p in zip(self.characters, picked):
            c.motion += 1
            c.history[c.count % len(c.history)] = c.last = p
            c.count += 1
        out = self._decode()
        for c in [c for c in self.characters if c.done]:
            self.remove(c)
        return out

    def _plan(self, c: Character) -> tuple[np.ndarray, int]:
        """-> (the tokens this character feeds now (S, L), the cache slot of the first), as EndlessLoop._step."""
        tokens, c.cached, fresh = context_tokens(c.history, c.count, c.cached, c.rebuild, self.window, self.refresh,
                                                 self.dims.bos_id, c.last)
        if not fresh:
            return tokens, c.length
        if c.cached == 0:
            c.motion = 0
        c.rebuild, c.length = False, 0
        return tokens, 0

    def _pick(self, chars: list[Character], plans: list[tuple[np.ndarray, int]], retry: bool) -> np.ndarray:
        """Feed every character its planned tokens and sample its next tokens (C, L).

        A plan of more than one token is a rebuild from an empty context: its tokens but the last run on a fresh
        scratch cache (those characters only), which then replaces their rows of the crowd's cache. Every
        character's last token goes into one call over all of them."""
        dims, per = self.dims, self.per_character
        slots = np.array([self._slot(c) for c in chars])
        rows = (slots[:, None] * per + np.arange(per)).ravel()
        every = len(chars) == len(self.characters)
        sizes = np.array([len(tokens) for tokens, _ in plans])
        for size in sorted(set(sizes[sizes > 1].tolist())):
            group = np.flatnonzero(sizes == size)
            scratch = self._scratch(len(group) * per)
            emb = np.concatenate([chars[m].rows_emb for m in group])
            for k in range(size - 1):
                self._step(emb, np.stack([plans[m][0][k] for m in group]), np.full(len(group), k), scratch)
            group_rows = (slots[group][:, None] * per + np.arange(per)).ravel()
            for c, fresh in zip(self.cache, scratch):
                c[group_rows] = fresh
        emb = np.concatenate([c.rows_emb for c in chars])
        last = np.stack([tokens[-1] for tokens, _ in plans])
        position = np.array([start + len(tokens) - 1 for tokens, start in plans], np.int64)
        if every:                   # the crowd's own cache, written in place
            logits = self._step(emb, last, position, self.cache)
        else:                       # a retry after END: fresh contexts, then their rows of the crowd's cache
            scratch = self._scratch(len(rows))
            logits = self._step(emb, last, position, scratch)
            for c, fresh in zip(self.cache, scratch):
                c[rows] = fresh
        for c, (tokens, start) in zip(chars, plans):
            c.length = start + len(tokens)
        logits = logits[:, 0]                                                    # (C * per, L, K + 1)
        if self.guided:
            logits = apply_guidance(logits[0::2], logits[1::2], self.sampling.guidance)
        logits = np.array(logits, dtype=np.float32)                              # own copy: masked below
        logits[:, 1:, dims.end_id] = -np.inf          # only the coarsest stream may end the motion
        for i, c in enumerate(chars):
            if retry or c.motion < 1:
                logits[i, 0, dims.end_id] = -np.inf
        return sample(logits, self.sampling, [c.rng for c in chars])

    def _scratch(self, rows: int) -> list[np.ndarray]:
        """Caches for `rows` rows that start a context: kept between ticks, as a fresh allocation of this size
        would fault in its pages every time. What earlier contexts left there is masked out of attention (a
        context at position p reads slots 0..p only), so only finiteness matters: zeros at first."""
        if len(self._spare[0]) < rows:
            self._spare = [np.zeros((rows,) + c.shape[1:], np.float32) for c in self._cache]
        return [a[:rows] for a in self._spare]

    def _step(self, emb: np.ndarray, tokens: np.ndarray, position: np.ndarray, cache: list[np.ndarray]):
        """One portable step call, tokens (C, L) and positions (C,) per character, on `cache` (its rows for
        these characters, contiguous) in place: each array is bound as both the past and the present, so the
        graph's ScatterElements writes the new slot where it is instead of copying the whole cache first (that
        copy was half a step's time on base; the results are the same bits, tests/runtime/test_crowd.py)."""
        b, per = self.fixed, self.per_character
        binding = b.step_session.io_binding()
        binding.bind_cpu_input("text_embedding", np.ascontiguousarray(emb, dtype=np.float32))
        binding.bind_cpu_input("tokens", np.ascontiguousarray(np.repeat(tokens, per, axis=0)[:, None], np.int64))
        binding.bind_cpu_input("position", np.repeat(position, per).astype(np.int64))
        logits = np.empty((len(emb), 1, self.dims.num_levels, self.dims.codebook_size + 1), np.float32)
        # every output bound to our arrays: fetching outputs from the binding would copy the caches back
        binding.bind_output("logits", "cpu", 0, np.float32, list(logits.shape), logits.ctypes.data)
        for past, present, array in zip(b.past_names, b.output_names[1:], cache):
            binding.bind_cpu_input(past, array)
            binding.bind_output(present, "cpu", 0, np.float32, list(array.shape), array.ctypes.data)
        b.step_session.run_with_iobinding(binding)
        return b._finite("step", logits)                                         # (rows, 1, L, K + 1)

    def _decode(self) -> dict[Character, Frames]:
        """FrameStreamer's windows for every character, one decoder call per window length."""
        ds, rf = self.dims.downsample, self.dims.receptive_field
        groups: dict[int, list[Character]] = {}
        for c in self.characters:
            c.decoded[:-1] = c.decoded[1:]
            c.decoded[-1] = c.last
            c.pending += 1
            if c.count == 1 or c.pending >= self.chunk or c.done:
                groups.setdefault(min(c.count, rf + c.pending), []).append(c)
        out = {}
        for n, chars in groups.items():
            features = self.backend.decode(np.stack([c.decoded[len(c.decoded) - n:] for c in chars]))
            for c, f in zip(chars, features):
                f = f[len(f) - c.pending * ds:]
                out[c] = Frames(c.frames, f, c.lock.push(c.integrator.push(f), f))
                c.frames += len(f)
                c.pending = 0
        return out
