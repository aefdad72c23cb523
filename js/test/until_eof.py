"""Run a command until this script's stdin closes, then stop it: a server a test starts dies with the test.

    python js/test/until_eof.py CMD [ARGS...]      (js/test/serve.test.mjs starts `mogo serve` so)

A test that ends, fails, times out or is killed (even with SIGKILL, which no handler of its own sees) closes the
pipe to our stdin; we then send CMD SIGTERM (it exits cleanly, as `mogo serve` does on SIGTERM) and SIGKILL after
10 s. SIGTERM or SIGINT to us does the same. CMD inherits stdout and stderr; we exit with its status.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import threading


def main() -> int:
    proc = subprocess.Popen(sys.argv[1:], stdin=subprocess.DEVNULL)
    done = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.buffer.read(), done.set()), daemon=True).start()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    while not done.is_set() and proc.poll() is None:
        done.wait(0.2)
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return proc.wait()


if __name__ == "__main__":
    sys.exit(main())
