"""Writing the procedural dataset in the HumanML3D folder layout: the clip files, the train/val/test split,
the Mean/Std feature statistics, dataset.json, and the command line (`python -m mogo_export.data.procedural`).

The whole dataset is the unit of atomicity: it is written into a hidden temporary sibling folder and
renamed into place at the end (removed on any failure), so its single files need no atomic writes of their
own. Everything is a function of (num_clips, seed), whatever the number of worker processes.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import shutil
import time
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mogo_runtime.features import FeatureLayout
from mogo_runtime.skeleton import HUMANML3D

from ..humanml3d import canonicalize, extract_features
from .captions import caption_line
from .clips import family_plan, generate_clip, label_for
from .families import FAMILIES
from .pose import FPS

GENERATOR_VERSION = 1
SPLITS = (("train", 0.80), ("val", 0.15), ("test", 0.05))


def mean_std(features, num_joints: int) -> tuple[np.ndarray, np.ndarray]:
    """HumanML3D's `mean_variance`: per-dimension mean; per-dimension std, then replaced in each feature
    group (root rot vel, root lin vel, root y, ric, rot6d, local vel, foot contact) by the group's mean
    std. HumanML3D divides each group by a weight that is 1.0 in the released code (the "feat_bias" of 5
    on root and foot terms is applied later, by T2M's evaluator training, not in Mean/Std.npy); so do we.

    `features`: a sequence of (T, D) arrays, or of paths to .npy files (read twice, never all at once).
    """
    load = (lambda f: np.load(f).astype(np.float64)) if not isinstance(features[0], np.ndarray) else \
        (lambda f: f.astype(np.float64))
    n, total = 0, 0.0
    for f in features:  # two passes in float64: the mean, then squared deviations from it
        x = load(f)
        n, total = n + len(x), total + x.sum(axis=0)
    mean = total / n
    sq = 0.0
    for f in features:
        sq = sq + ((load(f) - mean) ** 2).sum(axis=0)
    std = np.sqrt(sq / n)
    for sl in FeatureLayout(num_joints).slices().values():
        std[sl] = std[sl].mean()
    return mean.astype(np.float32), std.astype(np.float32)


def _write_clip(index: int, plan: list[tuple[str, ...]], seed: int, root: Path) -> tuple[str, str, int]:
    clip_id = f"{index:06d}"
    families = plan[index]
    joints, captions = generate_clip(families, np.random.default_rng([seed, index]))
    features = extract_features(joints, HUMANML3D)
    np.save(root / "new_joint_vecs" / f"{clip_id}.npy", features)
    np.save(root / "new_joints" / f"{clip_id}.npy", canonicalize(joints, HUMANML3D).astype(np.float32))
    (root / "texts" / f"{clip_id}.txt").write_text("".join(caption_line(c) + "\n" for c in captions),
                                                  encoding="utf-8")
    label = label_for(families)
    (root / "labels" / f"{clip_id}.txt").write_text(label + "\n", encoding="utf-8")
    return clip_id, label, len(joints)


def split_ids(ids: list[str], seed: int) -> dict[str, list[str]]:
    """Deterministic 80/15/5 split of clip ids (each split sorted); from 3 clips on, no split is empty."""
    n = len(ids)
    order = np.random.default_rng([seed, 3]).permutation(n)
    n_val = int(round(SPLITS[1][1] * n))
    n_test = n - int(round(SPLITS[0][1] * n)) - n_val
    if n >= 3:
        n_val, n_test = max(1, n_val), max(1, n_test)
    n_train = n - n_val - n_test
    parts = {"train": order[:n_train], "val": order[n_train:n_train + n_val], "test": order[n_train + n_val:]}
    return {name: sorted(ids[i] for i in idx) for name, idx in parts.items()}


def _build_into(tmp: Path, num_clips: int, seed: int, progress: bool, workers: int) -> None:
    """Write every file of the dataset into `tmp` (see build_dataset)."""
    plan = family_plan(num_clips, seed)
    job = partial(_write_clip, plan=plan, seed=seed, root=tmp)
    bar = tqdm(total=num_clips, desc="procedural clips", unit="clip", disable=not progress)
    results = []
    if workers > 1 and num_clips > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            for r in pool.imap(job, range(num_clips), chunksize=8):
                results.append(r)
                bar.update()
    else:
        for i in range(num_clips):
            results.append(job(i))
            bar.update()
    bar.close()

    ids = [r[0] for r in results]
    splits = split_ids(ids, seed)
    for name, members in splits.items():
        (tmp / f"{name}.txt").write_text("".join(m + "\n" for m in members), encoding="utf-8")
    train = [tmp / "new_joint_vecs" / f"{m}.npy" for m in splits["train"] or ids]
    mean, std = mean_std(train, HUMANML3D.num_joints)
    np.save(tmp / "Mean.npy", mean)
    np.save(tmp / "Std.npy", std)

    labels = [r[1] for r in results]
    frames = np.array([r[2] for r in results])
    info = {
        "generator": "mogo_export.data.procedural",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "num_clips": num_clips,
        "splits": {k: len(v) for k, v in splits.items()},
        "families": list(FAMILIES),
        "label_counts": {k: labels.count(k) for k in sorted(set(labels))},
        "label_format": "family name, or 'seq:<first>+<second>' for a two-action sequence (in order)",
        "num_sequences": sum(lab.startswith("seq:") for lab in labels),
        "fps": FPS,
        "frames": {"min": int(frames.min()), "max": int(frames.max()), "mean": round(float(frames.mean()), 2)},
        "feature_dim": FeatureLayout(HUMANML3D.num_joints).dim,
        "skeleton": HUMANML3D.to_dict(),
        "std_convention": "HumanML3D mean_variance: std averaged within each feature group, weights 1.0; "
                          "computed over the train split",
    }
    (tmp / "dataset.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n", encoding="utf-8")


def build_dataset(out_dir, num_clips: int = 2000, seed: int = 0, progress: bool = True, workers: int = 2,
                  overwrite: bool = False) -> Path:
    """Write a procedural dataset in the HumanML3D folder layout and return its path.

      new_joint_vecs/NNNNNN.npy  (T-1, 263) float32 features (mogo_export.data.humanml3d.extract_features)
      new_joints/NNNNNN.npy      (T, 22, 3) float32 joints, canonicalised as HumanML3D's are (floor y=0,
                                 frame 0 root at x=z=0 facing +z); the features have one frame fewer
      texts/NNNNNN.txt           3-4 lines `caption#word/POS ...#0.0#0.0`
      labels/NNNNNN.txt          the family (`squat`) or, for a two-action sequence, `seq:first+second`
      train.txt val.txt test.txt clip ids, an 80/15/5 split
      Mean.npy Std.npy           feature statistics over the train split (see `mean_std`)
      dataset.json               generator version, seed, counts, families, fps, skeleton
    Everything is a function of (num_clips, seed): the same call writes byte-identical files, whatever
    `workers` is. The dataset is built in a temporary sibling folder and renamed into place at the end.
    """
    out = Path(out_dir)
    if num_clips < 1:
        raise ValueError(f"num_clips must be >= 1, got {num_clips}")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass overwrite=True (--overwrite) to replace it")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.building-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    for sub in ("new_joint_vecs", "new_joints", "texts", "labels"):
        (tmp / sub).mkdir(parents=True)

    try:
        _build_into(tmp, num_clips, seed, progress, workers)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)  # never leave a half dataset behind, even a hidden one
        raise

    if out.exists():  # overwrite: swap in the new one, then drop the old
        trash = out.with_name(f".{out.name}.old-{os.getpid()}")
        out.rename(trash)
        tmp.rename(out)
        shutil.rmtree(trash)
    else:
        tmp.rename(out)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m mogo_export.data.procedural",
                                 description="Write a procedural text-to-motion dataset in the HumanML3D layout.")
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--clips", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--overwrite", action="store_true", help="replace OUT_DIR if it exists")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = build_dataset(args.out_dir, args.clips, args.seed, progress=not args.quiet, workers=args.workers,
                        overwrite=args.overwrite)
    print(f"wrote {args.clips} clips to {out} in {time.perf_counter() - t0:.1f} s")
