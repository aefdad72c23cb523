"""`mogo-eval`: judge what mogo-export trained and exported. Evaluation only; the product never imports it.

    mogo-eval quality --data data/procedural --checkpoints checkpoints/base --bundle bundles/base
    mogo-eval ablation --data data/procedural --out checkpoints/ablation
    mogo-eval train-evaluator --data data/procedural
    mogo-eval evaluate --data data/procedural --checkpoints checkpoints/base --bundle bundles/base
    mogo-eval stream --bundle bundles/base --variant int8 --minutes 10 --json outputs/stream_eval.json
"""
from __future__ import annotations

import argparse
from pathlib import Path


def _quality(args) -> int:
    import json

    from .quality import quality_report

    report = quality_report(args.data, args.checkpoints, gif=args.gif, bundle=args.bundle, seeds=args.seeds,
                            threads=args.threads)
    print(json.dumps(report, indent=2))
    return 0


def _ablation(args) -> int:
    """MoSA-VQ with and without learnable scaling: same preset, budget and seed; test-split MPJPE."""
    import torch

    from mogo_export.train import train_vq

    from .quality import vq_reconstruction

    if args.threads:
        torch.set_num_threads(args.threads)
    rows = {}
    for name, scaling in (("with learnable scaling", True), ("without learnable scaling", False)):
        out = args.out / ("scaling" if scaling else "no-scaling")
        train_vq(args.data, out, args.preset, seed=args.seed, learnable_scaling=scaling)
        rows[name] = vq_reconstruction(args.data, out / "vq.pt")
    for name, r in rows.items():
        print(f"{name:28s} MPJPE {r['mpjpe_mm']:.1f} mm   L1 {r['l1']:.4f}")
    return 0


def _train_evaluator(args) -> int:
    from .judges.evaluator import EvaluatorConfig
    from .protocol import EvaluatorSchedule, train_evaluator

    train_evaluator(args.data, args.out or args.data / "evaluator.pt", EvaluatorSchedule(steps=args.steps),
                    seed=args.seed, cfg=EvaluatorConfig(text_encoder=args.text_encoder))
    return 0


def _evaluate(args) -> int:
    from .protocol import EvaluateRequest, ProtocolConfig, evaluate, print_report, write_json

    protocol = ProtocolConfig(repeats=args.repeats, split=args.split, length=args.length, seed=args.seed,
                              mm_captions=args.mm_captions, mm_generations=args.mm_generations)
    req = EvaluateRequest(args.data, args.checkpoints, args.bundle, args.variant, args.evaluator, args.glove,
                          args.t2m_meta, args.vq_ablation or [], protocol, args.threads, args.tca)
    report = evaluate(req)
    print_report(report)
    if args.json:
        print(f"wrote {write_json(report, args.json)}")
    return 0


def _stream(args) -> int:
    from .protocol import write_json
    from .quality import train_classifier
    from .streaming import print_report, stream_report

    classifier = args.classifier or train_classifier(args.data, args.checkpoints)
    report = stream_report(args.bundle, args.data, classifier, args.variant, args.threads, 60 * args.minutes,
                           args.seed)
    print_report(report)
    if args.json:
        print(f"wrote {write_json(report, args.json)}")
    return 0


def _actions(args) -> int:
    from .actions import actions_report, named_prompts_report, print_report
    from .protocol import write_json
    from .quality import train_classifier

    classifier = args.classifier or train_classifier(args.data, args.checkpoints)
    report = actions_report(args.bundle, args.data, classifier, args.variant, args.threads, args.prompts, args.seed)
    report["named"] = named_prompts_report(args.bundle, args.data, classifier, args.variant, args.threads)
    print_report(report)
    if args.json:
        print(f"wrote {write_json(report, args.json)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from mogo_export.cli import add_training_args

    ap = argparse.ArgumentParser(prog="mogo-eval", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("quality", help="VQ reconstruction, action accuracy and diversity of generated motion")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--checkpoints", type=Path, required=True)
    p.add_argument("--gif", type=Path, default=None, help="also write one generated motion per family here")
    p.add_argument("--bundle", type=Path, default=None,
                   help="also judge every variant of this bundle (fp32, int8) through the runtime, same seeds")
    p.add_argument("--seeds", type=int, default=1, help="sampling draws per caption, averaged (default 1)")
    p.add_argument("--threads", type=int, default=2, help="onnxruntime threads of the bundle rows")
    p.set_defaults(run=_quality)

    p = add_training_args(sub.add_parser("ablation", help="MoSA-VQ with vs without learnable scaling (same "
                                                          "budget and seed)"))
    p.set_defaults(run=_ablation)

    p = sub.add_parser("train-evaluator", help="train the text-motion contrastive evaluator the metrics use")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--out", type=Path, default=None, help="default: <data>/evaluator.pt")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--text-encoder", default="all-MiniLM-L6-v2", help="frozen sentence encoder of the text side")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(run=_train_evaluator)

    p = sub.add_parser("evaluate", help="R-Precision, FID, MM-Dist, Diversity, MultiModality (Guo et al. 2022)")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--checkpoints", type=Path, default=None, help="rows: VQ reconstruction and torch generation")
    p.add_argument("--bundle", type=Path, default=None, help="rows: the bundle's variants, via mogo_runtime")
    p.add_argument("--variant", action="append", default=None, help="fp32 or int8 (repeatable; default: all)")
    p.add_argument("--tca", action="store_true", help="also a row per variant with TCA-aligned prompts")
    p.add_argument("--evaluator", type=Path, default=None,
                   help="evaluator.pt, or Guo et al.'s finest.tar / t2m folder (default: <data>/evaluator.pt, "
                        "trained if missing)")
    p.add_argument("--glove", type=Path, default=None, help="Guo et al.'s glove/ folder (their evaluator only)")
    p.add_argument("--t2m-meta", type=Path, default=None, help="folder with their evaluator's mean.npy, std.npy")
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--split", default="test")
    p.add_argument("--length", choices=["model", "gt"], default="model",
                   help="generated length: the model's END (model) or the real clip's (gt)")
    p.add_argument("--mm-captions", type=int, default=32, help="captions for MultiModality (0 = skip)")
    p.add_argument("--mm-generations", type=int, default=10, help="motions per MultiModality caption")
    p.add_argument("--vq-ablation", type=Path, nargs=2, default=None, metavar=("A.pt", "B.pt"),
                   help="two vq.pt (with / without learnable scaling): also the Table 3 layout")
    p.add_argument("--threads", type=int, default=2, help="onnxruntime threads of the bundle rows")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None)
    p.set_defaults(run=_evaluate)

    p = sub.add_parser("stream", help="an endless stream with a new prompt every 4-10 s: follows, reacts, smooth, "
                                      "no drift, bounded memory and time")
    p.add_argument("--bundle", type=Path, default=Path("bundles/base"))
    p.add_argument("--variant", default="int8")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime threads")
    p.add_argument("--minutes", type=float, default=10.0, help="length of the stream (at least 20 s)")
    p.add_argument("--data", type=Path, default=Path("data/procedural"),
                   help="held-out captions, the classifier's training data and the long sequences compared with")
    p.add_argument("--checkpoints", type=Path, default=Path("checkpoints/base"),
                   help="where quality's classifier.pt is (trained there if missing)")
    p.add_argument("--classifier", type=Path, default=None, help="a classifier.pt to use instead")
    p.add_argument("--seed", type=int, default=0, help="seeds the prompts, their times and the stream")
    p.add_argument("--json", type=Path, default=None)
    p.set_defaults(run=_stream)

    p = sub.add_parser("actions", help="prompts of two and three actions: is every action played, in order?")
    p.add_argument("--bundle", type=Path, default=Path("bundles/base"))
    p.add_argument("--variant", default="int8")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime threads")
    p.add_argument("--prompts", type=int, default=100, help="half of two actions, half of three")
    p.add_argument("--data", type=Path, default=Path("data/procedural"), help="held-out captions, the classifier's data")
    p.add_argument("--checkpoints", type=Path, default=Path("checkpoints/base"),
                   help="where quality's classifier.pt is (trained there if missing)")
    p.add_argument("--classifier", type=Path, default=None, help="a classifier.pt to use instead")
    p.add_argument("--seed", type=int, default=0, help="seeds the prompts and the motions")
    p.add_argument("--json", type=Path, default=None)
    p.set_defaults(run=_actions)

    return ap


def main(argv=None) -> int:
    from mogo_export.cli import run_command

    return run_command("mogo-eval", build_parser().parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
