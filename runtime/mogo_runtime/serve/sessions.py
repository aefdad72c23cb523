"""A motion server's sessions, and how they move between servers: saved (a SIGTERM's state file, a store's
checkpoint), restored, and handed from one server to another through a SessionStore (Ray replicas share one).

A server with a store writes each session to it every CHECKPOINT_TICKS ticks (the sessions spread over the ticks)
and at the end of every tick in which its client changed it (added or removed a character, a prompt, a control
request), before that tick's messages go out, with only the last CHECKPOINT_RECORDS of its characters' records (a
client further behind the checkpoint gets a SYNC). A character's tokens follow from its saved state and the requests
made since, so the store always holds a state from which the session goes on as it did, and with it the number of
the client's last request carried out (`applied`: the client sends the later ones again, protocol.py).

A client that reconnects to a server that does not know its session (Ray's proxy sent it to another replica, the one
it was on was removed or died) gets it from the store there: the server claims it (the server that had it
learns so at its next write and lets its copy go), runs the characters behind the client on to the token it expects
(`catch_up`: a crowd of their own, beside the server's ticks; at most CHECKPOINT_TICKS tokens when the old server
stopped), restores them and sends a SYNC of each, so the client's frames go on from where they were.
"""
from __future__ import annotations

import asyncio
import base64
import json
import time
import zlib
from collections import deque
from dataclasses import dataclass, field

from ..crowd import Character, Crowd
from ..state import restore_character, save_character
from ..wire.tap import CharacterTap

# 5 s of motion on base: the most a handed-over character runs on alone to catch up. Written every 5 ticks with their
# recent records, 400 characters of the tests' tiny model on one Ray replica ran at 0.68 of real time (p99 latency
# 374 ms); every 25 without them, at 0.94 (151 ms), as without a store (benchmarks/NOTES.md, "Issue 29")
CHECKPOINT_TICKS = 25
# A checkpoint's records of each character: a client a message or two behind it when its server went gets them (the
# last tick's message can be lost with the server) instead of a SYNC; all 300 a server keeps cost the most above.
CHECKPOINT_RECORDS = 8


@dataclass
class Hosted:
    """A character of a session: its crowd member, its stream writer, the records it sent lately (key: the first
    token of each tick's records); `sync`: its client gets a SYNC of it at the next welcome (a caught-up handover)."""

    character: Character
    tap: CharacterTap
    replay: deque = field(default_factory=deque)
    joints: bool = False
    sync: bool = False


@dataclass(eq=False)         # a session is itself (a dict key), not its fields
class Session:
    id: str
    characters: dict[int, Hosted] = field(default_factory=dict)
    next_id: int = 0
    applied: int = 0                         # the client's last numbered request carried out (protocol.py, `n`)
    acked: bool = False                      # on the tick thread: its client hears of `applied` after this tick
    queue: asyncio.Queue | None = None       # the connected client's outgoing messages; None while disconnected
    ws: object = None                        # its connection
    backlog: list | None = None              # messages of ticks that ended while its welcome was being written
    live: bool = False                       # on the tick thread: whether ticks go to the client or only to replay
    gone_at: float | None = None


def session_state(s: Session, records: int | None = None) -> dict:
    """The session as JSON-able data: its characters' states (state.py) and their recent records (the last
    `records` of them; None: all kept)."""
    def recent(replay: deque) -> list:
        kept = list(replay)
        return kept if records is None else kept[max(0, len(kept) - records):]
    return {"id": s.id, "next_id": s.next_id, "applied": s.applied, "characters": [{
        "id": ident, "state": save_character(h.character).decode(), "joints": h.joints,
        "replay": [[key, base64.b64encode(blob).decode()] for key, blob in recent(h.replay)]}
        for ident, h in s.characters.items()]}


def checkpoint_due(session: Session, tick: int) -> bool:
    """Whether tick `tick` writes the session to the store: one tick in CHECKPOINT_TICKS, which one by its id, so
    no tick writes them all."""
    return zlib.crc32(session.id.encode()) % CHECKPOINT_TICKS == tick % CHECKPOINT_TICKS


def restore_session(crowd: Crowd, data: dict, caught: dict[int, bytes] | None = None) -> Session:
    """`session_state`'s data -> the session, its characters members of `crowd` again. `caught`: a handover's
    characters run on to the token their client expects (`catch_up` of `behind`), restored from there; their client
    gets a SYNC of each. Data that does not fit raises ValueError (or KeyError, TypeError), and the characters
    restored so far leave the crowd."""
    session = Session(str(data["id"]), next_id=int(data["next_id"]), applied=int(data.get("applied", 0)),
                      gone_at=time.monotonic())
    caught = caught or {}
    try:
        for c in data["characters"]:
            ident = int(c["id"])
            character = restore_character(crowd, caught.get(ident, c["state"].encode()))
            # the tokens since its last record were made by catch_up, not kept: its client gets a SYNC instead
            replay = deque() if ident in caught else \
                deque((int(k), base64.b64decode(b, validate=True)) for k, b in c["replay"])
            session.characters[ident] = Hosted(character, CharacterTap(character, ident, started=True), replay,
                                               bool(c["joints"]), sync=ident in caught)
    except BaseException:
        for h in session.characters.values():
            crowd.remove(h.character)
        raise
    return session


def behind(data: dict, resume: dict[int, int]) -> dict[int, tuple[bytes, int]]:
    """The characters of `session_state`'s data whose client expects a token they have not made (the server that
    had them made it after its last checkpoint) -> (state, the token expected)."""
    out = {}
    for c in data["characters"]:
        expected = resume.get(int(c["id"]))
        if expected is not None and expected > json.loads(c["state"])["context"]["count"]:
            out[int(c["id"])] = (c["state"].encode(), expected)
    return out


def catch_up(gen, states: dict[int, tuple[bytes, int]]) -> dict[int, bytes]:
    """Saved characters (ident -> (state, tokens)) run on in a crowd of their own until each has its `tokens` (or
    its limit) -> their states then. A crowd's rows are computed independently, so these are the tokens each had in
    its own crowd. The cost is each context's rebuild (benchmarks/handover.py: ~50 ms a character on base)."""
    if not states:
        return {}
    crowd = Crowd(gen, max_characters=len(states))
    running = {ident: restore_character(crowd, state) for ident, (state, _) in states.items()}
    out = {}
    while running:
        for ident, c in list(running.items()):
            if c.count >= states[ident][1] or c.done:
                out[ident] = save_character(c)
                crowd.remove(c)
                del running[ident]
        if running:
            crowd.tick()
    return out


class SessionStore:
    """The sessions of a deployment's servers, each held by one (its owner): `put` by the owner, `claim` by a server
    a client reconnects to. Under Ray it runs as one actor the replicas share (serve/ray.py); in one process, as is.
    A session not written for `forget_seconds` (its server died, and no client came back for it) is forgotten:
    `forget_for` gives a server's clients its whole linger after its last checkpoint."""

    def __init__(self, forget_seconds: float):
        self.forget_seconds = forget_seconds
        self.sessions: dict[str, tuple[str, float, str]] = {}      # id -> (owner, when written, the state as JSON)

    def put(self, owner: str, states: dict[str, str], dropped: list[str]) -> list[str]:
        """The owner's sessions written (`states`) and let go (`dropped`) -> those of them another server claimed
        since (the owner lets its copy go)."""
        now, lost = time.monotonic(), []
        for sid in dropped:
            if self.sessions.get(sid, (owner,))[0] == owner:
                self.sessions.pop(sid, None)
        for sid, state in states.items():
            held = self.sessions.get(sid)
            if held is not None and held[0] != owner:
                lost.append(sid)
            else:
                self.sessions[sid] = (owner, now, state)
        for sid, (_, when, _) in list(self.sessions.items()):
            if now - when > self.forget_seconds:
                del self.sessions[sid]
        return lost

    def claim(self, session: str, owner: str) -> str | None:
        """The session's last state (JSON), now `owner`'s; None when the store does not have it."""
        held = self.sessions.get(session)
        if held is None or time.monotonic() - held[1] > self.forget_seconds:
            return None
        self.sessions[session] = (owner, time.monotonic(), held[2])
        return held[2]


def forget_for(linger_seconds: float, tick_seconds: float) -> float:
    """How long a store keeps a session nobody writes: a vanished client's linger, counted from its server's last
    checkpoint of it, which can be CHECKPOINT_TICKS ticks before the server died (twice that, for slow ticks)."""
    return linger_seconds + 2 * CHECKPOINT_TICKS * tick_seconds


class LocalStore:
    """A SessionStore in this process, called as a server calls a store (awaited): servers of one process, tests."""

    def __init__(self, store: SessionStore):
        self.store = store

    async def put(self, owner: str, states: dict[str, str], dropped: list[str]) -> list[str]:
        return self.store.put(owner, states, dropped)

    async def claim(self, session: str, owner: str) -> str | None:
        return self.store.claim(session, owner)
