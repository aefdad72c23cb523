"""`mogo-export`: build data, train, export, verify. Each subcommand is one stage of the pipeline.

    mogo-export dataset data/procedural --clips 2000
    mogo-export import-motion mocap/ --captions mocap/captions.tsv --out data/mocap   # your BVH / glTF takes
    mogo-export train --data data/procedural --out checkpoints/base --preset base
    torchrun --standalone --nproc_per_node 2 -m mogo_export.cli train ...              # data-parallel
    mogo-export export checkpoints/base --out bundles/base
    mogo-export verify bundles/base --checkpoints checkpoints/base
    mogo-export opset bundles/base/step.portable.onnx --opset 15 -o step.opset15.onnx   # for older Unity Sentis

Evaluation (quality, ablation, train-evaluator, evaluate) is `mogo-eval` (package mogo_eval), not the product's.
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


def _import_motion(args) -> int:
    from .data.importer import import_motion

    report = import_motion(args.folder, args.captions, args.out, rig=args.rig, layout=args.layout, seed=args.seed,
                           overwrite=args.overwrite, progress=not args.quiet)
    rigs = ", ".join(f"{n} on {r}" for r, n in sorted(report.rigs.items()))
    print(f"imported {report.clips} clips ({rigs}) to {report.out}; largest residual {report.worst_residual_mm:.3f} mm")
    for note in report.notes:
        print(f"note: {note}")
    return 0


def _train(args) -> int:
    import torch

    from .distributed import session
    from .train import train_all

    if args.threads:
        torch.set_num_threads(args.threads)

    with session() as group:     # one process unless torchrun started this one (mogo_export/distributed.py)
        train_all(args.data, args.out, preset=args.preset, seed=args.seed, group=group, loss_log=args.loss_log)
    return 0


def _export(args) -> int:
    from .export.bundle import INT8_GRAPHS, ORT_VARIANTS, export_bundle

    int8 = () if args.int8 == "none" else tuple(g for g in args.int8.split(",") if g) or INT8_GRAPHS
    if args.ort is None:   # default: every variant the bundle has of int8 and portable
        ort = tuple(v for v in ORT_VARIANTS if args.portable or v != "portable")
    else:
        ort = () if args.ort == "none" else tuple(v for v in args.ort.split(",") if v)
    export_bundle(args.checkpoints, args.out, opset=args.opset, int8=int8, portable=args.portable, ort=ort,
                  data=args.data)
    return 0


def _verify(args) -> int:
    from .verify import Thresholds, verify

    th = Thresholds(fp32_abs=args.fp32_abs, joints_mm=args.joints_mm, int8_token_agreement=args.int8_agreement,
                    int8_text_cosine=args.int8_cosine)
    report = verify(args.bundle, args.checkpoints, th, int8=not args.no_int8, portable=not args.no_portable)
    print(report.table())
    print("PASS" if report.ok else "FAIL: at least one check breached its bar")
    return 0 if report.ok else 1


def _opset(args) -> int:
    import onnx

    from .export.opset import portable_problems, to_opset

    model = to_opset(onnx.load(str(args.graph)), args.opset)
    problems = portable_problems(model, args.opset)
    onnx.save(model, str(args.out))
    print(f"{args.out}: opset {args.opset}" + (f"; not portable: {'; '.join(problems)}" if problems else ""))
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

    p = sub.add_parser("import-motion", help="import motion capture (.bvh, .glb on a shipped rig or your rig file) "
                                             "with captions as a dataset (HumanML3D layout; docs/rigs.md)")
    p.add_argument("folder", type=Path, help="every .bvh and .glb under it is imported")
    p.add_argument("--captions", type=Path, required=True,
                   help="a TSV file: file<TAB>caption, or file<TAB>caption<TAB>start<TAB>end (seconds), per line")
    p.add_argument("--out", type=Path, required=True, help="the dataset folder to write")
    p.add_argument("--rig", default=None, help="the files' rig: a shipped rig's name or a rig file (.json); default: "
                                               "the shipped rig whose bone names each file has")
    p.add_argument("--layout", choices=("humanml3d", "procedural"), default="humanml3d",
                   help="how the hips and collars sit around the pelvis and chest: as in the real HumanML3D data "
                        "(default), or as in mogo's procedural data (to train beside it)")
    p.add_argument("--seed", type=int, default=0, help="seed of the train/val/test split")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_import_motion)

    p = add_training_args(sub.add_parser("train", help="train MoSA-VQ, extract tokens, train the RQHC-Transformer "
                                                       "(also under torchrun, on several processes or GPUs)"))
    p.add_argument("--loss-log", type=Path, default=None,
                   help="append one JSON line per optimiser step (phase, step, the global batch's loss) to this file")
    p.set_defaults(run=_train)

    p = sub.add_parser("export", help="export checkpoints to an ONNX bundle")
    p.add_argument("checkpoints", type=Path)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET)
    p.add_argument("--int8", default="step,text_encoder",
                   help="graphs to also write as int8: comma-separated from step,text_encoder, or 'none'")
    p.add_argument("--portable", action=argparse.BooleanOptionalAction, default=True,
                   help="write the portable variant (fixed-capacity step graph, opset 17, no int8 ops)")
    p.add_argument("--ort", default=None,
                   help="variants to also write in ORT format for an onnxruntime minimal build: comma-separated "
                        "from int8,portable, or 'none' (default: both)")
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
    p.add_argument("--no-portable", action="store_true", help="skip the portable variant's checks")
    p.set_defaults(run=_verify)

    p = sub.add_parser("opset", help="convert a graph to an older ONNX opset (the portable graphs go down to 15, "
                                     "the portable step to 14; docs/bundle.md)")
    p.add_argument("graph", type=Path)
    p.add_argument("--opset", type=int, required=True)
    p.add_argument("-o", "--out", type=Path, required=True)
    p.set_defaults(run=_opset)

    return run_command("mogo-export", ap.parse_args(argv))


def add_training_args(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The options of every command that trains models (train, and evaluation's ablation)."""
    from .presets import DEFAULT as DEFAULT_PRESET, NAMES as PRESETS

    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET, help="see mogo_export/presets.py")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None,
                   help="torch threads (default: torch's choice; 1 is faster on a busy machine)")
    return p


def run_command(prog: str, args) -> int:
    """Run a parsed command; bad input ends in one `PROG: error:` line and exit status 2, not a traceback."""
    try:
        return args.run(args)
    except (ValueError, FileNotFoundError, KeyError) as e:
        if os.environ.get("MOGO_DEBUG"):
            raise
        print(f"{prog}: error: {e} (set MOGO_DEBUG=1 for the traceback)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
