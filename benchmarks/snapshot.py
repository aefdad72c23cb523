"""Behaviour snapshot: the tokens and features a bundle gives, saved once and compared bit for bit later.

A refactor of the runtime must change nothing a user gets. Before it, save what the bundle produces; after it,
compare:

    python -m benchmarks.snapshot save    bundles/base /tmp/before.npz
    python -m benchmarks.snapshot compare bundles/base /tmp/before.npz     # exit 1 on any difference

It covers 20 prompts x 3 seeds, fp32 and int8, greedy and sampled (the bundle's sampling defaults), with and
without `align` (TCA): 480 motions, each generated alone. The script also runs against the API of the runtime
before issue 13 (keyword sampling arguments), so the "before" file can be written by the old tree.
"""
from __future__ import annotations

import argparse
import inspect
import sys
import time

import numpy as np

PROMPTS = (
    "a person walks forward",
    "a person waves with the right hand",
    "a person walks forward and then jumps",
    "someone squats down slowly",
    "a man kicks with his left leg",
    "a person jumps in place twice",
    "a person turns around to the left",
    "the person claps their hands",
    "a person bows",
    "a person runs forward quickly",
    "a person sits down on a chair",
    "a person punches with the right hand",
    "someone walks backwards",
    "a person sidesteps to the right",
    "a person raises both arms above the head",
    "a man walks in a circle",
    "yo make the dude do a lil hop",
    "can you have him wave 👋 with his left hand then bow",
    "A PERSON STANDS STILL.",
    "she jumps forward, and after that she turns right",
)
SEEDS = (0, 1, 7)


def _generate(gen, text: str, seed: int, greedy: bool, align: bool):
    params = inspect.signature(gen.generate).parameters
    if "sampling" in params:  # the API since issue 13: one SamplingConfig
        from mogo_runtime.sampling import SamplingConfig

        sampling = SamplingConfig(temperature=0.0) if greedy else None
        return gen.generate(text, seed=seed, sampling=sampling, align=align)
    return gen.generate(text, seed=seed, temperature=0.0 if greedy else None, align=align)


def snapshot(bundle: str) -> dict[str, np.ndarray]:
    from mogo_runtime import MotionGenerator

    out: dict[str, np.ndarray] = {}
    for variant in ("fp32", "int8"):
        gen = MotionGenerator(bundle, variant=variant, threads=1)
        for mode in ("greedy", "sampled"):
            for align in (False, True):
                for i, text in enumerate(PROMPTS):
                    for seed in SEEDS:
                        m = _generate(gen, text, seed, mode == "greedy", align)
                        key = f"{variant}/{mode}/{'align' if align else 'raw'}/p{i:02d}/s{seed}"
                        out[key + "/tokens"] = np.asarray(m.tokens)
                        out[key + "/features"] = np.asarray(m.features)
                        out[key + "/joints"] = np.asarray(m.joints)
    return out


def compare(before: dict[str, np.ndarray], after: dict[str, np.ndarray]) -> list[str]:
    problems = [f"{k}: missing after" for k in sorted(set(before) - set(after))]
    problems += [f"{k}: new after" for k in sorted(set(after) - set(before))]
    for k in sorted(set(before) & set(after)):
        a, b = before[k], after[k]
        if a.shape != b.shape or a.dtype != b.dtype:
            problems.append(f"{k}: {a.dtype}{a.shape} before, {b.dtype}{b.shape} after")
        elif a.tobytes() != b.tobytes():
            problems.append(f"{k}: values differ (max abs {np.abs(a.astype(np.float64) - b).max():.3g})")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["save", "compare"])
    ap.add_argument("bundle")
    ap.add_argument("file")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    now = snapshot(args.bundle)
    motions = len(now) // 3
    if args.mode == "save":
        np.savez(args.file, **now)
        print(f"saved {motions} motions ({len(now)} arrays) to {args.file} in {time.perf_counter() - t0:.0f} s")
        return 0
    with np.load(args.file) as f:
        before = {k: f[k] for k in f.files}
    problems = compare(before, now)
    for p in problems[:40]:
        print(p)
    print(f"{motions} motions compared in {time.perf_counter() - t0:.0f} s: "
          f"{'IDENTICAL' if not problems else f'{len(problems)} arrays differ'}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
