"""The generating side of a token stream: what a crowd's character did since it was last read, as records.

    tap = CharacterTap(character, ident)      # right after crowd.add (or a restore): its START
    crowd.tick()
    records = tap.read()                     # every tick: its events, its new token, its root corrections

`ident` is the number the stream calls the character (a server numbers each connection's characters itself).
Read every tick: a tap that falls behind by more than the tokens a record holds, or the warp plans a character
keeps, raises rather than send a stream with a hole in it. A tap made once the character has tokens starts the
stream with its START and a SYNC (`sync`): a client that joins then decodes the crowd's frames from there on.
"""
from __future__ import annotations

import json

import numpy as np

from ..control.plant import STATE_FLOATS
from .format import CONTROL, END, PROMPT, RESTART, START, Event, Record, Sync, Tokens, Warp, WireError


def describe(target) -> str:
    """A control request as JSON text (the CONTROL event's text): informative, a client decodes without it."""
    if target is None:
        return json.dumps({"release": True})
    name = type(target).__name__
    if name == "WalkTo":
        return json.dumps({"walk_to": target.goal.tolist(), "speed": target.speed})
    if name == "FollowPath":
        return json.dumps({"path_points": len(target.points), "speed": target.speed})
    if name == "Steer":
        return json.dumps({"velocity": target.velocity.tolist(),
                           "facing": None if target.facing is None else target.facing.tolist()})
    return json.dumps({"game_root": True})


def sync(character, ident: int) -> Sync:
    """The character's decoder side now, after its last token (a crowd's Character: its FrameMaker and warp)."""
    maker = character.frames
    root, lock = maker.joints.root, maker.joints.lock
    rows = min(maker.count, maker.dims.receptive_field + maker.pending)
    state = np.zeros(0, np.float32) if maker.state is None else np.concatenate([s.ravel() for s in maker.state])
    warp = character.steering.warp if character.steering is not None else None
    eases = tuple(warp.eases) if warp is not None else ((0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0),)
    window = maker.window(rows).copy() if rows else maker.tokens[:0].copy()
    pinned, plant = warp.plant.state() if warp is not None else ([False, False], [0.0] * STATE_FLOATS)
    return Sync(ident, maker.count, maker.pending, window, state,
                np.array([root.angle, *root.position, *root.previous, *lock.offset], np.float64),
                None if lock.previous is None else lock.previous[0].copy(),
                (False, False) if lock.previous is None else tuple(bool(x) for x in lock.previous[1]),
                warp is not None and warp.active, eases, tuple(pinned), np.array(plant, np.float64))


class CharacterTap:
    """`started`: the stream already has the character's START (a character restored where it was saved)."""

    def __init__(self, character, ident: int, started: bool = False):
        self.character, self.ident = character, ident
        self.sent = character.count                     # tokens already in the stream
        self.switch = character.switches[-1] if character.switches else None     # the last switch sent
        self.restarts = character.restarts
        steering = character.steering
        self.target = steering.target if steering is not None else None
        self.plans = steering.warp.planned if steering is not None else 0
        self.pending: list[Record] = [] if started else [Event(ident, self.sent, START, character.text)]
        if not started and character.count:
            self.pending.append(sync(character, ident))

    def read(self) -> list[Record]:
        """The records since the last read, in stream order: events, then tokens, then root corrections."""
        c, out = self.character, self.pending
        self.pending = []
        new = []          # the switches after the last one sent, found from the newest back (a tick reads one or none)
        for switch in reversed(c.switches):
            if switch is self.switch:
                break
            new.append(switch)
        for seq, text in reversed(new):
            out.append(Event(self.ident, seq, PROMPT, text))
        self.switch = c.switches[-1] if c.switches else None
        if c.steering is not None and c.steering.target is not self.target:
            self.target = c.steering.target
            out.append(Event(self.ident, self.sent, CONTROL, describe(self.target)))
        if c.restarts != self.restarts:
            out.append(Event(self.ident, max(self.sent, c.count - 1), RESTART, str(c.restarts - self.restarts)))
            self.restarts = c.restarts
        new = c.count - self.sent
        if new > 0:
            if new > 1:
                raise WireError(f"character {self.ident}: {new} tokens since the last read; a tap is read every tick")
            out.append(Tokens(self.ident, self.sent, np.asarray(c.context.last)[None]))
            self.sent = c.count
        if c.steering is not None:
            out.extend(self._warps(c.steering.warp))
        return out

    def end(self) -> list[Record]:
        """The character's last records: what is left, and END."""
        return [*self.read(), Event(self.ident, self.sent, END)]

    def _warps(self, warp) -> list[Record]:
        new = warp.planned - self.plans
        if new > len(warp.plans):
            raise WireError(f"character {self.ident}: {new} root corrections since the last read, "
                            f"{len(warp.plans)} kept")
        self.plans = warp.planned
        return [Warp(self.ident, start, frames, (px, pz), turn, (sx, sz))
                for start, frames, px, pz, turn, sx, sz in list(warp.plans)[len(warp.plans) - new:]]
