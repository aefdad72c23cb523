"""A crowd character's whole state, saved and restored: a restored character goes on with the tokens and frames it
would have had had it never stopped. This is what lets a server restart, or hand a character to another machine,
without a visible jump.

    data = save_character(character)          # bytes (JSON): prompt, seed, random generator, recent tokens and their
                                              # controls, decode window, root, foot lock, steering
    character = restore_character(crowd, data)

The step cache is not saved: the tokens its numbers came from are (those since the context was last fed from an
empty cache, at most `StreamContext.keep`), and the restored character's first step feeds them again from an empty
cache, compacting where the stream did (endless.StreamContext.resume). A crowd's rows are computed independently of
one another, one token a call, so the cache it replays holds the same numbers (tests/runtime/test_state.py: bit for
bit against a character that never stopped). The text embeddings are saved, not the prompt encoded again: the
restored character is conditioned on the same numbers.

Saved data is read as untrusted: every field checked for its type, shape and range, else ValueError naming it.
"""
from __future__ import annotations

import base64
import json
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from .control.targets import FollowPath, GameRoot, Steer, WalkTo
from .control.plant import STATE_FLOATS
from .control.warp import Ease
from .decoding import MAX_CHUNK
from .endless import COMPACTIONS
from .generator import Conditioning
from .text import check_texts

if TYPE_CHECKING:
    from .crowd import Character, Crowd

FORMAT = "mogo.character/1"
MAX_STATE_BYTES = 64 << 20      # a character with a 100,000-point path is ~5 MB


def _array(a: np.ndarray) -> dict:
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": base64.b64encode(a.tobytes()).decode()}


def _target(target) -> dict | None:
    if target is None:
        return None
    if isinstance(target, WalkTo):
        return {"kind": "walk_to", "goal": target.goal.tolist(), "speed": target.speed, "arrived": target.arrived}
    if isinstance(target, FollowPath):
        return {"kind": "follow_path", "points": target.points.tolist(), "speed": target.speed,
                "progress": target.progress, "arrived": target.arrived}
    if isinstance(target, Steer):
        return {"kind": "steer", "velocity": target.velocity.tolist(),
                "facing": None if target.facing is None else target.facing.tolist()}
    return {"kind": "game_root", "pose": None if target.pose is None else target.pose.tolist(),
            "velocity": target.velocity.tolist(), "frame": target.frame}


def save_character(c: "Character") -> bytes:
    """The character's state as bytes. A character added with record=True is saved without its recording."""
    ctx, maker = c.context, c.frames
    root, lock = maker.joints.root, maker.joints.lock
    state = {
        "format": FORMAT, "text": c.text, "seed": c.seed, "limit": c.limit,
        "context": {
            "rng": ctx.rng.bit_generator.state, "history": _array(ctx.history),
            "controls": None if ctx.controls is None else _array(ctx.controls),
            "control": None if ctx.control is None else _array(ctx.control),
            "last": None if ctx.last is None else _array(ctx.last),
            "count": ctx.count, "cached": ctx.cached, "compactions": ctx.compactions, "motion": ctx.motion,
            "restarts": ctx.restarts,
            "parts": _array(np.stack(ctx.parts)), "limits": ctx.limits, "part": ctx.part,
            "finished_at": ctx.finished_at, "starts": ctx.starts, "restart": ctx.restart, "in_part": ctx.in_part},
        "frames": {
            "tokens": _array(maker.tokens), "count": maker.count, "pending": maker.pending, "frames": maker.frames,
            "decoder_state": None if maker.state is None else [_array(a) for a in maker.state],
            "chunk": maker.chunk, "angle": root.angle, "position": root.position.tolist(),
            "previous": root.previous.tolist(), "offset": lock.offset.tolist(),
            "toes": None if lock.previous is None else [lock.previous[0].tolist(), lock.previous[1].tolist()]},
        "steering": None if c.steering is None else {
            "target": _target(c.steering.target), "pose": c.steering.pose.tolist(), "frame": c.steering.frame,
            "eases": [list(e) for e in c.steering.warp.eases], "active": c.steering.warp.active,
            "plant": dict(zip(("pinned", "values"), c.steering.warp.plant.state()))},
    }
    return json.dumps(state, separators=(",", ":")).encode()


class _Fields:
    """A dict from saved data, read field by field: a wrong field is a ValueError naming where it is."""

    def __init__(self, data, where: str):
        if not isinstance(data, dict):
            raise ValueError(f"character state: {where} must be an object")
        self.data, self.where = data, where

    def _get(self, key: str):
        if key not in self.data:
            raise ValueError(f"character state: {self.where}.{key} is missing")
        return self.data[key]

    def fail(self, key: str, want: str):
        raise ValueError(f"character state: {self.where}.{key} must be {want}, got {str(self.data.get(key))[:80]}")

    def int(self, key: str, lo: int = 0, hi: int = 2 ** 63 - 1, none: bool = False) -> int | None:
        v = self._get(key)
        if v is None and none:
            return None
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            self.fail(key, f"an int in [{lo}, {hi}]" + (" or null" if none else ""))
        return v

    def real(self, key: str) -> float:
        v = self._get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            self.fail(key, "a finite number")
        return float(v)

    def bool(self, key: str) -> bool:
        v = self._get(key)
        if not isinstance(v, bool):
            self.fail(key, "true or false")
        return v

    def reals(self, key: str, n: int | None = None, none: bool = False) -> np.ndarray | None:
        v = self._get(key)
        if v is None and none:
            return None
        try:
            a = np.array(v, np.float64)
        except (TypeError, ValueError):
            a = np.zeros(0)
        if a.ndim != 1 or (n is not None and len(a) != n) or not np.isfinite(a).all() \
                or any(isinstance(x, bool) for x in (v if isinstance(v, list) else [])):
            self.fail(key, f"{n if n is not None else 'a list of'} finite numbers")
        return a

    def array(self, key: str, dtype: str, shape: tuple, none: bool = False) -> np.ndarray | None:
        v = self._get(key)
        if v is None and none:
            return None
        f = _Fields(v, f"{self.where}.{key}")
        want = np.dtype(dtype)
        if f._get("dtype") != want.str or f._get("shape") != list(shape) or not isinstance(f._get("data"), str):
            self.fail(key, f"an array of {want.str} {list(shape)}")
        try:
            raw = base64.b64decode(f._get("data"), validate=True)
        except ValueError:
            self.fail(key, "base64 data")
        if len(raw) != want.itemsize * int(np.prod(shape)):
            self.fail(key, f"{want.itemsize * int(np.prod(shape))} bytes of data")
        a = np.frombuffer(raw, want).reshape(shape).copy()
        if want.kind == "f" and not np.isfinite(a).all():
            self.fail(key, "finite numbers")
        return a

    def sub(self, key: str, none: bool = False) -> "_Fields | None":
        v = self._get(key)
        return None if v is None and none else _Fields(v, f"{self.where}.{key}")


def _restore_target(f: _Fields | None):
    if f is None:
        return None
    kind = f._get("kind")
    try:
        if kind == "walk_to":
            t = WalkTo(f.reals("goal", 2), f.real("speed"))
        elif kind == "follow_path":
            t = FollowPath(f._get("points"), f.real("speed"))
            t.progress = min(max(f.real("progress"), 0.0), t.total)
        elif kind == "steer":
            t = Steer(f.reals("velocity", 2), f.reals("facing", 2, none=True))
        elif kind == "game_root":
            t = GameRoot()
            t.pose, t.velocity, t.frame = f.reals("pose", 3, none=True), f.reals("velocity", 3), f.int("frame")
        else:
            f.fail("kind", "walk_to, follow_path, steer or game_root")
    except ValueError as e:
        if str(e).startswith("character state"):
            raise
        raise ValueError(f"character state: {f.where}: {e}") from None
    if kind in ("walk_to", "follow_path"):
        t.arrived = f.bool("arrived")
    return t


def restore_character(crowd: "Crowd", data: bytes) -> "Character":
    """A character of `crowd` from `save_character`'s bytes (saved from a crowd of the same bundle and sampling),
    going on from where it was saved at the crowd's next tick."""
    if not isinstance(data, (bytes, bytearray)) or len(data) > MAX_STATE_BYTES:
        raise ValueError(f"character state: bytes of at most {MAX_STATE_BYTES} expected")
    try:
        top = _Fields(json.loads(data), "state")
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise ValueError(f"character state: not JSON ({type(e).__name__})") from None
    if top._get("format") != FORMAT:
        top.fail("format", repr(FORMAT))
    text = top._get("text")
    if not isinstance(text, str):
        top.fail("text", "a prompt")
    check_texts([text])
    dims, spec = crowd.gen.dims, crowd.gen.bundle.manifest.streaming
    span, L = spec.window + spec.refresh, dims.num_levels
    control_dim = crowd.backend.control.dim if crowd.backend.control else 0

    c = top.sub("context")
    saved = c.sub("parts")
    shape = saved._get("shape")
    if not isinstance(shape, list) or len(shape) != 2 or shape[1] != dims.text_dim or shape[0] not in range(1, 65):
        saved.fail("shape", f"[actions (1 to 64), {dims.text_dim}]")
    parts = c.array("parts", "<f4", tuple(shape))
    limits = c._get("limits")
    if not isinstance(limits, list) or len(limits) != len(parts) or any(
            x is not None and (isinstance(x, bool) or not isinstance(x, int) or x < 1) for x in limits):
        c.fail("limits", f"{len(parts)} token counts (>= 1) or nulls")
    character = crowd.join(text, Conditioning(parts, limits, None), top.int("seed", 0, 2 ** 64 - 1),
                           top.int("limit", 1, none=True))
    try:
        _restore_into(character, top, c, dims, span, L, control_dim)
    except BaseException:
        crowd.remove(character)
        raise
    return character


def _restore_into(character, top: _Fields, c: _Fields, dims, span: int, L: int, control_dim: int) -> None:
    ctx, maker = character.context, character.frames
    rng = c._get("rng")
    try:
        ctx.rng.bit_generator.state = rng
    except (TypeError, ValueError, KeyError):
        c.fail("rng", "a PCG64 state")
    ctx.count = c.int("count")
    # states saved before contexts were compacted: a ring of the last `span` tokens, and never a compaction
    compacted = "compactions" in c.data
    ring = ctx.keep if compacted else span
    history = c.array("history", "<i8", (ring, L))
    if ((history < 0) | (history >= dims.codebook_size)).any():
        c.fail("history", f"codes in [0, {dims.codebook_size})")
    held = ctx.count - ring + np.arange(ring)            # the tokens the ring holds (those >= 0), token t at t % ring
    held = held[held >= 0]
    ctx.history[held % ctx.keep] = history[held % ring]
    if control_dim:
        controls = c.array("controls", "<f4", (ring, control_dim))
        ctx.controls[held % ctx.keep] = controls[held % ring]
        ctx.control = c.array("control", "<f4", (control_dim,))
    ctx.last = c.array("last", "<i8", (L,), none=ctx.count == 0)
    ctx.cached, ctx.motion, ctx.restarts = c.int("cached", 0, span), c.int("motion"), c.int("restarts")
    # an old state's full context was rebuilt from its ring, as its stream would have: it holds no more to replay
    ctx.compactions = c.int("compactions", 0, COMPACTIONS) if compacted else COMPACTIONS * (ctx.cached == span)
    replayed = not (ctx.cached == span and ctx.compactions == COMPACTIONS)    # else its next step rebuilds
    if replayed and ctx.cached + ctx.compactions * (span - ctx.window + 1) > max(ctx.count - 1, 0):
        c.fail("cached", f"context tokens before the last of the {ctx.count} picked, with {ctx.compactions} "
                         f"compactions of {span - ctx.window + 1} tokens each")
    ctx.part, ctx.in_part = c.int("part", 0, len(ctx.parts) - 1), c.int("in_part")
    ctx.finished_at = c.int("finished_at", none=True)
    starts = c._get("starts")
    if not isinstance(starts, list) or not 1 <= len(starts) <= len(ctx.parts) or \
            any(isinstance(x, bool) or not isinstance(x, int) or x < 0 for x in starts):
        c.fail("starts", "token counts, one per action started")
    ctx.starts = starts
    ctx.rows_emb = ctx.policy.condition(ctx.parts[ctx.part][None])
    ctx.restart = c.bool("restart")
    ctx.resume = ctx.count > 0 and not ctx.restart     # the first step feeds the context again (plan)

    f = top.sub("frames")
    maker.chunk = f.int("chunk", 1, MAX_CHUNK)
    rows = f.sub("tokens")._get("shape")
    if not isinstance(rows, list) or not rows or rows[0] not in range(dims.receptive_field + 1,
                                                                     dims.receptive_field + MAX_CHUNK + 1):
        f.fail("tokens", f"a window of {dims.receptive_field} + 1 to {MAX_CHUNK} tokens")
    maker.tokens = f.array("tokens", "<i8", (rows[0], L))
    maker.count, maker.pending, maker.frames = f.int("count"), f.int("pending", 0, maker.chunk), f.int("frames")
    saved = f.data.get("decoder_state")     # absent from states saved before bundles had decoder_step
    if (saved is None) != (maker.state is None) or (saved is not None and (
            not isinstance(saved, list) or len(saved) != len(maker.state))):
        f.fail("decoder_state", "present exactly when the bundle has a decoder_step graph, one array per state "
                                f"({0 if maker.state is None else len(maker.state)})")
    if saved is not None:
        states = _Fields(dict(enumerate(saved)), f"{f.where}.decoder_state")
        maker.state = [states.array(i, "<f4", a.shape) for i, a in enumerate(maker.state)]
    root, lock = maker.joints.root, maker.joints.lock
    root.angle, root.position, root.previous = f.real("angle"), f.reals("position", 2), f.reals("previous", 3)
    lock.offset = f.reals("offset", 2)
    toes = f._get("toes")
    if toes is not None:
        if not isinstance(toes, list) or len(toes) != 2:
            f.fail("toes", "[toe (x, z) pairs, contacts]")
        toe, contact = np.array(toes[0], np.float64), np.array(toes[1])
        if toe.shape != (2, 2) or contact.shape != (2,) or contact.dtype != bool or not np.isfinite(toe).all():
            f.fail("toes", "[toe (x, z) pairs, contacts]")
        lock.previous = (toe, contact)

    s = top.sub("steering", none=True)
    if (s is None) != (character.steering is None):
        top.fail("steering", "present exactly when the bundle's model has control")
    if s is not None:
        steering = character.steering
        steering.target = _restore_target(s.sub("target", none=True))
        steering.pose, steering.frame = s.reals("pose", 3), s.int("frame")
        eases = s._get("eases")
        if not isinstance(eases, list) or not 1 <= len(eases) <= steering.warp.eases.maxlen:
            s.fail("eases", f"1 to {steering.warp.eases.maxlen} eases")
        kept = []
        for i, e in enumerate(eases):
            ef = _Fields(dict(zip(Ease._fields, e)) if isinstance(e, list) and len(e) == 10 else None,
                         f"steering.eases[{i}]")
            kept.append(Ease(ef.int("start"), *(ef.real(k) for k in Ease._fields[1:9]), ef.int("frames", 0, 1 << 16)))
        steering.warp.eases = deque(kept, maxlen=steering.warp.eases.maxlen)
        steering.warp.active = s.bool("active")
        if "plant" in s.data:          # else saved before feet were planted: none are
            p = s.sub("plant")
            pinned = p._get("pinned")
            if not isinstance(pinned, list) or len(pinned) != 2 or not all(isinstance(x, bool) for x in pinned):
                p.fail("pinned", "[left, right] true or false")
            steering.warp.plant.load(pinned, p.reals("values", STATE_FLOATS))
