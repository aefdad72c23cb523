"""`mogo-export`: build data, train, export, verify. Each subcommand is one stage of the pipeline.

    mogo-export dataset data/procedural --clips 2000
    mogo-export train --data data/procedural --out checkpoints/base --preset base
    mogo-export export checkpoints/base --out bundles/base
    mogo-export verify bundles/base --checkpoints checkpoints/base
    mogo-export evaluate --data data/procedural --checkpoints checkpoints/base --bundle bundles/base
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def _dataset(args) -> int:
    from .data.procedural import build_dataset

    build_dataset(args.out, num_clips=args.clips, seed=args.seed, progress=True)
    print(f"dataset written to {args.out}")
    return 0


def _train(args) -> int:
    import torch

    from .train import train_all

    if args.threads:
        torch.set_num_threads(args.threads)

    train_all(args.data, args.out, preset=args.preset, seed=args.seed)
    return 0


def _export(args) -> int:
    from .export.bundle import INT8_GRAPHS, export_bundle

    int8 = () if args.int8 == "none" else tuple(g for g in args.int8.split(",") if g) or INT8_GRAPHS
    export_bundle(args.checkpoints, args.out, opset=args.opset, int8=int8, data=args.data)
    return 0


def _verify(args) -> int:
    from .verify import Thresholds, verify

    th = Thresholds(fp32_abs=args.fp32_abs, joints_mm=args.joints_mm, int8_token_agreement=args.int8_agreement,
                    int8_text_cosine=args.int8_cosine)
    report = verify(args.bundle, args.checkpoints, th, int8=not args.no_int8)
    print(report.table())
    print("PASS" if report.ok else "FAIL: at least one check breached its bar")
    return 0 if report.ok else 1


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

    from .quality import vq_reconstruction
    from .train import train_vq

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
    from .evaluation import EvaluatorSchedule, train_evaluator
    from .models.evaluator import EvaluatorConfig

    train_evaluator(args.data, args.out or args.data / "evaluator.pt", EvaluatorSchedule(steps=args.steps),
                    seed=args.seed, cfg=EvaluatorConfig(text_encoder=args.text_encoder))
    return 0


def _evaluate(args) -> int:
    from .evaluation import EvaluateRequest, ProtocolConfig, evaluate, print_report, write_json

    protocol = ProtocolConfig(repeats=args.repeats, split=args.split, length=args.length, seed=args.seed,
                              mm_captions=args.mm_captions, mm_generations=args.mm_generations)
    req = EvaluateRequest(args.data, args.checkpoints, args.bundle, args.variant, args.evaluator, args.glove,
                          args.t2m_meta, args.vq_ablation or [], protocol, args.threads, args.tca)
    report = evaluate(req)
    print_report(report)
    if args.json:
        print(f"wrote {write_json(report, args.json)}")
    return 0


def main(argv=None) -> int:
    from .export.graphs import DEFAULT_OPSET

    ap = argparse.ArgumentParser(prog="mogo-export", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("dataset", help="write the procedural motion dataset (HumanML3D layout)")
    p.add_argument("out", type=Path)
    p.add_argument("--clips", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(run=_dataset)

    p = sub.add_parser("train", help="train MoSA-VQ, extract tokens, train the RQHC-Transformer")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--preset", choices=["tiny", "base", "paper"], default="base")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None,
                   help="torch threads (default: torch's choice; 1 is faster on a busy machine)")
    p.set_defaults(run=_train)

    p = sub.add_parser("export", help="export checkpoints to an ONNX bundle")
    p.add_argument("checkpoints", type=Path)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET)
    p.add_argument("--int8", default="step,text_encoder",
                   help="graphs to also write as int8: comma-separated from step,text_encoder, or 'none'")
    p.add_argument("--data", type=Path, default=None,
                   help="dataset for the TCA caption index (default: the one the checkpoints were trained on)")
    p.set_defaults(run=_export)

    p = sub.add_parser("verify", help="parity of a bundle against its checkpoints; exit 1 on any breach")
    p.add_argument("bundle", type=Path)
    p.add_argument("--checkpoints", type=Path, required=True)
    p.add_argument("--fp32-abs", type=float, default=1e-4)
    p.add_argument("--joints-mm", type=float, default=0.1)
    p.add_argument("--int8-agreement", type=float, default=0.95,
                   help="teacher-forced int8 vs fp32 argmax agreement per (step, level)")
    p.add_argument("--int8-cosine", type=float, default=0.98)
    p.add_argument("--no-int8", action="store_true")
    p.set_defaults(run=_verify)

    p = sub.add_parser("quality", help="VQ reconstruction, action accuracy and diversity of generated motion")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--checkpoints", type=Path, required=True)
    p.add_argument("--gif", type=Path, default=None, help="also write one generated motion per family here")
    p.add_argument("--bundle", type=Path, default=None,
                   help="also judge every variant of this bundle (fp32, int8) through the runtime, same seeds")
    p.add_argument("--seeds", type=int, default=1, help="sampling draws per caption, averaged (default 1)")
    p.add_argument("--threads", type=int, default=2, help="onnxruntime threads of the bundle rows")
    p.set_defaults(run=_quality)

    p = sub.add_parser("ablation", help="MoSA-VQ with vs without learnable scaling (same budget and seed)")
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--preset", choices=["tiny", "base", "paper"], default="base")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
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

    args = ap.parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, FileNotFoundError, KeyError) as e:  # bad input: a message, not a traceback
        if os.environ.get("MOGO_DEBUG"):
            raise
        print(f"mogo-export: error: {e} (set MOGO_DEBUG=1 for the traceback)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
