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

A character is an endless stream (endless.StreamContext) whose frames come through a decoding.FrameMaker, as
`gen.stream(prompt, seed=seed)`'s do; only its calls are shared (the step, the decoder, the joints and the steering of
every character at once). So its tokens and frames are bit for bit what that stream gives it alone, whoever else is in
the crowd (tests/runtime/test_crowd.py, test_control.py): the graphs compute each row on its own (checked on `base`: a
row's logits and features are identical alone and in a batch of 24), and the Python around them is elementwise.

The step graph must be the fixed-capacity one (`portable`; `int8_fixed`: per-row int8, where per-tensor int8
would make a character's numbers depend on its neighbours; or `compact`: int8-stored weights, float32 arithmetic): each row carries its own `position`, so characters at
different points of their contexts share one call. Context rebuilds feed their tokens one call each, shared by the
characters rebuilding in the same tick (whatever their lengths); every character's last token goes into one call over
the whole crowd.
"""
from __future__ import annotations

import os
import threading
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from .bundle.sampling import SamplingConfig, sampling_or
from .checks import as_int
from .control.plant import legs_of
from .control.steering import Steerable, Steering
from .decoding import FrameMaker, Frames, check_chunk, decode_due
from .endless import Feed, StreamContext
from .engine import FixedCacheBackend, compact_slots
from .kinematics.frames import FrameJoints
from .outputs.motion import Motion
from .policy import StepPolicy, expand_seeds
from .text import check_texts

if TYPE_CHECKING:
    from .generator import MotionGenerator

SWITCH_HISTORY = 10_000   # prompt switches kept per character, as FrameStream keeps them
MEMORY_SHARE = 0.5        # of the memory available when a crowd is made, what its characters may take by default
SCRATCH_SLACK = 8         # a rebuild's scratch cache is kept until it holds this many times the rows rebuilds need
SCRATCH_CALLS = 64        # ... the most of the last this many rebuilds
# The most rows one step call on a scratch cache feeds (rebuilds, retries after END). Characters that start together
# (a restored server's, a crowd added at once) rebuild their contexts in the same ticks from then on; one call over
# all of them kept a scratch cache of every one resident (800 characters of the tests' tiny model: +110 MB, RSS 1.4x
# a staggered crowd's; on base 2 MiB a row). At 64 rows a call's fixed cost (~0.7 ms on base) is ~3% of its rows'.
SCRATCH_ROWS = 64


def available_memory() -> int:
    """Bytes of memory available to a new allocation now: the machine's (Linux: MemAvailable; elsewhere the free
    pages), at most what this process's address-space limit leaves (`ulimit -v`)."""
    try:
        with open("/proc/meminfo") as f:
            free = next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    except (OSError, StopIteration, ValueError, IndexError):
        try:
            free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (OSError, ValueError, AttributeError):
            free = 1 << 30         # nothing says: 1 GiB
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        return free if limit == resource.RLIM_INFINITY else max(0, min(free, limit - used))
    except (ImportError, OSError, ValueError):
        return free


class Character(Steerable):
    """One member of a crowd: its prompt and seed, its stream's token state (`context`) and frames (`frames`), and
    on a bundle whose model has control, where it goes (`walk_to`, `follow_path`, `steer`, `set_root`, `release`).
    Made by `Crowd.add`."""

    def __init__(self, crowd: "Crowd", ident: int, text: str, cond, seed: int, limit: int | None, record: bool):
        self.crowd, self.id, self.text, self.seed, self.limit = crowd, ident, text, seed, limit
        self.slot: int | None = None        # its place in the crowd (rows slot * rows ...), None once removed
        control = crowd.backend.control
        self.context = StreamContext(crowd.policy, cond.emb, seed, crowd.gen.bundle.manifest.streaming,
                                     control.dim if control else 0, cond.limits)
        self.frames = FrameMaker(crowd.gen.dims, crowd.gen.skeleton, crowd.chunk, crowd.backend.decoder_state)
        self.steering = Steering(control, crowd.gen.dims, self.context, legs_of(crowd.gen.skeleton),
                                 crowd.steering_lock) if control else None
        self.switches: deque[tuple[int, str]] = deque(maxlen=SWITCH_HISTORY)
        self.recorded: tuple[list, list, list] | None = ([], [], []) if record else None   # tokens, features, joints

    @property
    def count(self) -> int:
        """Tokens picked so far."""
        return self.context.count

    @property
    def restarts(self) -> int:
        """How often the model ended the motion and the prompt started again."""
        return self.context.restarts

    @property
    def done(self) -> bool:
        return self.limit is not None and self.count >= self.limit

    def set_prompt(self, text: str) -> None:
        """Follow `text` from this character's next token on (frames already decoded are not changed)."""
        self.crowd.set_prompt(self, text)

    def _check_open(self) -> None:
        self.crowd._slot(self)                  # a character removed from its crowd goes nowhere

    def motion(self) -> Motion:
        """Everything this character has done and been decoded so far, as one Motion (added with record=True)."""
        if self.recorded is None:
            raise ValueError(f"{self!r} was not added with record=True: its tokens and frames were not kept")
        gen, (tokens, features, joints) = self.crowd.gen, self.recorded
        none = np.zeros((0, gen.dims.feature_dim), np.float32), np.zeros((0, gen.skeleton.num_joints, 3), np.float32)
        return Motion(text=self.text, features=np.concatenate([none[0], *features]),
                      joints=np.concatenate([none[1], *joints]), fps=gen.dims.fps,
                      tokens=np.array(tokens, np.int64).reshape(-1, gen.dims.num_levels), skeleton=gen.skeleton,
                      seed=self.seed)

    def __repr__(self) -> str:
        return f"Character({self.id}, {self.text!r}, seed={self.seed}, tokens={self.count})"


class Crowd:
    """Characters that come and go, stepped together: `tick()` advances every one by a token.

    `sampling`: one SamplingConfig for the crowd (default the bundle's). `chunk`: tokens per decode after the
    first, as `MotionGenerator.stream`'s. `max_characters`: how many it may hold; default what the memory available
    now holds (`character_bytes` each, MEMORY_SHARE of it). Their step cache is reserved at once as address space;
    memory is used as characters come. One thread ticks a crowd at a time; `add`, `remove` and
    `Character.set_prompt` from other threads wait for a running tick.
    """

    def __init__(self, gen: "MotionGenerator", sampling: SamplingConfig | None = None, chunk: int = 4,
                 max_characters: int | None = None):
        if not isinstance(gen.backend, FixedCacheBackend):
            raise ValueError(f"a crowd steps its characters together through the fixed-capacity step graph, and "
                             f"variant {gen.variant!r} has the growing cache (whose rows must share one length) or "
                             f"runs one row per call (per-tensor int8): use MotionGenerator(..., variant='portable') "
                             f"variant='int8_fixed' (per-row int8) or variant='compact'")
        if not gen.endless:
            raise ValueError("this bundle was not trained for endless streams (its manifest has no 'streaming' "
                             "section): a crowd's characters stream without end")
        self.gen, self.backend, self.chunk = gen, gen.backend, check_chunk(chunk)
        self.policy = StepPolicy(sampling_or(gen.sampling_defaults, sampling), gen.dims)
        self.characters: list[Character] = []      # characters[i].slot == i owns rows [i * rows, (i + 1) * rows)
        self._spare = self.backend.empty_past(0).arrays
        self._asked: deque[int] = deque(maxlen=SCRATCH_CALLS)    # rows of the last rebuilds' scratch
        self._next_id = 0
        self._lock = threading.Lock()
        self.steering_lock = threading.Lock()      # every character's Steering's: a tick's update takes it once
        # a character's rows, in the crowd's cache and in the scratch rows of a rebuild
        self.character_bytes = 2 * self.policy.rows * sum(a[:1].nbytes for a in self.backend.empty_past(1).arrays)
        self.max_characters = (as_int("max_characters", max_characters, "an int >= 1 or None", 1)
                               if max_characters is not None else
                               max(1, int(MEMORY_SHARE * available_memory() // self.character_bytes)))
        # the cache of every row, for max_characters at once: zeros the system maps only as rows are first written,
        # so memory grows with the characters and adding one never copies the others' (growing by doubling
        # copied them: a 227-577 ms tick at the 128th character on base, and 192 characters late by 0.2 s)
        try:
            self._cache = self.backend.empty_past(self.max_characters * self.policy.rows).arrays
        except MemoryError:    # a system that commits memory up front (vm.overcommit_memory = 2), or a tight ulimit
            raise MemoryError(f"could not reserve the step cache of {self.max_characters} characters "
                              f"({self.max_characters * self.character_bytes / 2 / 2 ** 30:.1f} GiB of address space, "
                              f"used only as characters come): pass Crowd(..., max_characters=N) for fewer") from None

    def __len__(self) -> int:
        return len(self.characters)

    def add(self, text: str, seed: int = 0, seconds: float | None = None, record: bool = False) -> Character:
        """A new character following `text`, from the next tick; `seconds`: it leaves after that much motion.
        `record=True` keeps its tokens and frames for `Character.motion()` (memory grows with the motion)."""
        if not isinstance(text, str):
            raise ValueError(f"add() takes one prompt (str), got {type(text).__name__}")
        limit = self.gen.tokens_for(seconds)
        (seed,) = expand_seeds(seed, 1)
        (cond,) = self.gen.condition(check_texts([text]))      # one prompt per call: padding never mixes
        return self.join(text, cond, seed, limit, record)

    def join(self, text: str, cond, seed: int, limit: int | None, record: bool = False) -> Character:
        """A new character conditioned on `cond` (generator.Conditioning), `limit` tokens long (None: no end): `add`
        with the prompt already embedded (state.restore_character gives the saved embeddings)."""
        with self._lock:
            if len(self.characters) >= self.max_characters:
                raise ValueError(f"this crowd holds at most {self.max_characters} characters (each needs "
                                 f"{self.character_bytes / 2 ** 20:.1f} MiB of step cache); Crowd(..., "
                                 f"max_characters=N) sets another bound")
            character = Character(self, self._next_id, text, cond, seed, limit, bool(record))
            self._next_id += 1
            # its rows may hold a departed character's cache: finite, and masked out of its attention
            character.slot = len(self.characters)
            self.characters.append(character)
        return character

    def set_prompt(self, character: Character, text: str) -> None:
        """`character` follows `text` from its next token on. From another thread while a tick runs, this waits for
        that tick: the switch lands at the character's next token either way."""
        if not isinstance(text, str):
            raise ValueError(f"set_prompt() takes one prompt (str), got {type(text).__name__}")
        (cond,) = self.gen.condition(check_texts([text]))
        with self._lock:
            self._slot(character)                        # a character removed from its crowd moves no more
            character.context.condition(cond.emb, cond.limits)
            character.text = text
            character.switches.append((character.count, text))

    def remove(self, character: Character) -> None:
        """Take a character out; its frames not yet decoded are dropped (as closing a stream drops them). The last
        character moves into its rows."""
        with self._lock:
            self._remove(character)

    def _remove(self, character: Character) -> None:
        slot, per = self._slot(character), self.policy.rows
        last = self.characters.pop()
        if last is not character:
            for c in self._cache:
                c[slot * per:(slot + 1) * per] = c[last.slot * per:(last.slot + 1) * per]
            last.slot, self.characters[slot] = slot, last
        character.slot = None

    @property
    def cache(self) -> list[np.ndarray]:
        """The rows in use of every past/present array, [characters * rows, L * n_heads, capacity, head_dim]."""
        return [c[:len(self.characters) * self.policy.rows] for c in self._cache]

    def _slot(self, character: Character) -> int:
        if getattr(character, "crowd", None) is not self or character.slot is None:
            raise ValueError(f"{character!r} is not in this crowd")
        return character.slot

    def tick(self) -> dict[Character, Frames]:
        """Every character one token further; -> the frames each character got this tick (decoded `chunk`
        tokens at a time). Characters whose `seconds` are done get their last frames and leave."""
        if not self._lock.acquire(blocking=False):
            raise RuntimeError("Crowd.tick() is running in another thread: one thread ticks a crowd at a time")
        try:
            return self._tick()
        finally:
            self._lock.release()

    def _tick(self) -> dict[Character, Frames]:
        if not self.characters:
            return {}
        chars = list(self.characters)
        picked = self._pick(chars, [c.context.plan() for c in chars])
        ended = [c for c, p in zip(chars, picked) if not c.context.accept(p)]
        if ended:       # END: the prompt starts again with nothing kept, and picks again (END forbidden)
            for c, p in zip(ended, self._pick(ended, [c.context.plan() for c in ended])):
                c.context.accept(p)
        out = self._decode()
        for c in [c for c in self.characters if c.done]:
            self._remove(c)
        return out

    def _pick(self, chars: list[Character], plans: list[Feed]) -> np.ndarray:
        """Feed every character its planned tokens and pick its next tokens (C, L).

        A plan of more than one token starts from an empty context (a rebuild, or a restored character's replay): its
        tokens but the last run on a scratch cache (those characters only), which then replaces their rows of the
        crowd's cache. Every character's last token goes into one call over all of them, on the crowd's own cache when
        every character is in it. A row's numbers do not depend on the others in its call, so calls on a scratch cache
        go SCRATCH_ROWS rows at a time; a compaction moves slots of its character's rows only."""
        policy = self.policy
        slots = np.array([self._slot(c) for c in chars])
        rows = (slots[:, None] * policy.rows + np.arange(policy.rows)).ravel()
        sizes = np.array([len(plan.tokens) for plan in plans])
        controlled = self.backend.control is not None

        def control_at(members, k):      # the controls of position k of each member's feed, for its rows
            return policy.feed(np.stack([plans[m].controls[k] for m in members])) if controlled else None

        def compact(scratch, members, k):     # the members whose feed compacts before position k, in their rows
            for i, m in enumerate(members):
                if plans[m].compact[k]:
                    compact_slots(scratch, *chars[m].context.compaction, slice(i * policy.rows, (i + 1) * policy.rows))

        per_call = max(1, SCRATCH_ROWS // policy.rows)
        # rebuilds of every length share calls, longest first: the rows still fed at position k are then a prefix
        # of the group's, a contiguous part of its scratch (16 base characters restored at once, 15 lengths: their
        # first tick 0.74 s with a call per length and token, 0.33 s so; benchmarks/NOTES.md, "Issue 29")
        rebuilding = sorted(np.flatnonzero(sizes > 1).tolist(), key=lambda m: -sizes[m])
        for group in [rebuilding[i:i + per_call] for i in range(0, len(rebuilding), per_call)]:
            scratch = self._scratch(len(group) * policy.rows)
            emb = np.concatenate([chars[m].context.rows_emb for m in group])
            for k in range(sizes[group[0]] - 1):
                fed = group[:sum(sizes[m] - 1 > k for m in group)]
                n = len(fed) * policy.rows
                compact(scratch, fed, k)
                self.backend.step_in_place(emb[:n], policy.feed(np.stack([plans[m].tokens[k] for m in fed])),
                                           policy.feed(np.array([plans[m].slots[k] for m in fed])),
                                           [a[:n] for a in scratch], control_at(fed, k))
            group_rows = (slots[group][:, None] * policy.rows + np.arange(policy.rows)).ravel()
            for c, fresh in zip(self.cache, scratch):
                c[group_rows] = fresh
        for m, plan in enumerate(plans):            # a full context compacted before its last token
            if plan.compact[-1]:
                compact_slots(self.cache, *chars[m].context.compaction, rows[m * policy.rows:(m + 1) * policy.rows])
        emb = np.concatenate([c.context.rows_emb for c in chars])
        last = policy.feed(np.stack([plan.tokens[-1] for plan in plans]))
        position = policy.feed(np.array([plan.slots[-1] for plan in plans], np.int64))
        control = control_at(range(len(chars)), -1)
        if len(chars) == len(self.characters):      # the crowd's own cache, written in place
            logits = self.backend.step_in_place(emb, last, position, self.cache, control)
        else:       # a retry after END: BOS at slot 0 of fresh contexts, then their rows
            logits = []
            for part in [slice(i, i + per_call * policy.rows) for i in range(0, len(rows), per_call * policy.rows)]:
                scratch = self._scratch(len(rows[part]))
                logits.append(self.backend.step_in_place(emb[part], last[part], position[part], scratch,
                                                         None if control is None else control[part]))
                for c, fresh in zip(self.cache, scratch):
                    c[rows[part]] = fresh
            logits = np.concatenate(logits)
        return policy.pick(logits[:, 0], np.array([c.context.may_end for c in chars]),
                           [c.context.rng for c in chars])

    def _scratch(self, rows: int) -> list[np.ndarray]:
        """Caches for `rows` rows that start a context: kept between ticks, as a fresh allocation of this size
        would fault in its pages every time. What earlier contexts left there is masked out of attention (a
        context at position p reads slots 0..p only), so only finiteness matters: zeros at first. Made again
        for the most rows of the last SCRATCH_CALLS calls when it holds SCRATCH_SLACK times more, so a tick with
        many rebuilds does not keep its scratch resident."""
        self._asked.append(rows)
        need = max(self._asked)
        if not rows <= len(self._spare[0]) <= SCRATCH_SLACK * need:
            self._spare = self.backend.empty_past(need).arrays
        return [a[:rows] for a in self._spare]

    def _decode(self) -> dict[Character, Frames]:
        """Every character's due tokens, one decoder call per number of tokens (or window length)."""
        groups: dict[int, list[Character]] = {}
        for c in self.characters:
            if c.steering is not None and c.steering.target is not None:
                c.frames.chunk = 1      # its next token's control reads the pose the frames so far fix
            n = c.frames.push(c.context.last)
            n = n or c.frames.due(final=c.done)
            if n:
                groups.setdefault(n, []).append(c)
            if c.recorded is not None:
                c.recorded[0].append(c.context.last)
        out = {}
        for n, chars in groups.items():
            features = decode_due(self.backend, [c.frames for c in chars], n)
            out.update(zip(chars, FrameMaker.frames_many([c.frames for c in chars], features)))
        steered = [c for c in out if c.steering is not None]
        if steered:
            Steering.update_many([c.steering for c in steered], [out[c].index + len(out[c].joints) for c in steered],
                                 FrameJoints.next_poses([c.frames.joints for c in steered]))
        placed = Steering.place_many([c.steering for c in steered], [out[c].index for c in steered],
                                     [out[c].joints for c in steered])
        for c, joints in zip(steered, placed):
            out[c].joints = joints
        for c, frames in out.items():
            if c.recorded is not None:
                c.recorded[1].append(frames.features)
                c.recorded[2].append(frames.joints)
        return out
