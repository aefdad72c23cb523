"""The motion server's protocol (docs/serve.md): what a client may send, checked, and the limits that hold.

A client sends JSON text messages; the server answers in JSON text (replies, errors) and sends the motion as binary
token-stream messages (wire/format.py), one per tick holding the records of every character of the connection.

    {"op": "hello", "token": T}                        first, within Limits.hello_seconds: the bearer token
    {"op": "hello", "token": T, "session": S, "resume": {"3": 120}}   a reconnection: the session's characters go
                                                       on, each from the token the client expects next (one not
                                                       named, or no longer kept: from a SYNC of where it is now)
    {"op": "add", "prompt": P, "seed": 1, "seconds": 10, "ref": 7}   -> {"op": "added", "id": 0, "ref": 7}
    {"op": "request", "id": 0, "prompt": P, "n": 5}    a new prompt, and/or a control request (control/commands.py:
                                                       "goal", "path", "velocity", "root", "release")
    {"op": "joints", "id": 0, "on": true, "n": 6}      the character's joints too (JOINTS records)
    {"op": "remove", "id": 0}

`n` (optional, on request and joints: the two ops nothing answers) numbers a client's requests 1, 2, 3, ... within
its session. The server answers {"op": "applied", "n": 6} after the tick that carried them out (or refused them)
and is in the session's saved state, and a welcome says the last one applied (`"applied"`): a client keeps each
numbered request until then and sends those after it again on reconnecting, so a request its server got in the tick
it died in is not lost; one numbered at most the last applied is a copy, and is skipped.

A message that is not a JSON object of a known op with well-typed fields, a binary message, a message over
`max_message_bytes` or more than `messages_per_second` (with a burst of twice that) are the client's fault: it gets
one {"op": "error", "fatal": true, ...} and is disconnected. A request the server cannot carry out (a blank prompt,
a character that is not the client's, a limit reached) gets {"op": "error", "fatal": false, ...} and changes nothing.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

from ..checks import shown

OPS = {"hello": {"token", "session", "resume"}, "add": {"prompt", "seed", "seconds", "ref"},
       "request": None, "joints": {"id", "on", "n"}, "remove": {"id"}}
MAX_N = 2 ** 53 - 1        # a request number: what a JavaScript number counts exactly


@dataclass(frozen=True)
class Limits:
    characters_per_connection: int = 16
    characters: int = 4096             # in the whole server
    connections: int = 1024
    max_message_bytes: int = 64 << 10
    messages_per_second: float = 20.0
    hello_seconds: float = 5.0
    linger_seconds: float = 30.0       # a vanished client's characters wait this long for it to reconnect
    replay_tokens: int = 300           # per character: what a reconnecting client can ask again (60 s on base)
    send_queue: int = 64               # messages queued for a client that reads slowly; more and it is dropped


class ProtocolError(ValueError):
    """The client broke the protocol: one error message, then the connection is closed."""


class Refused(ValueError):
    """The server cannot do what a well-formed message asks: an error message, the connection stays."""


def parse(text: str) -> dict:
    """A client's text message -> its fields, with `op` known and its fields typed; else ProtocolError."""
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError):
        raise ProtocolError("a message must be a JSON object") from None
    if not isinstance(msg, dict) or msg.get("op") not in OPS:
        raise ProtocolError(f"a message is a JSON object with an op of {', '.join(OPS)}; got "
                            f"{shown(msg.get('op') if isinstance(msg, dict) else msg)}")
    op, allowed = msg["op"], OPS[msg["op"]]
    if allowed is not None:
        unknown = sorted(set(msg) - allowed - {"op"})
        if unknown:
            raise ProtocolError(f"{op}: unknown field(s) {', '.join(unknown)}")
    if op == "hello":
        _need(msg, "token", str)
        if "session" in msg:
            _need(msg, "session", str)
        resume = msg.get("resume", {})
        if not isinstance(resume, dict) or len(resume) > 65536 or not all(
                isinstance(k, str) and k.isdigit() and len(k) < 10 and _is_int(v) and v >= 0
                for k, v in resume.items()):
            raise ProtocolError("hello: resume must map character ids to the next token expected")
        if resume and "session" not in msg:
            raise ProtocolError("hello: resume needs the session")
        msg["resume"] = {int(k): v for k, v in resume.items()}
    elif op == "add":
        _need(msg, "prompt", str)
        if not _is_int(msg.get("seed", 0)) or not 0 <= msg.get("seed", 0) < 2 ** 63:
            raise ProtocolError("add: seed must be an int in [0, 2**63)")
        seconds = msg.get("seconds")
        if seconds is not None and (not isinstance(seconds, (int, float)) or isinstance(seconds, bool)
                                    or not math.isfinite(seconds)):
            raise ProtocolError("add: seconds must be a number or null")
        if "ref" in msg and not (_is_int(msg["ref"]) or isinstance(msg["ref"], str) and len(msg["ref"]) <= 64):
            raise ProtocolError("add: ref must be an int or a short string")
    else:
        if not _is_int(msg.get("id")) or msg["id"] < 0:
            raise ProtocolError(f"{op}: id must be a character id (an int >= 0)")
        if op == "joints" and not isinstance(msg.get("on"), bool):
            raise ProtocolError("joints: on must be true or false")
        if "n" in msg and not (_is_int(msg["n"]) and 1 <= msg["n"] <= MAX_N):
            raise ProtocolError(f"{op}: n must be a request number (an int in [1, 2**53))")
    return msg


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _need(msg: dict, key: str, kind: type) -> None:
    if not isinstance(msg.get(key), kind):
        raise ProtocolError(f"{msg['op']}: {key} must be a {kind.__name__}")


class RateLimit:
    """A token bucket: `rate` messages a second, bursts of 2 * rate."""

    def __init__(self, rate: float, now: float):
        self.rate, self.level, self.time = rate, 2 * rate, now

    def allow(self, now: float) -> bool:
        self.level = min(2 * self.rate, self.level + (now - self.time) * self.rate)
        self.time = now
        if self.level < 1:
            return False
        self.level -= 1
        return True
