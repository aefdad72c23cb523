"""Text to motion with a bundle: `MotionGenerator` is the user's API.

    from mogo_runtime import MotionGenerator, SamplingConfig
    gen = MotionGenerator("bundles/base", variant="fp32", threads=1)
    motion = gen.generate("a person walks forward and then jumps", seconds=6, seed=1)
    motion.save("walk.bvh")
    greedy = gen.generate("a person waves", sampling=SamplingConfig(temperature=0))
    for frame in gen.stream("a person waves", seed=2):       # frames as soon as they are decoded
        send_to_game(frame.joints)                           # (J, 3) metres, y up
    motion = gen.generate("yo make the dude do a lil hop", align=True)   # TCA: prompt in caption style
    print(motion.aligned_text)                               # what the model was conditioned on

The recipe (seeds, steps, END, guidance, sampling, decoding) is `decoding.GenerationTask`, shared with the torch
reference; the engine is `engine.py`. This module checks what a user asks for and shapes the results.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from .bundle.folder import Bundle
from .bundle.sampling import SamplingConfig, sampling_or
from .checks import as_real, shown
from .clock import NO_CLOCK, StageClock
from .control.plant import legs_of
from .control.steering import Steerable, Steering
from .decoding import Frames, Generated, GenerationTask
from .engine import open_backend
from .outputs.motion import Motion
from .plan import PlannedAction, plan_actions
from .policy import expand_seeds
from .text import check_texts, check_threads

MAX_SECONDS = 3600.0   # the longest fixed length on an endless bundle: tokens and frames are kept for the whole motion

if TYPE_CHECKING:  # tca is imported when alignment is first used: its patterns cost ~50 ms of every cold start
    from .tca import Aligner


@dataclass
class Frame:
    """One streamed motion frame."""

    index: int                    # frame number from the start of the motion
    time: float                   # index / fps, seconds
    features: np.ndarray          # (D,) de-normalised features
    joints: np.ndarray            # (J, 3) metres, y up


@dataclass
class Conditioning:
    """What one prompt conditions the model on: one embedding per action it names (plan.py), the tokens each lasts
    (None: until the model ends it), and the text shown as `aligned_text` (None: the prompt as typed)."""

    emb: np.ndarray                    # (actions, text_dim) float32
    limits: list[int | None]
    aligned: str | None

    @property
    def single(self) -> bool:
        """One action with no stated duration: the prompt runs as it always has, batched with others."""
        return len(self.limits) == 1 and self.limits[0] is None


SWITCH_HISTORY = 10_000   # ~1 MB of prompt switches kept per stream (a switch every 4 s: 11 hours)


class FrameStream(Steerable):
    """What `MotionGenerator.stream` returns: an iterator of Frames, the prompt it follows now and its aligned
    text, and, on a bundle trained for endless streams, `set_prompt` to change what the character does; on one whose
    model has control, where it goes too (`walk_to`, `follow_path`, `steer`, `set_root`, `release`: control/).

    `condition(texts, align)` -> a Conditioning per prompt is how the generator conditions on a prompt."""

    def __init__(self, task: GenerationTask, cond: Conditioning, seed: int, chunk: int, text: str,
                 condition: Callable):
        self.text, self.aligned_text, self._condition = text, cond.aligned, condition
        emb = cond.emb[:1]
        self._loop = task.loop(emb, [seed]) if task.streaming is not None else None
        if self._loop is not None and not cond.single:
            self._loop.set_actions(cond.emb, cond.limits)
        control = task.backend.control
        self.steering = Steering(control, task.backend.dims, self._loop.streams[0], legs_of(task.skeleton)) \
            if control is not None and self._loop is not None else None
        self._chunks = task.stream(emb, seed, chunk, self._loop, self.steering)
        self._fps = task.backend.dims.fps
        self._chunk: Frames | None = None    # the frames decoded last, and how many of them were handed out
        self._next = 0
        self._placed: np.ndarray | None = None      # the chunk's frames placed at its first (_place)
        self._saved: tuple | None = None             # the planted feet's state before them
        self._closed = False
        self._shown = 0                  # the number of the next frame handed out
        # (token, text, aligned text) of the last SWITCH_HISTORY set_prompt calls: a stream runs for days
        self.switches: deque[tuple[int, str, str | None]] = deque(maxlen=SWITCH_HISTORY)

    def __iter__(self) -> "FrameStream":
        return self

    def __next__(self) -> Frame:
        if self._closed:                     # close(): the frames decoded and not read are dropped
            raise StopIteration
        while self._chunk is None or self._next == len(self._chunk.joints):
            try:
                self._chunk, self._next, self._placed = next(self._chunks), 0, None
            except StopIteration:
                self._closed = True
                raise
        k, chunk = self._next, self._chunk
        index = chunk.index + k
        joints = chunk.joints[k] if self.steering is None else self._place(chunk, k)
        self._next, self._shown = k + 1, index + 1
        return Frame(index=index, time=index / self._fps, features=chunk.features[k], joints=joints)

    def _place(self, chunk: Frames, k: int) -> np.ndarray:
        """Frame k of `chunk` as shown (Steering.place), each placed as it is handed out: on the game's capsule as
        placed up to now when it owns the root. Where it does not, the chunk's frames are placed together at its
        first (a token's frames in one call, not four: the correction's eases change only when the next chunk is
        decoded); if the game takes the root within the chunk, the feet go back to the chunk's start, the frames
        shown are placed again (the same numbers) and the rest one by one, as they would have been."""
        s = self.steering
        owned = s.game_owns_root
        if k == 0 and not owned:
            self._saved = s.warp.plant.state()
            self._placed = s.place(chunk.index, chunk.joints)
        if self._placed is not None:
            if not owned:
                return self._placed[k]
            s.warp.plant.load(*self._saved)
            s.warp.joints(chunk.index, chunk.joints[:k])
            self._placed = None
        return s.place(chunk.index + k, chunk.joints[k:k + 1])[0]

    @property
    def tokens(self) -> int:
        """Tokens sampled so far (frames lag behind by the decoding chunk)."""
        return self._loop.count if self._loop is not None else 0

    @property
    def restarts(self) -> int:
        """How often the model ended the motion and the prompt started again (endless streams; else 0)."""
        return self._loop.restarts if self._loop is not None else 0

    def set_prompt(self, text: str, align: bool | Aligner = False) -> None:
        """Follow `text` from the next token on (the frames already decoded are not changed). Safe from another
        thread: a switch asked for while a step runs lands at the token after it."""
        if self._loop is None:
            raise ValueError("this bundle was not trained for endless streams (its manifest has no 'streaming' "
                             "section), so its streams cannot change prompt")
        if self._closed:
            raise ValueError("this stream is closed (close(), or its motion ended): it follows no more prompts")
        if not isinstance(text, str):
            raise ValueError(f"set_prompt() takes one prompt (str), got {type(text).__name__}")
        (cond,) = self._condition(check_texts([text]), align)
        token = self._loop.set_actions(cond.emb, cond.limits)
        self.text, self.aligned_text = text, cond.aligned
        self.switches.append((token, text, cond.aligned))

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError("this stream is closed (close(), or its motion ended): it goes nowhere any more")

    def _next_shown(self, s) -> int:
        return self._shown

    def _why_not(self) -> str:
        return (super()._why_not() if self._loop is not None else "this bundle was not trained for endless streams "
                "(its manifest has no 'streaming' section), so its streams cannot be steered")

    def close(self) -> None:
        self._closed = True
        self._chunks.close()


class MotionGenerator:
    """Generate motions from text with one variant of a bundle.

    `threads`: onnxruntime threads per graph, an int from 1 to `text.MAX_THREADS` (64). `aligner`: the text
    condition alignment `align=True` uses (mogo_runtime.tca); default the bundle's OfflineAligner.
    """

    def __init__(self, bundle: Bundle | str | Path, variant: str = "fp32", threads: int = 1,
                 aligner: Aligner | None = None):
        # Only the chosen variant's files are read, each hashed once as it is read (Bundle.load).
        if not isinstance(variant, str) or not variant:
            raise ValueError(f"variant must be a variant name such as 'fp32', 'int8' or 'portable', got {shown(variant)}")
        check_threads(threads)     # before the bundle is read and hashed
        self.bundle = bundle if isinstance(bundle, Bundle) else Bundle.load(bundle, variant)
        self.backend = open_backend(self.bundle, variant, threads)
        self.variant, self.dims, self.skeleton = variant, self.bundle.dims, self.bundle.skeleton
        self.max_tokens, self.max_seconds = self.dims.max_tokens, self.dims.max_seconds
        self.sampling_defaults: SamplingConfig = self.bundle.manifest.sampling_defaults
        self._aligner = aligner

    @property
    def aligner(self) -> Aligner:
        """The aligner of `align=True`: the one given, else the bundle's offline one (built on first use)."""
        if self._aligner is None:
            from .tca import OfflineAligner

            self._aligner = OfflineAligner(self.bundle, self.backend)
        return self._aligner

    @aligner.setter
    def aligner(self, aligner: Aligner) -> None:
        self._aligner = aligner

    @property
    def endless(self) -> bool:
        """Whether the bundle was trained for endless streams (stream without end, set_prompt, long lengths)."""
        return self.bundle.manifest.streaming is not None

    def generate(self, text: str | list[str] | list[tuple[str, float]], *, seconds: float | None = None,
                 seed: int | list[int] = 0, sampling: SamplingConfig | None = None, align: bool | Aligner = False,
                 progress: Callable[[int, int], None] | None = None,
                 clock: StageClock | None = None) -> Motion | list[Motion]:
        """One motion per prompt (a list for a list), all prompts in one batched loop.

        Prompt i of a list uses seed `seed + i` (or `seed[i]`), so it gets the motion a lone run with that
        seed gets. `seconds` fixes the length (rounded half up to whole tokens); None lets the model end the
        motion, at most `max_seconds`. On a bundle trained for endless streams a fixed length may be any length
        up to MAX_SECONDS (`seconds=600`: a 10-minute motion; where the model ends the action it starts it
        again), and a timeline
        `[(prompt, start_seconds), ...]` (starts from 0, increasing; `seconds` required) gives one motion that
        follows each prompt from its start. `sampling` None: the bundle's sampling defaults. `align=True` (or an
        Aligner) rewrites each prompt into the training captions' style first (TCA); the motion's
        `aligned_text` says what the model was conditioned on. `progress(step, limit)` is called after every step;
        `clock` (a clock.StageClock) adds up the time of each stage of the loop.
        A prompt is Unicode text of at most `text.MAX_PROMPT_CHARS` (10,000) characters (ValueError otherwise).
        """
        if not isinstance(text, (str, list, tuple)):
            raise ValueError(f"text must be a prompt (str), a list of prompts or a timeline [(prompt, start_seconds), "
                             f"...], got {type(text).__name__}")
        if isinstance(text, (list, tuple)) and text and all(isinstance(t, tuple) for t in text):
            return self._timeline(list(text), seconds, seed, sampling, align, progress, clock)
        texts = check_texts([text] if isinstance(text, str) else text)
        task, conds, seeds = self._prepare(texts, seconds, seed, sampling, align, clock)
        if all(c.single for c in conds):
            results = task.run(np.concatenate([c.emb for c in conds]), seeds, progress)
        else:       # a prompt of several actions plays them one after another: each prompt on its own
            results = [task.run(c.emb, [s], progress)[0] if c.single else task.actions(c.emb, c.limits, s, progress)
                       for c, s in zip(conds, seeds)]
        motions = [self._motion(t, r, s, c.aligned) for t, r, s, c in zip(texts, results, seeds, conds)]
        for m, r, c in zip(motions, results, conds):
            if r.starts is not None:
                m.actions = [(a, t * self.dims.downsample) for a, t in zip(c.aligned.split(" | "), r.starts)]
        return motions[0] if isinstance(text, str) else motions

    def _timeline(self, timeline, seconds, seed, sampling, align, progress, clock) -> Motion:
        if seconds is None:
            raise ValueError("a timeline needs seconds=, the length of the whole motion")
        if not all(len(item) == 2 and isinstance(item[0], str) for item in timeline):
            raise ValueError("a timeline is a list of (prompt, start_seconds) pairs")
        texts = check_texts([t for t, _ in timeline])
        total = self.tokens_for(seconds)
        try:
            starts = [self.tokens_for(t) if t else 0 for _, t in timeline]
        except ValueError as e:
            raise ValueError(f"a timeline start: {e}".replace("seconds must be", "it must be", 1)) from None
        if timeline[0][1] != 0 or any(b <= a for a, b in zip(starts, starts[1:])) or starts[-1] >= total:
            raise ValueError(f"timeline starts must begin at 0 and increase, each before the end ({seconds} s); got "
                             f"{shown([t for _, t in timeline], 200)}")
        task, conds, seeds = self._prepare(texts, seconds, [expand_seeds(seed, 1)[0]] * len(texts), sampling,
                                           align, clock, split=False)
        r = task.timeline(np.concatenate([c.emb for c in conds]), starts, seeds[0], progress)
        aligned = [c.aligned for c in conds]
        return self._motion(" | ".join(texts), r, seeds[0], None if aligned[0] is None else " | ".join(aligned))

    def _motion(self, text: str, r: Generated, seed: int, aligned: str | None) -> Motion:
        return Motion(text=text, features=r.features, joints=r.joints, fps=self.dims.fps, tokens=r.tokens,
                      skeleton=self.skeleton, seed=seed, aligned_text=aligned)

    def stream(self, text: str, *, seconds: float | None = None, seed: int = 0,
               sampling: SamplingConfig | None = None, align: bool | Aligner = False, chunk: int = 4) -> FrameStream:
        """Yield the frames of one prompt's motion as its tokens are sampled and decoded.

        On a bundle trained for endless streams (`endless`) the stream has no end unless `seconds` is given, and
        `set_prompt` on it changes the prompt from the next token; `close()` ends it. Otherwise the model ends
        the motion, at most `max_seconds`. The first token's frames come at once; after that frames come `chunk`
        tokens at a time (chunk=1: every token, at ~1.6x the decoding work; see decoding.FrameMaker). The
        causal decoder makes them equal to `generate(text, seconds=..., seed=seed)`'s frames (to float
        rounding). Arguments are checked, and the prompt aligned, when this is called, before the first frame
        is asked for; the returned stream's `aligned_text` says what the model follows.
        """
        if not isinstance(text, str):
            raise ValueError(f"stream() takes one prompt (str), got {type(text).__name__}; use generate() for a batch")
        task, conds, seeds = self._prepare(check_texts([text]), seconds, seed, sampling, align)
        return FrameStream(task, conds[0], seeds[0], chunk, text, self.condition)

    def _prepare(self, texts: list[str], seconds, seed, sampling, align, clock=None, split: bool = True):
        """What generate and stream share: checked arguments, the task, each prompt's Conditioning and seeds."""
        fixed = self.tokens_for(seconds)
        sampling = sampling_or(self.sampling_defaults, sampling)
        seeds = expand_seeds(seed, len(texts))
        clock = clock or NO_CLOCK
        with clock("text"):
            conds = self.condition(texts, align, split)
        task = GenerationTask(self.backend, self.skeleton, sampling, self.max_tokens, fixed,
                              self.bundle.manifest.streaming, clock)
        return task, conds, seeds

    def condition(self, texts: list[str], align: bool | Aligner = False, split: bool = True) -> list[Conditioning]:
        """What each prompt conditions the model on. On a bundle trained for endless streams (and `split`), a prompt
        that names several actions ("walks forward and then jumps") is split into them (plan.py), each aligned and
        encoded on its own, and its aligned text shows them joined by " | "; elsewhere a prompt is one
        conditioning, as typed (or aligned)."""
        plans = [plan_actions(t) if split and self.endless else [PlannedAction(t)] for t in texts]
        if all(len(p) == 1 and p[0].seconds is None for p in plans):
            emb, aligned = self._condition([p[0].text for p in plans], align)
            return [Conditioning(e[None], [None], a) for e, a in zip(emb, aligned)]
        out = []
        for text, plan in zip(texts, plans):   # one encoder call per prompt: its actions' padding never mixes
            emb, aligned = self._condition([a.text for a in plan], align)
            parts = [al if al is not None else a.text for a, al in zip(plan, aligned)]
            as_typed = parts == [text]
            out.append(Conditioning(emb, [self.tokens_for(a.seconds) for a in plan],
                                    None if as_typed else " | ".join(parts)))
        return out

    def _condition(self, texts: list[str], align) -> tuple[np.ndarray, list[str | None]]:
        """-> (text embeddings (B, text_dim), aligned texts or None each)."""
        prompts = self.align(texts, align)
        if prompts is None:
            return self.backend.encode_text(texts), [None] * len(texts)
        from .tca import apply_alignment

        return apply_alignment(prompts, self.backend.encode_text), [p.text for p in prompts]

    def align(self, texts: list[str], align: bool | Aligner = True):
        """The aligned prompts for `texts` (None when `align` is False): `align` is True or an Aligner."""
        if align is False or align is None:
            return None
        from .tca import Aligner

        aligner = self.aligner if align is True else align
        if not isinstance(aligner, Aligner):
            raise ValueError(f"align must be True, False or a mogo_runtime.tca.Aligner, got {shown(align)}")
        return aligner.align_batch(texts)

    def tokens_for(self, seconds: float | None) -> int | None:
        """Seconds -> a fixed number of tokens (half up), or None; ValueError outside the bundle's range."""
        if seconds is None:
            return None
        per_token = self.dims.downsample / self.dims.fps
        most, limit = (MAX_SECONDS, "endless streams") if self.endless else (self.max_seconds, "this bundle")
        allowed = (f"between {per_token:g} and {most:g} seconds for {limit} ({self.dims.downsample} frames per "
                   f"token at {self.dims.fps:g} fps)")
        value = as_real("seconds", seconds, allowed, per_token / 2, most + per_token)
        tokens = math.floor(value / per_token + 0.5 + 1e-9)   # the epsilon keeps 6.0 s from landing just below
        if not 1 <= tokens <= (round(most / per_token) if self.endless else self.max_tokens):
            raise ValueError(f"seconds must be {allowed}, got {seconds!r}")
        return tokens
