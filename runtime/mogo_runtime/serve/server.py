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
  continue from their last sequence number with the tokens they would have had;
- with a `store` (sessions.py; Ray replicas share one), sessions are checkpointed there, and a client whose server
  was removed or died reconnects to another, which takes its session over and goes on with the same tokens; the
  requests the dead server received and did not carry out, the client sends again (numbered: protocol.py).
"""
from __future__ import annotations

import asyncio
import hmac
import json
import os
import secrets
import signal
import sys
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from ..control.commands import request_from
from ..crowd import Crowd
from ..wire import format as wire
from ..wire.tap import CharacterTap, sync
from .connection import CLOSE_SECONDS, close_with_error, connection_class, error_message
from .memory import TRIM_SECONDS, return_free_memory, rss_mb
from .protocol import Limits, ProtocolError, RateLimit, Refused, parse
from .sessions import (CHECKPOINT_RECORDS, Hosted, Session, behind, catch_up, checkpoint_due, restore_session,
                       session_state)

STATE_FORMAT = "mogo.server/1"


class MotionServer:
    def __init__(self, gen, token: str, limits: Limits = Limits(), state_file: str | Path | None = None,
                 origins: list[str] | None = None, speed: float = 1.0, status_seconds: float = 0.0, store=None):
        """`store`: a SessionStore as awaitable `put` and `claim` (sessions.py; a Ray actor under `--ray`), to which
        sessions are checkpointed and from which a client another server had is taken over."""
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
        self.store, self.changed, self.dropped = store, set(), []     # sessions to write to the store, to let go
        if self.state_file is not None and self.state_file.exists():
            self._restore(self.state_file)

    # ---- the tick: on the worker thread ----

    def _advance(self) -> tuple[list, dict[Session, bytes], tuple[dict[str, str] | None, bool]]:
        replies = []
        while self.commands:
            session, command = self.commands.popleft()
            self.changed.add(session)
            replies.extend(command())
        for session in self.changed:
            if session.acked:
                session.acked = False
                replies.append((session, json.dumps({"op": "applied", "n": session.applied})))
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
        return replies, out, self._checkpoint()

    def _checkpoint(self) -> tuple[dict[str, str] | None, bool]:
        """The sessions to write to the store after this tick (each one every CHECKPOINT_TICKS ticks, and those
        changed; sessions.py), as JSON, None without a store; and whether a client changed one (then the write
        comes before the tick's messages: what a client sees of its requests, the store has)."""
        if self.store is None:
            self.changed = set()
            return None, False
        write = {s for s in self.sessions.values() if checkpoint_due(s, self.ticks)}
        changed = {s for s in self.changed if self.sessions.get(s.id) is s}
        self.changed = set()
        return {s.id: json.dumps(session_state(s, CHECKPOINT_RECORDS)) for s in write | changed}, bool(changed)

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
                return [(session, error_message(str(e), about="add"))]
            session.characters[ident] = Hosted(c, CharacterTap(c, ident))
            return [(session, json.dumps({"op": "added", "id": ident, "ref": msg.get("ref")}))]
        return run

    def _request(self, session: Session, msg: dict):
        def run():
            if "n" in msg:
                if msg["n"] <= session.applied:     # sent again after a reconnect, but carried out before
                    return []
                session.applied, session.acked = msg["n"], True
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
                request_from({k: v for k, v in msg.items() if k not in ("op", "id", "n")}).apply(h.character)
            except ValueError as e:
                return [(session, error_message(str(e), about=msg["op"]))]
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
            await close_with_error(ws, str(e))
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
        taken = None            # (state, characters caught up) of a session another server had, from the store
        if "session" in msg:
            session = self.sessions.get(msg["session"])
            if session is None and self.store is not None:
                taken = await self._claim(msg["session"], msg["resume"])
            if session is None and taken is None:
                raise ProtocolError("unknown or expired session")
            if session is not None and session.queue is not None:
                raise ProtocolError("that session is connected elsewhere")
        else:
            if self._connected() >= self.limits.connections:
                raise ProtocolError(f"the server has {self.limits.connections} connections, its limit")
            session = Session(secrets.token_urlsafe(18))     # registered by _resume, on the tick thread
        queue = asyncio.Queue(self.limits.send_queue)
        session, welcome = await asyncio.get_running_loop().run_in_executor(self.pool, self._resume, session,
                                                                            msg["resume"], queue, taken)
        # no await from here on: the welcome, then what ticks made meanwhile, then the ticks as they come
        for message in [*welcome, *session.backlog]:
            queue.put_nowait(message)
        session.backlog = None
        return session

    def _resume(self, session: Session | None, resume: dict[int, int], queue: asyncio.Queue,
                taken: tuple[dict, dict[int, bytes]] | None = None) -> tuple[Session, list]:
        """On the tick thread: the session (restored from `taken`, a state another server had), the welcome and the
        records a reconnecting client missed; from now on the session's tick messages wait in its backlog until the
        handler has queued these. A new session is registered here: the sessions change only on this thread, which
        iterates them while the event loop reads them."""
        if taken is not None:
            session = self._take_over(*taken)
        elif self.sessions.get(session.id) is not session:
            if session.characters:       # expired meanwhile (_expire removed it and its characters)
                raise ProtocolError("unknown or expired session")
            self.sessions[session.id] = session
        replay, synced = [], []
        for ident, h in session.characters.items():
            expected = resume.get(ident)
            kept = expected is not None and (expected >= h.tap.sent or bool(h.replay) and h.replay[0][0] <= expected)
            if not kept or h.sync:
                h.sync = False
                # the client has nothing of it, or missed more than is kept: it joins the character where it is now
                start = [] if expected is not None else [wire.Event(ident, h.tap.sent, wire.START, h.character.text)]
                replay.append(b"".join(map(wire.encode, [*start, sync(h.character, ident)])))
                synced.append(ident)
            else:
                replay.extend(blob for key, blob in h.replay if key >= expected)
        session.queue, session.backlog, session.gone_at, session.live = queue, [], None, True
        return session, [json.dumps({"op": "welcome", "session": session.id, "server": self.id,
                                     "characters": {str(i): h.tap.sent for i, h in session.characters.items()},
                                     "synced": synced, "applied": session.applied}),
                         self.hello + b"".join(replay)]

    def _dispatch(self, session: Session, msg: dict) -> None:
        if msg["op"] == "hello":
            raise ProtocolError("hello once, first")
        if msg["op"] == "add":
            ident, session.next_id = session.next_id, session.next_id + 1
            self.commands.append((session, self._add(session, ident, msg)))
        else:
            self.commands.append((session, self._request(session, msg)))

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
                asyncio.create_task(close_with_error(
                    ws, f"{self.limits.send_queue} messages unread: the client is too slow"))

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
                f"rss {rss_mb():.0f} MB")

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
                await loop.run_in_executor(self.pool, return_free_memory)
            replies, out, (checkpoint, changed) = await loop.run_in_executor(self.pool, self._advance)
            if changed:        # a server that dies now has shown its clients nothing the store does not hold
                await self._write_store(checkpoint)
                checkpoint = None
            for session, message in replies:
                self._deliver(session, message)
            for session, message in out.items():
                self._deliver(session, message)
            if checkpoint or self.dropped:      # most ticks write nothing: no call to the store then
                await self._write_store(checkpoint or {})
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
                self._let_go(session)
                self.dropped.append(sid)

    def _let_go(self, session: Session) -> None:
        """On the tick thread: the session and its characters leave this server."""
        for h in session.characters.values():
            if h.character.slot is not None:
                self.crowd.remove(h.character)
        if self.sessions.get(session.id) is session:
            del self.sessions[session.id]

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
                         create_connection=connection_class()) as server:
            if ready is not None:
                ready(server)
            await self.run(stop)
            if self.state_file is not None:
                await loop.run_in_executor(self.pool, self.save, self.state_file)
            server.close()
        self.pool.shutdown()

    # ---- state ----

    async def _write_store(self, states: dict[str, str]) -> None:
        """The checkpoint to the store; the sessions another server claimed meanwhile are let go here. A store that
        fails is said on stderr, once a failure, and the server carries on (its clients lose nothing unless it dies)."""
        dropped, self.dropped = self.dropped, []
        try:
            lost = await self.store.put(self.id, states, dropped)
        except Exception as e:
            print(f"mogo serve: the session store failed ({type(e).__name__}: {e}); will write again",
                  file=sys.stderr, flush=True)
            self.dropped = dropped + self.dropped
            return
        if lost:
            def let_go():
                for sid in lost:
                    session = self.sessions.get(sid)
                    if session is not None and session.queue is None:     # its client is on another server now
                        self._let_go(session)
            await asyncio.get_running_loop().run_in_executor(self.pool, let_go)

    async def _claim(self, sid: str, resume: dict[int, int]) -> tuple[dict, dict[int, bytes]] | None:
        """A session another server had, now this server's (the store says so) -> its state, and its characters
        that are behind their client run on to the token it expects (sessions.py): on a thread of their own, beside
        the ticks. None when the store does not have it."""
        try:
            state = await self.store.claim(sid, self.id)
        except Exception as e:
            raise ProtocolError(f"the session store failed ({type(e).__name__}); try again") from None
        if state is None:
            return None

        def catch_up_behind():
            data = json.loads(state)           # the store holds what a server of this deployment wrote
            return data, catch_up(self.gen, behind(data, resume))
        try:
            return await asyncio.get_running_loop().run_in_executor(None, catch_up_behind)
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise ProtocolError(f"the session could not be taken over ({e})") from None

    def _take_over(self, data: dict, caught: dict[int, bytes]) -> Session:
        """On the tick thread: a claimed session restored here (its characters behind their client from `caught`)."""
        if data["id"] in self.sessions:     # two clients of one session at once: the first has it
            raise ProtocolError("that session is connected elsewhere")
        try:
            session = restore_session(self.crowd, data, caught)
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise ProtocolError(f"the session could not be taken over ({e})") from None
        self.sessions[session.id] = session
        self.changed.add(session)          # written back at once: this server has it now
        return session

    def save(self, path: Path) -> None:
        """Every session and character to `path`, atomically (a temporary file renamed over it)."""
        data = {"format": STATE_FORMAT, "sessions": [session_state(s) for s in self.sessions.values()]}
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
                session = restore_session(self.crowd, s)
                self.sessions[session.id] = session
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise ValueError(f"{path}: not a motion server's saved state ({e})") from None
        path.rename(path.with_name(path.name + ".restored"))     # restored once: a later crash cannot replay it
