"""The compact variant (int8-stored weights, float32 arithmetic; docs/bundle.md) against fp32, portable and int8 on
a bundle: what it weighs, how close it stays to fp32, how fast it runs, and whether Python, Node and Chromium give
the same tokens.

    .venv/bin/python -m benchmarks.compact --bundle bundles/base            # ~5 minutes on base, 2 cores
    .venv/bin/python -m benchmarks.compact --bundle bundles/base --no-js    # Python only

1. Size of each variant as a page or a phone downloads it: its graph files, the tokenizer and the TCA index.
2. Teacher-forced argmax agreement with fp32 (mogo-export verify's measure: fp32's greedy tokens fed to both, the
   argmax of every step and level compared) over PROMPTS and verify's prompts; the text embeddings' cosine to fp32.
3. Time per clip (MOTION_FRAMES frames, the bundle's sampling, 1 thread), variants alternated, best of --rounds.
4. Exactness: PROMPTS x --seeds seeds, greedy and the bundle's default sampling, plus a stream whose prompt changes
   three times, on the compact variant in the Python runtime; the same cases in Node (js/scripts/cases.mjs) and in
   headless Chromium (web/scripts/cases.mjs, which also times the web page loading compact, portable and int8).
Writes benchmarks/results/compact-<UTC time>.json and prints a Markdown summary.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from mogo_export.agreement import forced_logits, greedy_tokens, teacher_forced
from mogo_export.verify import PROMPTS as VERIFY_PROMPTS
from mogo_runtime import MotionGenerator
from mogo_runtime.bundle import Bundle
from mogo_runtime.bundle.manifest import COMPACT, PORTABLE
from mogo_runtime.engine import OrtBackend, open_backend

from .common import MOTION_FRAMES

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "golden"))
from make_golden import case_results  # noqa: E402  (the golden file's own case runner)

# what a game developer types: the actions base knows, in their words
PROMPTS = ["a person walks forward", "a person runs forward quickly", "a person jumps twice",
           "a person waves with the right hand", "a person kicks with the left leg", "a person sits down on the ground",
           "a person does a backflip", "a person dances", "a person throws a ball overhand", "a person crouches and sneaks forward",
           "a person turns around", "a person walks in a circle", "a person punches with both fists",
           "a person picks something up from the floor", "a person does jumping jacks", "a person falls down and gets back up",
           "a person climbs up a ladder", "a person walks forward and then jumps", "a person limps forward",
           "a person salutes"]
STREAM_SWITCHES = [[8, "a person jumps twice"], [20, "a person waves with the right hand"], [32, "a person runs forward quickly"]]
VARIANTS = ("fp32", "int8", PORTABLE, "int8_fixed", COMPACT)


def variant_bytes(bundle: Bundle, variant: str) -> int:
    m = bundle.manifest
    files = {e.file for e in m.variants[variant].values()} | {m.text_encoder.tokenizer}
    files |= {m.tca.file} if m.tca else set()
    return sum(m.files[f][0] for f in files)


def agreement(bundle: Bundle, prompts: list[str]) -> dict:
    fp32 = OrtBackend(bundle, "fp32", threads=2)
    tokens = greedy_tokens(fp32, prompts, list(range(len(prompts))), fp32.dims.max_tokens)
    reference = forced_logits(fp32, prompts, tokens)
    base_emb = fp32.encode_text(prompts)
    out = {"prompts": len(prompts), "steps": int(sum(len(t) for t in tokens))}
    for v in (x for x in VARIANTS[1:] if x in bundle.variants):
        backend = open_backend(bundle, v, threads=2)
        forced, _ = teacher_forced(reference, forced_logits(backend, prompts, tokens))
        emb = backend.encode_text(prompts)
        cos = (emb * base_emb).sum(1) / np.linalg.norm(emb, axis=1) / np.linalg.norm(base_emb, axis=1)
        out[v] = {"teacher_forced": float(forced), "text_cosine_min": float(cos.min())}
    return out


def speed(bundle_path: Path, variants: list[str], rounds: int) -> dict:
    gens = {v: MotionGenerator(bundle_path, variant=v, threads=1) for v in variants}
    seconds = MOTION_FRAMES / next(iter(gens.values())).dims.fps
    for g in gens.values():
        g.generate(PROMPTS[0], seed=0, seconds=2.0)                     # warm-up
    times = {v: [] for v in variants}
    for r in range(rounds):
        for v, g in gens.items():
            t0 = time.perf_counter()
            g.generate(PROMPTS[r % len(PROMPTS)], seed=r, seconds=seconds)
            times[v].append(time.perf_counter() - t0)
    return {v: {"best_s": min(t), "median_s": float(np.median(t)), "motion_s": seconds} for v, t in times.items()}


def exactness_cases(bundle_path: Path, seeds: int) -> list[dict]:
    gen = MotionGenerator(bundle_path, variant=COMPACT, threads=1)
    defaults = {k: v for k, v in gen.sampling_defaults.to_dict().items() if v is not None}
    samplings = {"greedy": {"temperature": 0.0}, "defaults": defaults}
    cases = [{"variant": COMPACT, "sampling": s, "seed": str(seed), "text": p}
             for s in samplings.values() for p in PROMPTS for seed in range(seeds)]
    if Bundle.load(bundle_path).manifest.streaming:
        cases.append({"variant": COMPACT, "sampling": defaults, "seed": "5", "text": PROMPTS[0], "seconds": 10.0,
                      "stream": STREAM_SWITCHES})
    for case in cases:
        case.update(case_results({COMPACT: gen}, case))
    return cases


def run_js(script: str, bundle: Path, cases_file: Path, *extra: str) -> dict:
    proc = subprocess.run(["node", str(ROOT / script), str(bundle), str(cases_file), *extra], capture_output=True,
                          text=True, cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"{script} failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", default="bundles/base", type=Path)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--no-js", action="store_true", help="skip Node and Chromium")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results", help="folder of the JSON result")
    opts = ap.parse_args(argv)
    bundle = Bundle.load(opts.bundle)
    if COMPACT not in bundle.variants:
        print(f"{opts.bundle} has no compact variant: re-export it (mogo-export export)", file=sys.stderr)
        return 2
    result = {"bundle": str(opts.bundle), "sizes_mb": {v: variant_bytes(bundle, v) / 1e6 for v in VARIANTS
                                                      if v in bundle.variants}}
    print("sizes (graphs + tokenizer + TCA index, MB):", {k: round(v, 1) for k, v in result["sizes_mb"].items()})
    result["agreement"] = agreement(bundle, PROMPTS + list(VERIFY_PROMPTS))
    print("agreement with fp32:", json.dumps(result["agreement"]))
    result["speed"] = speed(opts.bundle, [v for v in ("fp32", PORTABLE, COMPACT, "int8") if v in bundle.variants],
                            opts.rounds)
    print("speed (one clip):", json.dumps(result["speed"]))
    cases = exactness_cases(opts.bundle, opts.seeds)
    result["cases"] = {"count": len(cases), "steps": sum(len(t) for c in cases for t in c["tokens"])}
    print(f"Python: {len(cases)} cases on the compact variant, {result['cases']['steps']} token steps")
    if not opts.no_js:
        with tempfile.TemporaryDirectory() as tmp:
            cases_file = Path(tmp) / "cases.json"
            cases_file.write_text(json.dumps({"cases": cases}))
            result["node"] = run_js("js/scripts/cases.mjs", opts.bundle, cases_file)
            print("Node:", json.dumps(result["node"]))
            timed = ",".join(v for v in (COMPACT, PORTABLE, "int8") if v in bundle.variants)
            result["chromium"] = run_js("web/scripts/cases.mjs", opts.bundle, cases_file, timed)
            print("Chromium:", json.dumps(result["chromium"]))
    out = opts.out / f"compact-{datetime.now(timezone.utc):%Y%m%dT%H%M%SZ}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")
    exact = all(result.get(r, {}).get("identical") == len(cases) for r in ("node", "chromium")) or opts.no_js
    return 0 if exact else 1


if __name__ == "__main__":
    sys.exit(main())
