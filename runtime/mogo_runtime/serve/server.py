"""The motion server: one crowd, stepped in real time, whose characters belong to the WebSocket clients that added
them; every tick each client gets one binary token-stream message with its characters' records (protocol.py).

    server = MotionServer(MotionGenerator("bundles/base", variant="compact"), token="...", state_file="serve.state")
    asyncio.run(server.serve("127.0.0.1", 8765))        # `mogo serve BUNDLE --port 8765`

The authority generates; clients decode (wire/client.py). A tick (one token for every character, 0.2 s of motion
on base) runs on a worker thread, with the clients' requests applied just before it, so the event loop keeps
answering while the model runs. Nothing is lost:
- a client that disconnects keeps its characters for `linger_seconds`; reconnecting with its session and the next
  token it expects of each character, it gets the records it missed (kept `replay_tokens` per character) and goes on;
  a character it missed more of, or did not name (a client that lost its decoder, a page reloaded), it gets as a
  SYNC of where the character is now (and a START before it, where not named): its frames jump there, exactly;
- SIGTERM stops the ticks, saves every character's state (state.py), its recent records and its session to
  `state_file`, written whole or not at all; a server started on that file restores them, so clients that reconnect
  continue from their last sequence number with the tokens they would have had.
"""
from __future__ import annotations

import asyncio
import base64
import functools
import hmac
import json
import os
import secrets
import signal
import sys
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from ..control.commands import request_from
from ..crowd import Character, Crowd
from ..state import restore_character, save_character
from ..wire import format as wire
from ..wire.tap import CharacterTap, sync
from .protocol import Limits, ProtocolError, RateLimit, Refused, parse

STATE_FORMAT = "mogo.server/1"


@dataclass
class Hosted:
    """A character of a session: its crowd member, its stream writer, the records it sent lately (key: the first
    token of each tick's records)."""

    character: Character
    tap: CharacterTap
    replay: deque = field(default_factory=deque)
    joints: bool = False


@dataclass(eq=False)         # a session is itself (a dict key), not its fields
class Session:
    id: str
    characters: dict[int, Hosted] = field(default_factory=dict)
    next_id: int = 0
    queue: asyncio.Queue | None = None       # the connected client's outgoing messages; None while disconnected
    ws: object = None                        # its connection
    backlog: list | None = None              # messages of ticks that ended while its welcome was being written
    live: bool = False                       # on the tick thread: whether ticks go to the client or only to replay
    gone_at: float | None = None


class MotionServer:
    def __init__(self, gen, token: str, limits: Limits = Limits(), state_file: str | Path | None = None,
                 origins: list[str] | None = None, speed: float = 1.0, status_seconds: float = 0.0):
        if len(token) < 16:
            raise ValueError("the server's bearer token must be at least 16 characters")
        # browsers send an Origin: only those listed connect; None stands for clients that send none (not browsers)
        self.origins = [None] if origins is None else list(origins)
        self.gen, self.token, self.limits = gen, token.encode(), limits
        self.crowd = Crowd(gen, max_characters=limits.characters)
        self.hello = wire.encode(wire.hello_for(gen.bundle.manifest, gen.variant))
        self.period = gen.dims.downsample / gen.dims.fps / speed
        self.sessions: dict[str, Session] = {}
        self.id = secrets.token_hex(4)       # which server (which Ray replica) a client is on, in its welcome
        # every change to the crowd and the sessions' characters runs on this one thread, between ticks
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="mogo-tick")
        self.commands: deque = deque()       # the clients' requests, applied on that thread before the next tick
        self.state_file = Path(state_file) if state_file else None
        self.ticks, self.tick_seconds, self.status_seconds = 0, deque(maxlen=100_000), status_seconds
        if self.state_file is not None and self.state_file.exists():
            self._restore(self.state_file)

    # ---- the tick: on the worker thread ----

    def _advance(self) -> tuple[list, dict[Session, bytes]]:
        replies = []
        while self.commands:
            replies.extend(self.commands.popleft()())
        self._expire()
        start = time.perf_counter()
        frames = self.crowd.tick() if len(self.crowd) else {}
        out: dict[Session, bytes] = {}
        for session in list(self.sessions.values()):
            blobs = []
            for ident, h in list(session.characters.items()):
                key = h.tap.sent
                records = h.tap.read()
                if h.character.slot is None:           # its `seconds` are done: the crowd let it go
                    records.append(wire.Event(ident, h.tap.sent, wire.END))
                    del session.characters[ident]
                if h.joints and h.character in frames:
                    f = frames[h.character]
                    records.append(wire.Joints(ident, f.index, f.joints))
                if records:
                    blob = b"".join(map(wire.encode, records))
                    h.replay.append((key, blob))
                    while len(h.replay) > self.limits.replay_tokens:
                        h.replay.popleft()
                    blobs.append(blob)
            if blobs and session.live:      # else the replay has them, for when the client comes back
                out[session] = b"".join(blobs)
        self.ticks += 1
        stamp = wire.encode(wire.Tick(self.ticks, time.monotonic()))
        out = {session: stamp + blob for session, blob in out.items()}
        self.tick_seconds.append(time.perf_counter() - start)
        return replies, out

    def _add(self, session: Session, ident: int, msg: dict):
        def run():
            if self.sessions.get(session.id) is not session:     # the client left and its session expired
                return []
            try:
                if len(session.characters) >= self.limits.characters_per_connection:
                    raise Refused(f"a connection holds at most {self.limits.characters_per_connection} characters")
                if len(self.crowd) >= self.limits.characters:
                    raise Refused(f"the server holds {self.limits.characters} characters, its limit")
                c = self.crowd.add(msg["prompt"], seed=msg.get("seed", 0), seconds=msg.get("seconds"))
            except ValueError as e:
                return [(session, _error(str(e), about="add"))]
            session.characters[ident] = Hosted(c, CharacterTap(c, ident))
            return [(session, json.dumps({"op": "added", "id": ident, "ref": msg.get("ref")}))]
        return run

    def _request(self, session: Session, msg: dict):
        def run():
            h = session.characters.get(msg["id"])
            try:
                if h is None:
                    raise Refused(f"no character {msg['id']} in this session")
                if msg["op"] == "remove":
                    self.crowd.remove(h.character)
                    blob = b"".join(map(wire.encode, h.tap.end()))
                    h.replay.append((h.tap.sent, blob))
                    del session.characters[msg["id"]]
                    return [(session, blob), (session, json.dumps({"op": "removed", "id": msg["id"]}))]
                if msg["op"] == "joints":
                    h.joints = msg["on"]
                    return []
                request_from({k: v for k, v in msg.items() if k not in ("op", "id")}).apply(h.character)
            except ValueError as e:
                return [(session, _error(str(e), about=msg["op"]))]
            return []
        return run

    # ---- connections: on the event loop ----

    async def handler(self, ws) -> None:
        session = None
        try:
            session = await self._welcome(ws)
            session.ws = ws
            writer = asyncio.create_task(self._write(ws, session.queue))
            rate = RateLimit(self.limits.messages_per_second, time.monotonic())
            try:
                async for text in ws:
                    if not isinstance(text, str):
                        raise ProtocolError("the server takes JSON text messages, not binary")
                    if not rate.allow(time.monotonic()):
                        raise ProtocolError(f"more than {self.limits.messages_per_second:g} messages a second")
                    self._dispatch(session, parse(text))
            finally:
                writer.cancel()
        except ProtocolError as e:
            await _close(ws, str(e))
        except ConnectionError:       # the client left mid-message (a Starlette connection says so; websockets ends)
            pass
        except Exception as e:
            if not type(e).__name__.startswith("ConnectionClosed"):    # websockets': the client left
                raise
        finally:
            if session is not None and session.ws is ws:
                # a session without characters has nothing to come back for
                gone = time.monotonic() - (self.limits.linger_seconds if not session.characters else 0)
                session.queue, session.ws, session.gone_at, session.live = None, None, gone, False

    async def _welcome(self, ws) -> Session:
        try:
            text = await asyncio.wait_for(ws.recv(), self.limits.hello_seconds)
        except asyncio.TimeoutError:
            raise ProtocolError(f"no hello within {self.limits.hello_seconds:g} s") from None
        if not isinstance(text, str):
            raise ProtocolError("the first message must be a JSON hello")
        msg = parse(text)
        if msg["op"] != "hello":
            raise ProtocolError("the first message must be a hello")
        if not hmac.compare_digest(msg["token"].encode(), self.token):
            raise ProtocolError("wrong token")
        if "session" in msg:
            session = self.sessions.get(msg["session"])
            if session is None:
                raise ProtocolError("unknown or expired session")
            if session.queue is not None:
                raise ProtocolError("that session is connected elsewhere")
        else:
            if self._connected() >= self.limits.connections:
                raise ProtocolError(f"the server has {self.limits.connections} connections, its limit")
            session = Session(secrets.token_urlsafe(18))     # registered by _resume, on the tick thread
        queue = asyncio.Queue(self.limits.send_queue)
        welcome = await asyncio.get_running_loop().run_in_executor(self.pool, self._resume, session, msg["resume"],
                                                                   queue)
        # no await from here on: the welcome, then what ticks made meanwhile, then the ticks as they come
        for message in [*welcome, *session.backlog]:
            queue.put_nowait(message)
        session.backlog = None
        return session

    def _resume(self, session: Session, resume: dict[int, int], queue: asyncio.Queue) -> list:
        """On the tick thread: the welcome and the records a reconnecting client missed; from now on the session's
        tick messages wait in its backlog until the handler has queued these. A new session is registered here:
        the sessions change only on this thread, which iterates them while the event loop reads them."""
        if self.sessions.get(session.id) is not session:
            if session.characters:       # expired meanwhile (_expire removed it and its characters)
                raise ProtocolError("unknown or expired session")
            self.sessions[session.id] = session
        replay, synced = [], []
        for ident, h in session.characters.items():
            expected = resume.get(ident)
            if expected is None or (h.replay and h.replay[0][0] > expected):
                # the client has nothing of it, or missed more than is kept: it joins the character where it is now
                start = [] if expected is not None else [wire.Event(ident, h.tap.sent, wire.START, h.character.text)]
                replay.append(b"".join(map(wire.encode, [*start, sync(h.character, ident)])))
                synced.append(ident)
            else:
                replay.extend(blob for key, blob in h.replay if key >= expected)
        session.queue, session.backlog, session.gone_at, session.live = queue, [], None, True
        return [json.dumps({"op": "welcome", "session": session.id, "server": self.id,
                            "characters": {str(i): h.tap.sent for i, h in session.characters.items()},
                            "synced": synced}),
                self.hello + b"".join(replay)]

    def _dispatch(self, session: Session, msg: dict) -> None:
        if msg["op"] == "hello":
            raise ProtocolError("hello once, first")
        if msg["op"] == "add":
            ident, session.next_id = session.next_id, session.next_id + 1
            self.commands.append(self._add(session, ident, msg))
        else:
            self.commands.append(self._request(session, msg))

    async def _write(self, ws, queue: asyncio.Queue) -> None:
        try:
            while True:
                await ws.send(await queue.get())
        except Exception:        # the connection closed: the handler's read loop ends and cleans up
            pass

    def _deliver(self, session: Session, message) -> None:
        if session.queue is None:
            return
        if session.backlog is not None:
            session.backlog.append(message)
            return
        try:
            session.queue.put_nowait(message)
        except asyncio.QueueFull:      # a client that does not read: dropped, its characters linger
            ws, session.queue, session.ws = session.ws, None, None
            session.gone_at, session.live = time.monotonic(), False
            if ws is not None:
                asyncio.create_task(_close(ws, f"{self.limits.send_queue} messages unread: the client is too slow"))

    def _connected(self) -> int:
        # list() copies the dict in one step, so the tick thread cannot change it halfway through the count
        return sum(s.queue is not None for s in list(self.sessions.values()))

    def status(self) -> str:
        """One line: ticks, characters, sessions, tick times since the last status line, memory."""
        times = sorted(self.tick_seconds)
        self.tick_seconds.clear()
        p50, p99 = (times[len(times) // 2], times[min(len(times) - 1, int(0.99 * len(times)))]) if times else (0, 0)
        return (f"tick {self.ticks}, {len(self.crowd)} characters, {self._connected()}"
                f" clients, tick p50 {1e3 * p50:.2f} ms p99 {1e3 * p99:.2f} ms (of {1e3 * self.period:.0f}), "
                f"rss {_rss_mb():.0f} MB")

    async def run(self, stop: asyncio.Event) -> None:
        """Tick in real time until `stop` is set; a status line on stderr every `status_seconds`."""
        loop = asyncio.get_running_loop()
        deadline = last_status = last_trim = loop.time()
        while not stop.is_set():
            if self.status_seconds and loop.time() - last_status >= self.status_seconds:
                last_status = loop.time()
                print(f"mogo serve: {self.status()}", file=sys.stderr, flush=True)
            if loop.time() - last_trim >= TRIM_SECONDS:
                last_trim = loop.time()
                await loop.run_in_executor(self.pool, _return_free_memory)
            replies, out = await loop.run_in_executor(self.pool, self._advance)
            for session, message in replies:
                self._deliver(session, message)
            for session, message in out.items():
                self._deliver(session, message)
            deadline += self.period
            delay = deadline - loop.time()
            if delay < -10 * self.period:      # far behind (a machine too busy): start counting again from now
                deadline = loop.time()
            try:
                await asyncio.wait_for(stop.wait(), max(delay, 0))
            except asyncio.TimeoutError:
                pass

    def _expire(self) -> None:
        now = time.monotonic()
        for sid, session in list(self.sessions.items()):
            if session.queue is None and session.gone_at is not None \
                    and now - session.gone_at > self.limits.linger_seconds:
                for h in session.characters.values():
                    if h.character.slot is not None:
                        self.crowd.remove(h.character)
                del self.sessions[sid]

    async def serve(self, host: str, port: int, ready=None, stop: asyncio.Event | None = None) -> None:
        """Serve until `stop` is set (default: SIGTERM or SIGINT); then save the state (`state_file`) and return.
        `ready(server)` is called once it listens (its `sockets` say the port)."""
        from websockets.asyncio.server import serve

        loop = asyncio.get_running_loop()
        if stop is None:
            stop = asyncio.Event()
            for sig in (signal.SIGTERM, signal.SIGINT):
                loop.add_signal_handler(sig, stop.set)
        async with serve(self.handler, host, port, origins=self.origins, compression=None,
                         max_size=self.limits.max_message_bytes, max_queue=4, ping_interval=10,
                         ping_timeout=10, close_timeout=CLOSE_SECONDS,
                         create_connection=_connection_class()) as server:
            if ready is not None:
                ready(server)
            await self.run(stop)
            if self.state_file is not None:
                await loop.run_in_executor(self.pool, self.save, self.state_file)
            server.close()
        self.pool.shutdown()

    # ---- state ----

    def save(self, path: Path) -> None:
        """Every session and character to `path`, atomically (a temporary file renamed over it)."""
        data = {"format": STATE_FORMAT, "sessions": [{
            "id": s.id, "next_id": s.next_id, "characters": [{
                "id": ident, "state": save_character(h.character).decode(), "joints": h.joints,
                "replay": [[key, base64.b64encode(blob).decode()] for key, blob in h.replay]}
                for ident, h in s.characters.items()]} for s in self.sessions.values()]}
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w") as f:
            json.dump(data, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)

    def _restore(self, path: Path) -> None:
        try:
            data = json.loads(path.read_text())
            if data.get("format") != STATE_FORMAT:
                raise ValueError(f"format is not {STATE_FORMAT}")
            for s in data["sessions"]:
                session = Session(str(s["id"]), next_id=int(s["next_id"]), gone_at=time.monotonic())
                for c in s["characters"]:
                    character = restore_character(self.crowd, c["state"].encode())
                    tap = CharacterTap(character, int(c["id"]), started=True)
                    replay = deque((int(k), base64.b64decode(b, validate=True)) for k, b in c["replay"])
                    session.characters[int(c["id"])] = Hosted(character, tap, replay, bool(c["joints"]))
                self.sessions[session.id] = session
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise ValueError(f"{path}: not a motion server's saved state ({e})") from None
        path.rename(path.with_name(path.name + ".restored"))     # restored once: a later crash cannot replay it


# How long a client the server closed has to answer the close before its connection is dropped (websockets' default
# is 10 s).
CLOSE_SECONDS = 2.0


def _connection_class():
    """websockets' server connection, except that it stops reading from a client whose frames the protocol refused
    (too big, not WebSocket). websockets then reads and discards whatever the client still sends until it closes:
    on loopback a 16 MB message cost the server 10-20 ms of its tick thread's CPU (benchmarks/serve_load.py).
    Paused, the kernel's buffers fill and the client's writes stall; the connection ends at CLOSE_SECONDS."""
    from websockets.asyncio.server import ServerConnection
    from websockets.frames import CloseCode

    refused = {CloseCode.PROTOCOL_ERROR, CloseCode.UNSUPPORTED_DATA, CloseCode.INVALID_DATA,
               CloseCode.MESSAGE_TOO_BIG}

    class RefusingConnection(ServerConnection):
        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            sent = self.protocol.close_sent
            if sent is not None and self.protocol.close_rcvd is None and sent.code in refused:
                self.transport.pause_reading()

    return RefusingConnection


# How often the tick thread hands the memory malloc holds free back to the system. glibc keeps freed blocks in its
# heap: a restored server's characters rebuild their contexts together, and their passing peak stayed resident (800
# characters of the tests' tiny model: 322 MB against 226 for the same crowd started staggered; 207 and 206 after
# a trim). A trim took 2.6 ms there, 11 ms beside 256 base characters.
TRIM_SECONDS = 30.0


def _return_free_memory() -> None:
    """glibc's malloc_trim(0); nothing elsewhere (other C libraries manage their heaps their own way)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.cache
def _malloc_trim():
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


def _rss_mb() -> float:
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024
    except (OSError, StopIteration, ValueError):
        return float("nan")


def _error(message: str, fatal: bool = False, about: str | None = None) -> str:
    """`about`: the op of the message refused (a client waiting for one reply tells the others apart)."""
    return json.dumps({"op": "error", "fatal": fatal, "message": message, "about": about})


async def _close(ws, message: str) -> None:
    try:
        await ws.send(_error(message, fatal=True))
        await ws.close(1008, message[:120])
    except Exception:        # the connection is already gone: nothing to tell it
        pass
