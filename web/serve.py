"""Serve the repository root over HTTP for the web page (web/index.html): static files only, no inference.

    python3 web/serve.py [--port 8000] [--host 127.0.0.1] [--mount /test=/tmp/bundles]

Prints the page's URL and serves until interrupted. The page fetches the bundle (manifest.json, *.onnx,
tokenizer.json), the JavaScript runtime (js/src) and its npm packages (web/node_modules: onnxruntime-web's .mjs and
.wasm, three) from here. Every response carries the cross-origin isolation headers (COOP/COEP), so a browser
may give onnxruntime-web several threads (`?threads=N`), and `no-cache`, so an edited file is never served stale.
`--mount PREFIX=DIR` serves DIR under the URL path PREFIX (the tests serve freshly built bundles that way).
Standard library only: no venv needed.
"""
from __future__ import annotations

import argparse
import functools
import http.server
import os
import posixpath
import sys
import urllib.parse
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TYPES = {".wasm": "application/wasm", ".mjs": "text/javascript", ".js": "text/javascript", ".json": "application/json",
         ".onnx": "application/octet-stream", ".bvh": "text/plain", ".map": "application/json"}


class Handler(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, **TYPES}
    mounts: dict[str, Path] = {}

    def translate_path(self, path: str) -> str:
        clean = posixpath.normpath(urllib.parse.unquote(urllib.parse.urlsplit(path).path))
        for prefix, folder in self.mounts.items():
            if clean == prefix or clean.startswith(prefix + "/"):
                rest = [p for p in clean[len(prefix):].split("/") if p and p not in (".", "..")]
                return str(folder.joinpath(*rest))
        return super().translate_path(path)

    def end_headers(self) -> None:
        self.send_header("Cross-Origin-Opener-Policy", "same-origin")
        self.send_header("Cross-Origin-Embedder-Policy", "require-corp")
        self.send_header("Cache-Control", "no-cache")
        super().end_headers()

    def log_message(self, format: str, *args) -> None:  # noqa: A002 (the base class's name)
        if os.environ.get("MOGO_WEB_LOG"):
            super().log_message(format, *args)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (default: this machine only)")
    ap.add_argument("--port", type=int, default=8000, help="port; 0 picks a free one")
    ap.add_argument("--mount", action="append", default=[], metavar="PREFIX=DIR",
                    help="also serve DIR under the URL path PREFIX (repeatable)")
    ap.add_argument("--page", default="web/", help="the path printed after the server's address")
    args = ap.parse_args(argv)
    mounts = {}
    for m in args.mount:
        prefix, sep, folder = m.partition("=")
        if not sep or not prefix.startswith("/") or not Path(folder).is_dir():
            ap.error(f"--mount takes /PREFIX=DIR with an existing DIR, got {m!r}")
        mounts[posixpath.normpath(prefix)] = Path(folder).resolve()
    Handler.mounts = mounts
    handler = functools.partial(Handler, directory=str(ROOT))
    try:
        server = http.server.ThreadingHTTPServer((args.host, args.port), handler)
    except OSError as e:
        print(f"serve.py: error: cannot listen on {args.host}:{args.port} ({e.strerror}); "
              f"pick another port, e.g. `make web PORT=8001`", file=sys.stderr)
        return 2
    host, port = server.server_address[:2]
    print(f"mogo web page: http://{host}:{port}/{args.page}", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
