"""`mogo serve BUNDLE --ray --replicas N`: the motion server as a Ray Serve deployment.

Each replica is a whole `MotionServer` (its own crowd, its own tick loop) behind Ray Serve's HTTP proxy, which
routes each WebSocket connection to a replica and keeps it there for its life; the protocol is the same, byte for
byte (protocol.py). The replicas checkpoint their sessions to one SessionStore actor (serve/sessions.py): a client
whose replica was removed (or died) reconnects, lands on another, and that one takes its session over, its
characters going on with the tokens they would have had. Replicas are added or removed by deploying again with
another `--replicas` (Ray Serve changes the count without restarting the replicas that stay, so their connections
carry on).

    ray start --head                                # or any Ray cluster; RAY_ADDRESS says where
    mogo serve bundles/base --ray --replicas 2 --port 8000
"""
# no `from __future__ import annotations`: FastAPI reads the route's `websocket: WebSocket` annotation as a class
import asyncio
import signal
import sys
import threading

from fastapi import FastAPI, WebSocket
from ray import serve

from .protocol import Limits, ProtocolError
from .server import MotionServer
from .sessions import SessionStore, forget_for

APP = "mogo"
STORE, NAMESPACE = "mogo-sessions", "mogo"      # the session store actor, shared by the replicas
# Ray Serve's code version: deploying again with the same one and another replica count scales in place (the
# replicas that stay, and their connections, carry on); a version Ray does not know replaces every replica. A change
# to the server's code or protocol bumps it.
VERSION = "mogo-serve/2"


class StarletteConnection:
    """A Starlette WebSocket with the part of websockets' connection API that MotionServer.handler uses: recv, send,
    close and iteration over messages (ending when the client leaves). A message over the limit is refused here:
    Ray's proxy accepts up to 16 MB before the replica sees it."""

    def __init__(self, websocket, max_size: int):
        self.ws, self.max_size = websocket, max_size

    async def recv(self):
        msg = await self.ws.receive()
        if msg["type"] == "websocket.disconnect":
            raise ConnectionResetError("the client left")
        data = msg.get("text") if msg.get("text") is not None else msg.get("bytes")
        if data is not None and len(data) > self.max_size:
            raise ProtocolError(f"a message of {len(data)} bytes (at most {self.max_size})")
        return data

    async def send(self, data) -> None:
        if isinstance(data, str):
            await self.ws.send_text(data)
        else:
            await self.ws.send_bytes(data)

    async def close(self, code: int = 1000, reason: str = "") -> None:
        await self.ws.close(code, reason)

    def __aiter__(self):
        return self

    async def __anext__(self):
        try:
            return await self.recv()
        except ConnectionResetError:
            raise StopAsyncIteration from None


class ActorStore:
    """The deployment's SessionStore actor, as a server awaits a store."""

    def __init__(self, actor):
        self.actor = actor

    async def put(self, owner: str, states: dict[str, str], dropped: list[str]) -> list[str]:
        return await self.actor.put.remote(owner, states, dropped)

    async def claim(self, session: str, owner: str) -> str | None:
        return await self.actor.claim.remote(session, owner)


def session_store(forget_seconds: float):
    """The store actor: made by the first replica, found by the others (and by a redeployment). It takes no CPU
    of its own (a replica takes one): it only holds JSON."""
    import ray

    return ray.remote(SessionStore).options(name=STORE, namespace=NAMESPACE, get_if_exists=True,
                                            lifetime="detached", num_cpus=0).remote(forget_seconds)


app = FastAPI()


# A replica being removed closes its connections within 2 s (Ray's default waits 20 s for them to end).
@serve.deployment(name="MotionServer", ray_actor_options={"num_cpus": 1}, graceful_shutdown_timeout_s=2,
                  graceful_shutdown_wait_loop_s=1)
@serve.ingress(app)
class MotionReplica:
    def __init__(self, bundle: str, variant: str, token: str, limits: Limits, origins, threads: int):
        from ..generator import MotionGenerator

        gen = MotionGenerator(bundle, variant=variant, threads=threads)
        forget = forget_for(limits.linger_seconds, gen.dims.downsample / gen.dims.fps)
        self.server = MotionServer(gen, token, limits, origins=origins, store=ActorStore(session_store(forget)))
        self.origins, self.max_size = self.server.origins, limits.max_message_bytes
        self.stop, self.ticking = asyncio.Event(), None

    @app.websocket("/")
    async def connect(self, websocket: WebSocket) -> None:
        if websocket.headers.get("origin") not in self.origins:
            await websocket.close(1008)            # before accepting: the handshake is refused (HTTP 403)
            return
        if self.ticking is None:                   # the replica's own loop: tick there, from the first client on
            self.ticking = asyncio.create_task(self.server.run(self.stop))
        await websocket.accept()
        await self.server.handler(StarletteConnection(websocket, self.max_size))

    @app.get("/status")
    def status(self) -> str:
        return self.server.status()


def serve_on_ray(args, token: str, limits: Limits) -> int:
    """Deploy (or scale to `args.replicas`) and wait for SIGTERM or Ctrl-C; then shut the application down."""
    import ray

    ray.init(address="auto" if args.ray_address is None else args.ray_address, log_to_driver=False,
             ignore_reinit_error=True)
    # one proxy, on the head node: a proxy on every node of a cluster on one machine would take the port twice
    serve.start(proxy_location="HeadOnly", http_options={"host": args.host, "port": args.port})
    # every WebSocket is one of Ray's "ongoing requests", of which a replica takes 5 by default: the server's own
    # connection limit is the one that holds (a sixth client waited for a place; measured: 800 characters ran at 2.5%)
    replica = MotionReplica.options(num_replicas=args.replicas, max_ongoing_requests=limits.connections)
    # serve.run gives a deployment without a version a random one, and Ray replaces every replica of a new version;
    # Ray 2.60 removed the public `version` and keeps this field (client.py: `deployment._version or random`), which
    # tests/runtime/test_serve_ray.py holds to scaling in place
    replica._version = VERSION
    serve.run(replica.bind(str(args.bundle.resolve()), args.variant, token, limits, args.origin, args.threads),
              name=APP, route_prefix="/")
    print(f"mogo serve: {args.bundle} ({args.variant}) on Ray Serve, {args.replicas} replica(s), "
          f"ws://{args.host}:{args.port}", file=sys.stderr, flush=True)
    if args.detach:
        return 0
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    serve.delete(APP)
    try:
        ray.kill(ray.get_actor(STORE, namespace=NAMESPACE))
    except ValueError:          # no replica ever made it
        pass
    print("mogo serve: the Ray Serve application and its session store are deleted", file=sys.stderr)
    return 0
