"""The main job for a new user (`make demo`): data, and motions a person can look at.

    python -m mogo_export.demo [--data data/procedural] [--out outputs/demo]

Builds the procedural dataset if it is not there yet, then writes a preview GIF and a BVH for a few clips and
prints where they are.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from mogo_runtime.bvh import write_bvh
from mogo_runtime.preview import render_gif
from mogo_runtime.skeleton import HUMANML3D

from .data.procedural import build_dataset


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("data/procedural"))
    ap.add_argument("--out", type=Path, default=Path("outputs/demo"))
    ap.add_argument("--clips", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    if not (args.data / "dataset.json").exists():
        t0 = time.perf_counter()
        print(f"building the procedural dataset ({args.clips} clips) in {args.data} ...")
        build_dataset(args.data, num_clips=args.clips, seed=args.seed, progress=True)
        print(f"  done in {time.perf_counter() - t0:.1f} s")
    else:
        print(f"using the dataset in {args.data}")

    args.out.mkdir(parents=True, exist_ok=True)
    ids = (args.data / "test.txt").read_text().split()[:4]
    for clip in ids:
        joints = np.load(args.data / "new_joints" / f"{clip}.npy")
        caption = (args.data / "texts" / f"{clip}.txt").read_text().splitlines()[0].split("#")[0]
        gif = render_gif(args.out / f"{clip}.gif", joints, HUMANML3D, fps=HUMANML3D.fps, title=caption)
        bvh = write_bvh(args.out / f"{clip}.bvh", joints, HUMANML3D, fps=HUMANML3D.fps, units="cm")
        print(f"  {caption!r}: {gif} {bvh}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
