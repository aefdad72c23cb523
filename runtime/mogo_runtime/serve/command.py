"""`mogo serve BUNDLE --port 8765`: the motion server on the command line (server.py, docs/serve.md).

The bearer token comes from a file (--token-file) or $MOGO_SERVE_TOKEN, never from the command line, where any
user of the machine reads it in the process list.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

TOKEN_ENV = "MOGO_SERVE_TOKEN"
MAX_TOKEN_FILE = 4096


def add_parser(sub) -> None:
    p = sub.add_parser("serve", help="a WebSocket motion server: clients add characters, the server sends tokens",
                       description="Host a crowd for WebSocket clients (protocol: docs/serve.md). The token comes "
                                   f"from --token-file or ${TOKEN_ENV}.")
    p.add_argument("bundle", type=Path, help="bundle folder")
    p.add_argument("--variant", default="compact",
                   help="a batched variant: compact (default), portable or int8_fixed")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8765, help="port (default 8765)")
    p.add_argument("--token-file", type=Path, help=f"file holding the bearer token (else ${TOKEN_ENV})")
    p.add_argument("--origin", action="append", metavar="URL",
                   help="a browser origin allowed to connect, repeatable (default: clients that send no Origin)")
    p.add_argument("--state", type=Path, metavar="FILE",
                   help="save every character here on SIGTERM, and resume from it when it exists at start")
    p.add_argument("--characters-per-connection", type=int, default=16)
    p.add_argument("--characters", type=int, default=4096, help="characters in the whole server (default 4096)")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime threads (default 1)")
    p.add_argument("--status", type=float, default=60.0, metavar="SECONDS",
                   help="a status line on stderr every SECONDS (default 60; 0: none)")
    p.add_argument("--ray", action="store_true", help="serve as a Ray Serve deployment (serve/ray.py)")
    p.add_argument("--replicas", type=int, default=1,
                   help="with --ray: replicas (default 1); deploying again with another count scales")
    p.add_argument("--ray-address", help="with --ray: the Ray cluster (default: $RAY_ADDRESS, else a running one)")
    p.add_argument("--detach", action="store_true", help="with --ray: deploy and return, leaving it running")
    p.set_defaults(run=run)


def read_token(path: Path | None) -> str:
    if path is not None:
        try:
            with open(path, "rb") as f:
                data = f.read(MAX_TOKEN_FILE + 1)
        except OSError as e:
            raise ValueError(f"--token-file {path}: {e.strerror}") from None
        if len(data) > MAX_TOKEN_FILE:
            raise ValueError(f"--token-file {path}: over {MAX_TOKEN_FILE} bytes; a token file holds one token")
        try:
            token = data.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise ValueError(f"--token-file {path}: not UTF-8 text") from None
    else:
        token = os.environ.get(TOKEN_ENV, "")
    if len(token) < 16:
        raise ValueError(f"a bearer token of at least 16 characters is required: --token-file FILE or ${TOKEN_ENV}")
    return token


def run(args: argparse.Namespace) -> int:
    import asyncio

    from ..checks import as_int
    from ..generator import MotionGenerator
    from ..outputs.extras import require
    from .protocol import Limits
    from .server import MotionServer

    as_int("--port", args.port, "a port in [0, 65535] (0: any free one)", 0, 65535)
    as_int("--characters-per-connection", args.characters_per_connection, "an int >= 1", 1)
    as_int("--characters", args.characters, "an int >= 1", 1)
    as_int("--replicas", args.replicas, "an int >= 1", 1)
    if not args.status >= 0:
        raise ValueError(f"--status must be seconds >= 0, got {args.status}")
    require("ray" if args.ray else "serve")
    token = read_token(args.token_file)
    limits = Limits(characters_per_connection=args.characters_per_connection, characters=args.characters)
    if args.ray:
        from .ray import serve_on_ray

        return serve_on_ray(args, token, limits)
    gen = MotionGenerator(args.bundle, variant=args.variant, threads=args.threads)
    server = MotionServer(gen, token, limits, state_file=args.state, origins=args.origin, status_seconds=args.status)

    def ready(ws_server):
        ports = sorted({s.getsockname()[1] for s in ws_server.sockets})
        print(f"mogo serve: {args.bundle} ({args.variant}) on ws://{args.host}:{ports[0]}", file=sys.stderr,
              flush=True)
    asyncio.run(server.serve(args.host, args.port, ready))
    print(f"mogo serve: stopped{f'; state saved to {args.state}' if args.state else ''}", file=sys.stderr)
    return 0
