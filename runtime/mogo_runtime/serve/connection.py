"""The server's side of a WebSocket (websockets): the connection class it accepts with, and the one error a client
gets before it is closed (protocol.py says when)."""
from __future__ import annotations

import json

# How long a client the server closed has to answer the close before its connection is dropped (websockets' default
# is 10 s).
CLOSE_SECONDS = 2.0


def connection_class():
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


def error_message(message: str, fatal: bool = False, about: str | None = None) -> str:
    """`about`: the op of the message refused (a client waiting for one reply tells the others apart)."""
    return json.dumps({"op": "error", "fatal": fatal, "message": message, "about": about})


async def close_with_error(ws, message: str) -> None:
    try:
        await ws.send(error_message(message, fatal=True))
        await ws.close(1008, message[:120])
    except Exception:        # the connection is already gone: nothing to tell it
        pass
