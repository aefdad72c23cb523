"""Prompts of several actions: does each action play, in order?

    mogo-eval actions --bundle bundles/base --data data/procedural --checkpoints checkpoints/base [--prompts 100]

Each prompt joins two or three held-out single-action captions of different families ("a man waves with his left
hand, then squats down twice and then sits down"), as a user would type them. The runtime splits it (plan.py) and
plays the actions one after another; `Motion.actions` says where each starts. Each action's span is classified by
the project's action classifier (quality.py), without its first half second, where the previous action fades out
through the causal decoder. A prompt counts when every action is recognised as its family, in order.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mogo_export.data.dataset import MotionDataset
from mogo_export.data.procedural.families import LAST_ONLY
from mogo_runtime.plan import plan_actions

from .quality import classify, held_out_cases, load_classifier

# What a game developer types, and the family it asks for: the MOGO paper's qualitative prompts (its figures 6-9) and
# the other prompts issue 27 tried on the 21-family `base` (each then landed on one of those 21)
NAMED_PROMPTS = (
    ("a person does a backflip", "backflip"),
    ("holds injured leg and collapses to ground", "collapse_holding_leg"),
    ("does a swimming motion while standing", "swim_strokes"),
    ("dances", "dance"),
    ("crouches and sneaks forward", "sneak"),
    ("throws a ball", "throw_overhand"),
    ("picks something up from the floor", "pick_up"),
    ("falls down and gets back up", "fall_and_get_up"),
    ("climbs up a ladder", "climb_ladder"),
    ("does jumping jacks", "jumping_jacks"),
    ("pushes a heavy box", "push"),
)
TEMPLATES = {2: ("{a} and then {b}", "{a}, then {b}", "{a} and after that {b}"),
             3: ("{a}, then {b} and then {c}", "{a}, {b}, and then {c}", "{a}, then {b}, and finally {c}")}
SETTLE_S = 0.5          # each action is judged without its first half second
MIN_JUDGED_S = 1.0      # ... and at least this much of it


def _phrase(caption: str) -> str:
    """'a man squats down twice.' -> 'squats down twice' (the verb phrase the templates join)."""
    words = caption.rstrip(". ").split()
    return " ".join(words[2:] if words[0] in ("a", "the", "this") else words[1:])


def compound_prompts(data: Path, families: list[str], count: int, seed: int) -> list[tuple[str, list[str]]]:
    """`count` prompts, half of two actions and half of three, from held-out captions: (prompt, families in order).
    No family twice in a prompt; a family that ends seated or lying (LAST_ONLY) only last."""
    cases = held_out_cases(data, families)
    by_family: dict[str, list[str]] = {}
    for caption, family in cases:   # not a caption the runtime reads as two ("walks quickly and then at a normal pace")
        if len(plan_actions(caption)) == 1:
            by_family.setdefault(family, []).append(caption)
    out: list[tuple[str, list[str]]] = []
    names = sorted(by_family)
    rng = np.random.default_rng(seed)
    for _ in range(100 * count):
        if len(out) == count:
            break
        n = 2 if len(out) < count // 2 else 3
        first = [f for f in names if f not in LAST_ONLY]
        chosen = list(rng.choice(first, n - 1, replace=False))
        chosen.append(str(rng.choice([f for f in names if f not in chosen])))
        caps = [by_family[f][int(rng.integers(len(by_family[f])))] for f in chosen]
        tpl = TEMPLATES[n][int(rng.integers(len(TEMPLATES[n])))]
        subject = " ".join(caps[0].split()[:2]) if caps[0].split()[0] in ("a", "the", "this") else caps[0].split()[0]
        text = f"{subject} " + tpl.format(**dict(zip("abc", (_phrase(c) for c in caps))))
        if len(plan_actions(text)) == n:   # not when a caption's own comma makes the runtime read one more action
            out.append((text, [str(f) for f in chosen]))
    if len(out) < count:
        raise ValueError(f"{data}: only {len(out)} of {count} compound prompts could be made from its held-out captions")
    return out


def actions_report(bundle: Path, data: Path, classifier: Path, variant: str = "int8", threads: int = 1,
                   count: int = 100, seed: int = 0, progress: bool = True) -> dict:
    from mogo_runtime import MotionGenerator

    model, families = load_classifier(classifier)
    ds = MotionDataset.load(data, "test")
    gen = MotionGenerator(bundle, variant=variant, threads=threads)
    prompts = compound_prompts(data, families, count, seed)
    settle, least = round(SETTLE_S * gen.dims.fps), round(MIN_JUDGED_S * gen.dims.fps)
    rows, start = [], time.perf_counter()
    for i, (text, want) in enumerate(tqdm(prompts, desc="compound prompts", unit="prompt", disable=not progress)):
        motion = gen.generate(text, seed=seed + i)
        starts = [f for _, f in motion.actions or []] + [motion.num_frames]
        spans = [motion.features[a + (settle if b - a - settle >= least else 0):b] for a, b in zip(starts, starts[1:])]
        got = classify(model, families, [ds.normalize(s) for s in spans])[0] if spans else []
        rows.append({"prompt": text, "want": want, "got": got, "seconds": motion.seconds,
                     "split": len(spans) == len(want)})
    took = time.perf_counter() - start
    ok = [r["got"] == r["want"] for r in rows]
    by_n = {n: float(np.mean([o for o, r in zip(ok, rows) if len(r["want"]) == n])) for n in (2, 3)}
    position = [float(np.mean([r["got"][k] == r["want"][k] for r in rows if len(r["got"]) > k])) for k in range(3)]
    return {"bundle": str(bundle), "variant": variant, "prompts": len(rows), "all_in_order": float(np.mean(ok)),
            "all_in_order_by_actions": by_n, "accuracy_by_position": position,
            "split_as_named": float(np.mean([r["split"] for r in rows])),
            "seconds_per_prompt": took / max(1, len(rows)), "rows": rows}


def named_prompts_report(bundle: Path, data: Path, classifier: Path, variant: str = "int8", threads: int = 1,
                         seeds: int = 3) -> dict:
    """NAMED_PROMPTS, aligned (align=True) as a new user would run them, `seeds` motions each, classified."""
    from mogo_runtime import MotionGenerator

    model, families = load_classifier(classifier)
    ds = MotionDataset.load(data, "test")
    gen = MotionGenerator(bundle, variant=variant, threads=threads)
    rows = []
    for text, want in NAMED_PROMPTS:
        motions = [gen.generate(text, seed=s, align=True) for s in range(seeds)]
        got = classify(model, families, [ds.normalize(m.features) for m in motions])[0]
        rows.append({"prompt": text, "want": want, "known": want in families, "got": got,
                     "aligned": motions[0].aligned_text})
    return {"prompts": rows, "seeds": seeds,
            "hits": float(np.mean([g == r["want"] for r in rows for g in r["got"]]))}


def print_report(report: dict) -> None:
    print(f"{report['prompts']} compound prompts on {report['bundle']} ({report['variant']}):")
    print(f"  every action recognised, in order: {report['all_in_order']:.3f} "
          f"(2 actions {report['all_in_order_by_actions'][2]:.3f}, 3 actions {report['all_in_order_by_actions'][3]:.3f})")
    print("  per position: " + ", ".join(f"{a:.3f}" for a in report["accuracy_by_position"]))
    print(f"  split into the actions named: {report['split_as_named']:.3f}; "
          f"{report['seconds_per_prompt']:.2f} s per prompt")
    for r in [r for r in report["rows"] if r["got"] != r["want"]][:8]:
        print(f"  missed: {r['prompt']!r}: wanted {r['want']}, got {r['got']}")
    named = report.get("named")
    if named:
        print(f"what a new user types (align=True, {named['seeds']} seeds each): {named['hits']:.3f} judged as asked")
        for r in named["prompts"]:
            note = "" if r["known"] else "  (not a family of this model)"
            print(f"  {r['prompt']!r} -> {', '.join(r['got'])} (asked: {r['want']}){note}; aligned: {r['aligned']!r}")
