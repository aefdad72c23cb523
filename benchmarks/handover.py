"""What it costs to move a server's characters (docs/serve.md, "Nothing lost" and "Ray Serve"):

    python -m benchmarks.handover --bundle bundles/base [--variant compact] [--characters 16] [--ticks 300]

A session of N characters is played `ticks` ticks as a server plays it (each tick's records kept, up to the
server's `replay_tokens`), then timed, one thread:
- a SYNC record of one character (bytes): what a client that lost its decoder gets;
- a checkpoint of the session as a server writes it to its store (bytes and ms a character, best of 5);
- a takeover at its worst: its characters, saved CHECKPOINT_TICKS tokens behind their client, caught up in a crowd
  of their own (ms, best of 3;
  a server runs it beside its ticks), then restored into the server's crowd, whose next tick rebuilds their
  contexts (ms: what that tick costs more than a tick without them).
"""
from __future__ import annotations

import argparse
import json
import time

from mogo_runtime import MotionGenerator
from mogo_runtime.crowd import Crowd
from mogo_runtime.serve.protocol import Limits
from mogo_runtime.serve.sessions import CHECKPOINT_RECORDS, CHECKPOINT_TICKS, Hosted, Session, catch_up, session_state
from mogo_runtime.state import restore_character, save_character
from mogo_runtime.wire import format as wire
from mogo_runtime.wire.tap import CharacterTap, sync

PROMPTS = ["a person walks forward", "a person waves with the right hand", "a person jumps in place",
           "a person turns left"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--variant", default="compact")
    ap.add_argument("--characters", type=int, default=16)
    ap.add_argument("--ticks", type=int, default=300)
    args = ap.parse_args(argv)
    if args.ticks <= CHECKPOINT_TICKS:
        ap.error(f"--ticks must be more than the {CHECKPOINT_TICKS} ticks between checkpoints")

    gen = MotionGenerator(args.bundle, variant=args.variant, threads=1)
    crowd, session = Crowd(gen, max_characters=2 * args.characters), Session("benchmark")
    for i in range(args.characters):
        c = crowd.add(PROMPTS[i % len(PROMPTS)], seed=i)
        session.characters[i] = Hosted(c, CharacterTap(c, i))
    behind = {}
    for t in range(args.ticks):
        if t == args.ticks - CHECKPOINT_TICKS:
            behind = {i: (save_character(h.character), h.character.count + CHECKPOINT_TICKS)
                      for i, h in session.characters.items()}
        crowd.tick()
        for h in session.characters.values():
            key, records = h.tap.sent, h.tap.read()
            h.replay.append((key, b"".join(map(wire.encode, records))))
            while len(h.replay) > Limits().replay_tokens:
                h.replay.popleft()

    n = args.characters
    sync_bytes = len(wire.encode(sync(session.characters[0].character, 0)))
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        state = json.dumps(session_state(session, CHECKPOINT_RECORDS))
        best = min(best, time.perf_counter() - t0)
    takeover = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        caught = catch_up(gen, behind)
        takeover = min(takeover, time.perf_counter() - t0)
    crowd.tick()                                    # the server's crowd, and its tick without the newcomers
    t0 = time.perf_counter()
    crowd.tick()
    plain = time.perf_counter() - t0
    restored = [restore_character(crowd, state) for state in caught.values()]
    t0 = time.perf_counter()
    crowd.tick()
    rebuild = time.perf_counter() - t0 - plain
    assert all(c.count == behind[i][1] + 1 for i, c in zip(caught, restored))
    print(f"{args.bundle} ({args.variant}), {n} characters after {args.ticks} ticks:")
    print(f"  SYNC record: {sync_bytes / 1024:.1f} KB")
    print(f"  checkpoint: {len(state) / n / 1024:.1f} KB and {1e3 * best / n:.2f} ms a character "
          f"({len(state) / 1024:.0f} KB, {1e3 * best:.1f} ms the session)")
    print(f"  takeover, {CHECKPOINT_TICKS} tokens behind: {1e3 * takeover:.0f} ms ({1e3 * takeover / n:.1f} ms a "
          f"character) beside the ticks, then {1e3 * rebuild:.0f} ms more in the tick that rebuilds their contexts")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
