"""Golden tokens (llama2.c's test_all idea): fixed prompts, seeds and settings on the toy bundle -> the tokens every
runtime must give. Written by the Python runtime; checked by tests/runtime/test_golden.py (Python),
js/test/golden.test.mjs (Node) and the browser test (web/). Regenerate only when the contract changes on purpose:

    .venv/bin/python tests/golden/make_golden.py        # rewrites tests/golden/toy.json, prints what changed

The toy bundle (tests/runtime/toy_bundle.py) is built from a seeded numpy generator, so every machine builds the
same graphs; the file keeps their sha256, so a failing check says whether the bundle or the loop changed.
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
GOLDEN = HERE / "toy.json"

PROMPTS = ["a person walks forward", "a person jumps twice", "a person walks in a circle"]
SEEDS = [0, 1, 2 ** 63 - 1]
SAMPLINGS = {
    "greedy": {"temperature": 0.0},
    "top_p": {"temperature": 1.0, "top_p": 0.8},
    "guided": {"temperature": 0.9, "top_p": 0.8, "guidance": 2.0},
    "top_k": {"temperature": 1.2, "top_k": 5},
}
TIMELINE = [[PROMPTS[0], 0.0], [PROMPTS[1], 1.0], [PROMPTS[2], 2.2]]


def cases(variants: list[str]) -> list[dict]:
    """Every case: single clips the model ends, fixed lengths (endless loop), a batch, a timeline. Seeds are
    strings: 2**63 - 1 does not survive a JSON reader that parses numbers as doubles (JavaScript)."""
    out = []
    for variant in variants:
        for name, sampling in SAMPLINGS.items():
            for seed in SEEDS:
                for prompt in PROMPTS:
                    out.append({"variant": variant, "sampling": sampling, "seed": str(seed), "text": prompt})
                out.append({"variant": variant, "sampling": sampling, "seed": str(seed), "text": PROMPTS[0],
                            "seconds": 6.0})
            out.append({"variant": variant, "sampling": sampling, "seed": "7", "text": PROMPTS})
            out.append({"variant": variant, "sampling": sampling, "seed": "3", "text": TIMELINE, "seconds": 4.0})
    return out


def run_case(generators: dict, case: dict) -> list[list[list[int]]]:
    """-> one token list (T, L) per motion of the case."""
    from mogo_runtime.bundle.sampling import SamplingConfig

    text = case["text"]
    if isinstance(text, list) and isinstance(text[0], list):
        text = [tuple(item) for item in text]
    motions = generators[case["variant"]].generate(text, seconds=case.get("seconds"), seed=int(case["seed"]),
                                                   sampling=SamplingConfig(**case["sampling"]))
    motions = motions if isinstance(motions, list) else [motions]
    return [m.tokens.tolist() for m in motions]


def build_toy(out: Path) -> Path:
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from toy_bundle import build_toy_bundle

    mean = np.load(ROOT.parent / "shared" / "fixtures" / "humanml3d" / "Mean.npy")
    return build_toy_bundle(out, mean)


def bundle_hashes(bundle: Path, variants=("fp32", "int8")) -> dict:
    """sha256 of the files the golden cases run: the graphs of `variants` and the tokenizer (a variant added to
    the bundle later leaves the golden tokens valid)."""
    m = json.loads((bundle / "manifest.json").read_text())
    used = {g["file"] for v in variants for g in m["variants"][v].values()} | {m["text_encoder"]["tokenizer"]}
    return {name: f["sha256"] for name, f in m["files"].items() if name in used}


def main() -> int:
    from mogo_runtime import MotionGenerator

    with tempfile.TemporaryDirectory() as tmp:
        bundle = build_toy(Path(tmp) / "toy")
        generators = {v: MotionGenerator(bundle, variant=v) for v in ("fp32", "int8")}
        all_cases = cases(list(generators))
        for case in all_cases:
            case["tokens"] = run_case(generators, case)
        golden = {"bundle": "tests/runtime/toy_bundle.py: build_toy_bundle(out, Mean.npy of the HumanML3D fixture)",
                  "files": bundle_hashes(bundle), "cases": all_cases}
    old = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else None
    GOLDEN.write_text(json.dumps(golden, separators=(",", ":")) + "\n")
    tokens = sum(len(t) for c in all_cases for t in c["tokens"])
    changed = "new" if old is None else sum(a != b for a, b in zip(old["cases"], all_cases)) + abs(
        len(old["cases"]) - len(all_cases))
    print(f"wrote {GOLDEN}: {len(all_cases)} cases, {tokens} time steps; cases changed: {changed}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
