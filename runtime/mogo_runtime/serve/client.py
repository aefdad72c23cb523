"""A motion server's client (protocol.py), for a game or a test: add characters, send prompts and control
requests, and receive their records; with a bundle, their frames too (decoded here, wire/client.py).

    async with await ServerClient.connect("ws://127.0.0.1:8765", token, bundle="bundles/base", variant="compact") as c:
        walker = await c.add("a person walks forward", seed=1)
        await c.request(walker, goal=[4.0, 2.0])
        while True:
            ident, frames = await c.next()               # (n, J, 3) joints as they are decoded

`next_seq` holds the next token expected of each character: `reconnect()` hands it to the server, which sends what
was missed, so a dropped connection (or a server restarted on its saved state) loses and repeats nothing. Requests
(`request`, `joints`) are numbered and kept in `unapplied` until the server says it carried them out; `reconnect()`
sends again those its welcome does not count, so one its server got in the tick it died in is not lost. A request
while the connection is down raises ConnectionError (the caller decides what still matters once it reconnects). A client
that joins a session afresh (`connect(..., session=S)`: a game restarted, a page reloaded) names no character; the
server sends each as a START and a SYNC of where it is now, and the frames go on from there.
"""
from __future__ import annotations

import asyncio
import json

from ..wire import format as wire
from ..wire.client import MotionClient


class ServerError(RuntimeError):
    """The server refused a request (`fatal`: and closed the connection)."""

    def __init__(self, message: str, fatal: bool):
        super().__init__(message)
        self.fatal = fatal


class ServerClient:
    def __init__(self, url: str, token: str, decoder: MotionClient | None = None, origin: str | None = None):
        self.url, self.token, self.decoder, self.origin = url, token, decoder, origin
        self.session: str | None = None
        self.welcome: dict = {}                  # the server's last welcome (its "server" id: which replica)
        self.next_seq: dict[int, int] = {}
        self.records: asyncio.Queue = asyncio.Queue()      # (ident, Frames) with a decoder, else records
        self.errors: list[ServerError] = []
        self._replies: asyncio.Queue = asyncio.Queue()
        self._ws = self._reader = None
        self.levels: int | None = None
        self.unapplied: dict[int, str] = {}      # request number -> the message, until the server applied it
        self.numbered = 0                        # the last request number used
        self._connecting = False                 # a reconnect() runs: a request made now waits for it

    @classmethod
    async def connect(cls, url: str, token: str, bundle=None, variant: str = "fp32", origin: str | None = None,
                      session: str | None = None):
        """A new client; with `session`, of a session another client (or this program before it restarted) had."""
        client = cls(url, token, MotionClient(bundle, variant) if bundle is not None else None, origin)
        client.session = session
        await client.reconnect()
        return client

    async def reconnect(self) -> dict:
        """Connect (again): a new session the first time, then the same one, from the tokens expected next."""
        if self._ws is not None:
            await self.close()
        self._connecting = True
        try:
            return await self._handshake()
        finally:
            self._connecting = False

    async def _handshake(self) -> dict:
        from websockets.asyncio.client import connect

        ws = await connect(self.url, origin=self.origin, compression=None, max_size=16 << 20)
        hello = {"op": "hello", "token": self.token}
        if self.session is not None:
            hello.update(session=self.session, resume={str(k): v for k, v in self.next_seq.items()})
        await ws.send(json.dumps(hello))
        welcome = json.loads(await ws.recv())
        if welcome.get("op") != "welcome":
            await ws.close()
            raise ServerError(welcome.get("message", str(welcome)), bool(welcome.get("fatal")))
        self.session, self.welcome = welcome["session"], welcome
        self._applied(welcome["applied"])
        self.numbered = max(self.numbered, welcome["applied"])     # a session another client numbered before
        # the requests not applied, in order; one made meanwhile waits its turn here (the server skips a number
        # below one it has applied, so none may overtake another)
        sent = welcome["applied"]
        while (later := [k for k in self.unapplied if k > sent]):
            sent = min(later)
            await ws.send(self.unapplied[sent])
        self._ws = ws
        self._reader = asyncio.create_task(self._read())
        return welcome

    def _applied(self, n: int) -> None:
        for k in [k for k in self.unapplied if k <= n]:
            del self.unapplied[k]

    async def _read(self) -> None:
        try:
            async for message in self._ws:
                if isinstance(message, str):
                    reply = json.loads(message)
                    if reply.get("op") == "applied":
                        self._applied(reply["n"])
                    elif reply.get("op") == "error":
                        error = ServerError(reply["message"], reply["fatal"])
                        self.errors.append(error)
                        if reply["fatal"] or reply.get("about") in ("add", "remove"):    # what a caller waits for
                            await self._replies.put(error)
                    else:
                        await self._replies.put(reply)
                    continue
                records = wire.read_message(message, self.levels)
                for r in records:
                    if isinstance(r, wire.Hello):
                        self.levels = r.levels
                    elif isinstance(r, wire.Tokens):
                        self.next_seq[r.character] = r.seq + len(r.codes)
                    elif isinstance(r, wire.Sync):        # the server moved the character on to where it is now
                        self.next_seq[r.character] = r.seq
                    elif isinstance(r, wire.Event) and r.event == wire.START:
                        self.next_seq.setdefault(r.character, r.seq)
                if self.decoder is None:
                    for r in records:
                        await self.records.put(r)
                else:
                    for ident, frames in self.decoder.apply(records).items():
                        await self.records.put((ident, frames))
            closed = ConnectionError("the server closed the connection")     # a clean close ends the loop
        except Exception as e:       # the connection closed, or a stream the decoder refuses: the caller sees it
            closed = e
        await self._replies.put(closed)
        await self.records.put(closed)

    async def _reply(self, op: str) -> dict:
        reply = await self._replies.get()
        if isinstance(reply, BaseException):
            raise reply
        if reply.get("op") != op:
            raise ServerError(f"expected {op}, got {reply}", False)
        return reply

    async def add(self, prompt: str, seed: int = 0, seconds: float | None = None) -> int:
        """-> the new character's id."""
        await self._ws.send(json.dumps({"op": "add", "prompt": prompt, "seed": seed, "seconds": seconds}))
        return (await self._reply("added"))["id"]

    async def request(self, ident: int, **fields) -> None:
        """A prompt and/or a control request: prompt=, goal=, path=, speed=, velocity=, facing=, root=, release="""
        await self._numbered({"op": "request", "id": ident, **fields})

    async def joints(self, ident: int, on: bool = True) -> None:
        await self._numbered({"op": "joints", "id": ident, "on": on})

    async def _numbered(self, msg: dict) -> None:
        """Send `msg` with the next request number, kept until applied (during a reconnect(), sent by it)."""
        from websockets.exceptions import ConnectionClosed

        connected = self._ws is not None and self._reader is not None and not self._reader.done()
        if not connected and not self._connecting:
            raise ConnectionError(f"not connected to {self.url}: reconnect() first")
        self.numbered += 1
        message = self.unapplied[self.numbered] = json.dumps({**msg, "n": self.numbered})
        if connected:
            try:
                await self._ws.send(message)
            except ConnectionClosed:     # it went as this was sent: kept, the next reconnect() sends it
                pass

    async def remove(self, ident: int) -> None:
        await self._ws.send(json.dumps({"op": "remove", "id": ident}))
        await self._reply("removed")

    async def next(self):
        """The next (ident, Frames) with a decoder, else the next record."""
        item = await self.records.get()
        if isinstance(item, BaseException):
            raise item
        return item

    async def close(self) -> None:
        if self._reader is not None:
            self._reader.cancel()
        if self._ws is not None:
            await self._ws.close()
        self._ws = self._reader = None

    async def __aenter__(self):
        return self

    async def __aexit__(self, *exc):
        await self.close()
