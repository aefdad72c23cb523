"""What a motion server's clients must get, for js/test/serve.test.mjs (run against a real `mogo serve`).

    python js/test/make_serve_reference.py --out REF --bundle TOY_PORTABLE   (run.sh does this)

Writes REF/serve.json: the bundle and variant the test serves, and for each prompt and seed the first TOKENS tokens
of a character generated in a crowd of its own (a server's character gives them whoever shares its crowd:
tests/runtime/test_serve.py, reference_tokens), and the joints Python's decode-only client (wire/client.py) makes
of the first prompt's stream of FRAMES_TOKENS tokens: what the JS client's frames must be.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from mogo_runtime import MotionGenerator
from mogo_runtime.crowd import Crowd
from mogo_runtime.wire import format as wire
from mogo_runtime.wire.client import MotionClient

PROMPTS = [("a person walks forward", 1), ("a person waves with the right hand", 2)]
TOKENS = 50           # the test reads 40 of each character, across two reconnections
FRAMES_TOKENS = 20    # the decoded stream's tokens (4 s on the toy)
VARIANT = "compact"   # `mogo serve`'s default


def reference_tokens(gen, prompt: str, seed: int, n: int) -> np.ndarray:
    """A character's first n tokens in a crowd of its own, (n, levels)."""
    crowd = Crowd(gen)
    c = crowd.add(prompt, seed=seed)
    out = []
    for _ in range(n):
        crowd.tick()
        out.append(c.context.last.copy())
    return np.stack(out)


def decoded(bundle: Path, prompt: str, tokens: np.ndarray) -> np.ndarray:
    """The joints Python's decode-only client gives for a stream of `tokens` (one record a tick, as a server's)."""
    client = MotionClient(bundle, variant=VARIANT)
    records = [wire.hello_for(client.bundle.manifest, VARIANT), wire.Event(0, 0, wire.START, prompt)]
    records += [wire.Tokens(0, t, tokens[t:t + 1]) for t in range(len(tokens))]
    return client.apply(records)[0].joints


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--bundle", type=Path, required=True, help="a toy bundle with the compact variant")
    args = ap.parse_args(argv)
    gen = MotionGenerator(args.bundle, variant=VARIANT)
    prompts = [{"prompt": p, "seed": s, "tokens": reference_tokens(gen, p, s, TOKENS).tolist()} for p, s in PROMPTS]
    joints = decoded(args.bundle, PROMPTS[0][0], np.array(prompts[0]["tokens"][:FRAMES_TOKENS]))
    ref = {"bundle": str(args.bundle.resolve()), "variant": VARIANT, "prompts": prompts,
           "joints": {"tokens": FRAMES_TOKENS, "frames": len(joints), "data": joints.astype(np.float32).ravel().tolist()}}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "serve.json").write_text(json.dumps(ref))
    print(f"wrote {args.out / 'serve.json'} ({len(PROMPTS)} prompts x {TOKENS} tokens, {len(joints)} frames decoded)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
