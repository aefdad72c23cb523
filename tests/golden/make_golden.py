"""Golden tokens (llama2.c's test_all idea): fixed prompts, seeds and settings on the toy bundle -> the tokens every
runtime must give. Written by the Python runtime; checked by tests/runtime/test_golden.py (Python),
js/test/golden.test.mjs (Node) and the browser test (web/). Regenerate only when the contract changes on purpose:

    .venv/bin/python tests/golden/make_golden.py        # rewrites tests/golden/toy*.json, prints what changed

The toy bundle (tests/runtime/toy_bundle.py) is built from a seeded numpy generator, so every machine builds the
same graphs; the file keeps their sha256, so a failing check says whether the bundle or the loop changed.

The prompts of several actions (plan.py: "walks forward and then jumps twice", "... for 2 seconds, then ...") come
last: generated without and with seconds, in a batch with prompts of one action, and streamed, with prompt switches
(set_prompt) to prompts of one and of several actions. Where a prompt was split, a case also holds the aligned texts
(the actions joined by " | "); a stream case, the token each switch landed at.

tests/golden/toy_control.json holds controlled streams on the toy bundle with control (build_toy_bundle(...,
portable=True, control=True)): a scripted list of requests (walk_to, follow_path, steer with and without facing,
set_root every token for a while, release), each made before the first frame of its token is read, and for each
case the tokens, the control vector each was picked with (float32), the token each request landed at and whether the
character had arrived after each token.
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
GOLDEN_CONTROL = HERE / "toy_control.json"

PROMPTS = ["a person walks forward", "a person jumps twice", "a person walks in a circle"]
SEEDS = [0, 1, 2 ** 63 - 1]
SAMPLINGS = {
    "greedy": {"temperature": 0.0},
    "top_p": {"temperature": 1.0, "top_p": 0.8},
    "guided": {"temperature": 0.9, "top_p": 0.8, "guidance": 2.0},
    "top_k": {"temperature": 1.2, "top_k": 5},
}
TIMELINE = [[PROMPTS[0], 0.0], [PROMPTS[1], 1.0], [PROMPTS[2], 2.2]]
# prompts of several actions (runtime/mogo_runtime/plan.py), one with a stated duration
PLANNED = ["a person walks forward and then jumps twice",
           "a person walks forward for 2 seconds, then jumps twice and then walks in a circle",
           "a person walks in a circle, then he jumps twice"]   # the toy's circle runs on: it gives way at max_tokens
PLANNED_BATCH = [PROMPTS[0], PLANNED[0], PROMPTS[2], "a person waves for 1.5 s"]
# a stream of 6 s: its prompt, then [token, prompt] switches made before the first frame of that token is read
PLANNED_STREAM = ["a person jumps twice for 1 second, then walks in a circle",
                  [[6, PLANNED[0]], [16, PROMPTS[1]], [22, PLANNED[1]]]]
PLANNED_SAMPLINGS = ("greedy", "top_p", "guided")
RESULTS = ("tokens", "aligned", "landed")     # what a case checks, those of them it holds


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


def planned_cases(variants: list[str]) -> list[dict]:
    """Prompts of several actions, after `cases` in the golden file (the torch reference, tests/export/
    test_golden_torch.py, has no plan and runs `cases` only): each action played until the model ends it or for its
    stated duration, then the next; generated, and streamed with prompt switches."""
    out = []
    for variant in variants:
        for name in PLANNED_SAMPLINGS:
            sampling = SAMPLINGS[name]
            for seed in (0, 1):
                for prompt in PLANNED:
                    out.append({"variant": variant, "sampling": sampling, "seed": str(seed), "text": prompt})
            out.append({"variant": variant, "sampling": sampling, "seed": "2", "text": PLANNED[1], "seconds": 6.0})
            out.append({"variant": variant, "sampling": sampling, "seed": "2", "text": PLANNED[0], "seconds": 3.0})
            out.append({"variant": variant, "sampling": sampling, "seed": "7", "text": PLANNED_BATCH})
            out.append({"variant": variant, "sampling": sampling, "seed": "5", "text": PLANNED_STREAM[0],
                        "seconds": 6.0, "stream": PLANNED_STREAM[1]})
    return out


CONTROL_VARIANTS = ("fp32", "int8", "portable", "compact")
CONTROL_SAMPLINGS = {k: SAMPLINGS[k] for k in ("greedy", "top_p", "guided")}
CONTROL_SECONDS = 6.0
# [token, request, arguments]: made before the first frame of that token is read. The first lands while frames
# still come 4 tokens at a time (the stream then makes them one token at a time); the path repeats a point.
REQUESTS = [[3, "walk_to", [[1.0, 1.5], 1.4]],
            [8, "follow_path", [[[0.0, 0.0], [1.0, 1.0], [1.0, 1.0], [3.0, 0.5]], 2.0]],
            [13, "steer", [[0.6, -1.0], [1.0, 0.0]]],
            *[[t, "set_root", [0.05 * t, 0.1 + 0.01 * t, 0.03 * t]] for t in range(16, 22)],
            [22, "release", []],
            [25, "walk_to", [[0.1, 0.3]]],                 # near: some arrive, at once or later
            [28, "steer", [[0.1, 0.0]]]]


def control_cases(variants) -> list[dict]:
    return [{"variant": variant, "sampling": sampling, "seed": str(seed), "text": PROMPTS[i % len(PROMPTS)],
             "seconds": CONTROL_SECONDS, "requests": REQUESTS}
            for variant in variants for name, sampling in CONTROL_SAMPLINGS.items()
            for i, seed in enumerate((0, 1, 5))]


def run_control_case(generators: dict, case: dict) -> dict:
    """A controlled stream, read frame by frame -> {tokens (T, L), controls (T, dim), landed, arrived}. The tokens
    and their controls are read from the stream's context as they are picked (its ring holds the last few)."""
    from mogo_runtime.bundle.sampling import SamplingConfig

    gen = generators[case["variant"]]
    stream = gen.stream(case["text"], seconds=case["seconds"], seed=int(case["seed"]),
                        sampling=SamplingConfig(**case["sampling"]))
    context, ds = stream.steering.context, gen.dims.downsample
    out = {"tokens": [], "controls": [], "landed": [], "arrived": []}
    frames = 0
    while True:
        if frames % ds == 0:
            for t, name, args in case["requests"]:
                if t == frames // ds:
                    getattr(stream, name)(*args)
                    out["landed"].append(stream.tokens)
        try:
            next(stream)
        except StopIteration:
            break
        frames += 1
        assert context.count - len(out["tokens"]) <= context.span, "tokens picked faster than the ring holds them"
        for t in range(len(out["tokens"]), context.count):
            out["tokens"].append(context.history[t % context.span].tolist())
            out["controls"].append(context.controls[t % context.span].tolist())
        if frames % ds == 0:
            out["arrived"].append(stream.arrived)
    return out


def run_case(generators: dict, case: dict) -> list[list[list[int]]]:
    """-> one token list (T, L) per motion of a case of `cases`."""
    return [m.tokens.tolist() for m in _motions(generators, case)]


def _motions(generators: dict, case: dict) -> list:
    from mogo_runtime.bundle.sampling import SamplingConfig

    text = case["text"]
    if isinstance(text, list) and isinstance(text[0], list):
        text = [tuple(item) for item in text]
    motions = generators[case["variant"]].generate(text, seconds=case.get("seconds"), seed=int(case["seed"]),
                                                   sampling=SamplingConfig(**case["sampling"]))
    return motions if isinstance(motions, list) else [motions]


def case_results(generators: dict, case: dict) -> dict:
    """Any case -> what the golden file holds of it (`results`): {"tokens": one token list (T, L) per motion} and,
    where a prompt was split into its actions, "aligned": each motion's aligned text; a stream case: the stream's
    tokens, its aligned text at the start and after each switch, and "landed": the token each switch landed at."""
    from mogo_runtime.bundle.sampling import SamplingConfig

    if "stream" in case:
        return run_stream_case(generators[case["variant"]], case, SamplingConfig(**case["sampling"]))
    motions = _motions(generators, case)
    out = {"tokens": [m.tokens.tolist() for m in motions]}
    if any(m.aligned_text is not None for m in motions):
        out["aligned"] = [m.aligned_text for m in motions]
    return out


def run_stream_case(gen, case: dict, sampling) -> dict:
    """A stream read frame by frame, each switch made before the first frame of its token is read; its tokens read
    from the stream's context as they are picked (its ring holds the last few)."""
    stream = gen.stream(case["text"], seconds=case.get("seconds"), seed=int(case["seed"]), sampling=sampling)
    context, ds = stream._loop.streams[0], gen.dims.downsample
    tokens, aligned, landed = [], [stream.aligned_text], []
    frames = 0
    while True:
        if frames % ds == 0:
            for t, text in case["stream"]:
                if t == frames // ds:
                    stream.set_prompt(text)
                    landed.append(stream.switches[-1][0])
                    aligned.append(stream.aligned_text)
        try:
            next(stream)
        except StopIteration:
            break
        frames += 1
        assert context.count - len(tokens) <= context.span, "tokens picked faster than the ring holds them"
        tokens.extend(context.history[t % context.span].tolist() for t in range(len(tokens), context.count))
    return {"tokens": [tokens], "aligned": aligned, "landed": landed}


def results(case: dict) -> dict:
    """What a golden case holds of what run_case gives."""
    return {k: case[k] for k in RESULTS if k in case}


def build_toy(out: Path, control: bool = False) -> Path:
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from toy_bundle import build_toy_bundle

    mean = np.load(ROOT.parent / "shared" / "fixtures" / "humanml3d" / "Mean.npy")
    return build_toy_bundle(out, mean, portable=control, control=control)


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
        all_cases = cases(list(generators)) + planned_cases(list(generators))
        for case in all_cases:
            case.update(case_results(generators, case))
        golden = {"bundle": "tests/runtime/toy_bundle.py: build_toy_bundle(out, Mean.npy of the HumanML3D fixture)",
                  "files": bundle_hashes(bundle), "cases": all_cases}
        bundle = build_toy(Path(tmp) / "toy-control", control=True)
        generators = {v: MotionGenerator(bundle, variant=v) for v in CONTROL_VARIANTS}
        controlled = control_cases(CONTROL_VARIANTS)
        for case in controlled:
            case.update(run_control_case(generators, case))
        golden_control = {"bundle": "tests/runtime/toy_bundle.py: build_toy_bundle(out, Mean.npy of the HumanML3D "
                                    "fixture, portable=True, control=True)",
                          "files": bundle_hashes(bundle, CONTROL_VARIANTS), "cases": controlled}
    for path, data in ((GOLDEN, golden), (GOLDEN_CONTROL, golden_control)):
        old = json.loads(path.read_text()) if path.exists() else None
        path.write_text(json.dumps(data, separators=(",", ":")) + "\n")
        tokens = sum(len(c["tokens"]) if "requests" in c else sum(map(len, c["tokens"])) for c in data["cases"])
        changed = "new" if old is None else sum(a != b for a, b in zip(old["cases"], data["cases"])) + abs(
            len(old["cases"]) - len(data["cases"]))
        print(f"wrote {path}: {len(data['cases'])} cases, {tokens} time steps; cases changed: {changed}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
