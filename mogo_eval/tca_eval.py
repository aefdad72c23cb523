"""Measure text condition alignment (TCA): action accuracy on hand-written paraphrases, with and without TCA.

    python -m mogo_eval.tca_eval --bundle bundles/base --data data/procedural --checkpoints checkpoints/base

For every paraphrase of mogo_eval/paraphrases.py (labelled with its action family) and every seed, a motion
is generated from the prompt as typed ("raw") and from what each variant of the offline aligner
(mogo_runtime.tca) conditions on:
  normalize       the normalised wording alone, no retrieval (an ablation: what retrieval adds)
  nearest         the nearest training caption per clause (what the runtime does)
  nearest-nolex   the same without the left/right, forward/backward re-ranking
(`blend`, a similarity-weighted mean of caption embeddings, measured equal to `nearest` and was removed from
the runtime: docs/tca.md.) The quality classifier (mogo_eval.quality, trained once on the dataset's training
split) judges each motion's family. Every method uses the same seeds, so differences are paired. Accuracy is
reported per paraphrase set (dev: the set the wording lexicon was tuned on; heldout: written after, never tuned
on) with a 95% interval (bootstrap over prompts). `--reference` adds in-distribution captions from the test split
as a ceiling.

Generation runs on the bundle through the runtime (`--variant fp32|int8`) or, with `--torch`, on the checkpoints
(mogo_eval.features); retrieval embeds prompts with the same text encoder. A bundle without a caption index gets
one built from --data's training captions (with a note).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from mogo_export.data.dataset import load_mean_std
from mogo_runtime.tca import CaptionIndex, OfflineAligner, sentence

from .paraphrases import SETS

METHODS = {"raw": "the prompt as typed", "normalize": "the normalised wording, no retrieval",
           "nearest": "the nearest training caption per clause (the runtime)",
           "nearest-nolex": "nearest without the direction-word re-ranking"}


def aligned_texts(method: str, texts: list[str], index: CaptionIndex, encode) -> list[str]:
    """What `method` conditions the model on, per prompt (always text: the runtime encodes it)."""
    if method == "raw":
        return list(texts)
    aligner = OfflineAligner(index=index, text_session=encode,
                             lexical_weight=0.0 if method == "nearest-nolex" else None)
    if method == "normalize":   # as the runtime words it, before retrieval; nothing recognised: as typed
        return [sentence(aligner.normalizer.normalize(t)) or t for t in texts]
    return [p.text for p in aligner.align_batch(texts)]


def _setup(args):
    """(features generator, prompt encoder, caption index, where the index came from, sampling)."""
    from mogo_runtime import Bundle
    from mogo_runtime.tca import load_bundle_index

    from .features import bundle_features, torch_features

    bundle = Bundle.load(args.bundle) if args.bundle else None
    index, source = (load_bundle_index(bundle)[0], None) if bundle is not None else (None, None)
    if index is not None:
        source = f"{args.bundle}/{bundle.manifest.tca.file}"
    if args.torch:
        from mogo_export.checkpoint import read_checkpoint
        from mogo_export.export.bundle import sampling_defaults
        from mogo_export.reference import TorchGenerator

        gen = TorchGenerator.from_checkpoints(args.checkpoints)
        meta = read_checkpoint(Path(args.checkpoints) / "transformer.pt", "transformer")["meta"]
        sampling = bundle.manifest.sampling_defaults if bundle is not None else sampling_defaults(meta)
        encode, encoder = gen.backend.encode_text, gen.backend.text_encoder.name
        make = lambda s: torch_features(gen, s)  # noqa: E731
    else:
        from mogo_runtime.text import TextEncoderSession

        te = bundle.manifest.text_encoder
        te_file = bundle.manifest.graph_file("text_encoder", args.variant).file
        session = TextEncoderSession(bundle.read_verified(te_file), bundle.read_verified(te.tokenizer),
                                     threads=args.threads)
        sampling, encode, encoder = bundle.manifest.sampling_defaults, session.encode, te.name
        make = lambda s: bundle_features(args.bundle, args.variant, s, args.threads)  # noqa: E731
    if args.temperature is not None:
        sampling = dataclasses.replace(sampling, temperature=args.temperature)
    if index is None:
        from mogo_export.export.caption_index import training_captions

        captions, labels = training_captions(args.data)
        print(f"note: {args.bundle or 'no bundle'}: no caption index; embedding the {len(captions)} training "
              f"captions of {args.data} with the generator's text encoder", file=sys.stderr)
        index = CaptionIndex(captions, encode(captions), labels, encoder)
        source = f"built from {args.data}"
    return make(sampling), encode, index, source, sampling


def _reference_cases(data: Path, families: list[str], per_family: int) -> list[tuple[str, str]]:
    from mogo_export.data.dataset import MotionDataset
    from .quality import single_family

    out, count = [], {}
    for it in MotionDataset.load(data, "test").items:
        fam = single_family(it.label)
        if fam in families and count.get(fam, 0) < per_family:
            out.append((it.captions[0], fam))
            count[fam] = count.get(fam, 0) + 1
    return out


def _interval(correct: np.ndarray, rng: np.random.Generator, n: int = 2000) -> tuple[float, float]:
    """95% bootstrap interval of the mean over prompts; correct is (prompts, seeds) of 0/1 (or paired differences)."""
    per_prompt = correct.mean(1)
    idx = rng.integers(len(per_prompt), size=(n, len(per_prompt)))
    means = per_prompt[idx].mean(1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def evaluate(args) -> dict:
    import torch

    from .quality import classify, load_classifier, train_classifier

    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    clf_path = train_classifier(args.data, args.checkpoints, progress=False)
    model, families = load_classifier(clf_path)
    features, encode, index, source, sampling = _setup(args)
    mean, std = load_mean_std(args.data)
    cases = [(name, text, fam) for name in args.sets for text, fam in SETS[name]]
    unknown = sorted({fam for _, _, fam in cases} - set(families))
    if unknown:   # a small dataset may lack a family: its paraphrases cannot be judged
        print(f"note: skipping paraphrases of {unknown}: not among the classifier's families", file=sys.stderr)
        cases = [c for c in cases if c[2] in families]
    if args.reference:
        cases += [("reference", t, f) for t, f in _reference_cases(args.data, families, args.reference)]
    if args.limit:
        cases = cases[:args.limit]
    seeds = [args.seed + s for s in range(args.seeds)]
    methods = [m for m in args.methods]
    print(f"TCA eval: {len(cases)} prompts x {len(seeds)} seeds x {len(methods)} methods; index {source} "
          f"({len(index)} captions); sampling {sampling}", file=sys.stderr)

    results: dict = {"bundle": str(args.bundle), "backend": "torch" if args.torch else f"onnxruntime-{args.variant}",
                     "index": source, "index_captions": len(index), "seeds": seeds, "sampling": sampling.to_dict(),
                     "classifier": str(clf_path), "methods": {}}
    rng = np.random.default_rng(0)
    raw_correct = None
    for method in methods:
        tm = time.perf_counter()
        with torch.no_grad():
            aligned_text = aligned_texts(method, [t for _, t, _ in cases], index, encode)
        correct = np.zeros((len(cases), len(seeds)))
        preds: list[list[str]] = [[] for _ in cases]
        for si, seed in enumerate(seeds):
            for b in range(0, len(cases), args.batch):
                rows = list(range(b, min(b + args.batch, len(cases))))
                with torch.no_grad():   # row r's seed is the same for every method: differences are paired
                    feats = features.generate([aligned_text[r] for r in rows], [seed * 100_003 + r for r in rows],
                                              None)
                clips = [((f - mean) / std).astype(np.float32) if len(f) else
                         np.zeros((4, len(mean)), np.float32) for f in feats]
                p, _ = classify(model, families, clips)
                for r, pred in zip(rows, p):
                    preds[r].append(pred)
                    correct[r, si] = pred == cases[r][2]
        if method == "raw":
            raw_correct = correct
        summary = {}
        groups = {name: [i for i, c in enumerate(cases) if c[0] == name] for name in dict.fromkeys(c[0] for c in cases)}
        groups["paraphrases"] = [i for i, c in enumerate(cases) if c[0] != "reference"]
        for name, rows in groups.items():
            if not rows:
                continue
            lo, hi = _interval(correct[rows], rng)
            summary[name] = {"accuracy": float(correct[rows].mean()), "ci95": [lo, hi], "prompts": len(rows)}
            if raw_correct is not None and method != "raw":   # paired with raw: same prompts, same seeds
                diff = correct[rows] - raw_correct[rows]
                dlo, dhi = _interval(diff, rng)
                summary[name]["vs_raw"] = {"delta": float(diff.mean()), "ci95": [dlo, dhi]}
        results["methods"][method] = {
            "summary": summary, "seconds": time.perf_counter() - tm,
            "cases": [{"set": s, "prompt": t, "family": f, "aligned": a, "predictions": pr,
                       "accuracy": float(correct[i].mean())}
                      for i, ((s, t, f), a, pr) in enumerate(zip(cases, aligned_text, preds))]}
        print(f"  {method:14s} " + "  ".join(f"{k} {v['accuracy']:.3f} [{v['ci95'][0]:.2f}, {v['ci95'][1]:.2f}]"
                                             + (f" (vs raw {v['vs_raw']['delta']:+.3f})" if "vs_raw" in v else "")
                                             for k, v in summary.items())
              + f"  ({time.perf_counter() - tm:.0f} s)", file=sys.stderr)
    results["seconds"] = time.perf_counter() - t0
    return results


def table(results: dict) -> str:
    """Accuracy [95% CI] per method and prompt set; below, the paired difference to raw [95% CI]."""
    first = next(iter(results["methods"].values()))["summary"]
    sets = list(first)
    lines = ["| method | " + " | ".join(f"{s} (n={first[s]['prompts']})" for s in sets) + " |",
             "|---|" + "---|" * len(sets)]
    for m, r in results["methods"].items():
        cells = []
        for s in sets:
            v = r["summary"][s]
            cell = f"{v['accuracy']:.3f} [{v['ci95'][0]:.2f}, {v['ci95'][1]:.2f}]"
            if "vs_raw" in v:
                d = v["vs_raw"]
                cell += f"<br>{d['delta']:+.3f} [{d['ci95'][0]:+.2f}, {d['ci95'][1]:+.2f}]"
            cells.append(cell)
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, help="the bundle (required unless --torch)")
    ap.add_argument("--data", type=Path, required=True, help="the dataset folder (classifier, normalisation)")
    ap.add_argument("--checkpoints", type=Path, required=True, help="where classifier.pt lives (trained if missing)")
    ap.add_argument("--variant", default="fp32")
    ap.add_argument("--torch", action="store_true", help="generate with the torch checkpoints instead of the bundle")
    ap.add_argument("--methods", type=lambda s: s.split(","), default=list(METHODS),
                    help=f"comma-separated, from {','.join(METHODS)}")
    ap.add_argument("--sets", type=lambda s: s.split(","), default=list(SETS))
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--temperature", type=float, help="default: the bundle's sampling_defaults")
    ap.add_argument("--reference", type=int, default=0, metavar="N",
                    help="also N test-split captions per family (the in-distribution ceiling)")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--limit", type=int, default=0, help="first N prompts only (smoke runs)")
    ap.add_argument("--out", type=Path, help="JSON results (default: <checkpoints>/tca_eval.json)")
    args = ap.parse_args(argv)
    if args.bundle is None and not args.torch:
        ap.error("--bundle is required (or --torch to generate with the checkpoints)")
    bad = [m for m in args.methods if m not in METHODS] + [s for s in args.sets if s not in SETS]
    if bad:
        ap.error(f"unknown method/set {bad}; methods {list(METHODS)}, sets {list(SETS)}")
    results = evaluate(args)
    out = args.out or args.checkpoints / "tca_eval.json"
    out.write_text(json.dumps(results, indent=1))
    print(table(results))
    print(f"wrote {out} ({results['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
