"""Writing the procedural dataset in the HumanML3D folder layout: the clip files (short clips, then long
sequences, then path sequences, then control sequences), the train/val/test split, the Mean/Std feature
statistics, dataset.json, and the command line (`python -m mogo_export.data.procedural`).

The whole dataset is the unit of atomicity: it is written into a hidden temporary sibling folder and
renamed into place at the end (removed on any failure), so its single files need no atomic writes of their
own. Everything is a function of (num_clips, long_sequences, path_sequences, control_sequences, seed),
whatever the number of worker processes; a short clip does not depend on the other counts, nor a long, path or
control sequence on the counts before it (only its id does).
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
from typing import Callable

import numpy as np
from tqdm import tqdm

from mogo_runtime.kinematics.features import FeatureLayout
from mogo_runtime.kinematics.skeleton import HUMANML3D

from ..humanml3d import canonicalize, extract_features
from .captions import caption_line
from .clips import Clip, family_plan, generate_clip, label_for
from .families import FAMILIES
from .pose import FPS
from .paths import CONTROL_KINDS, generate_path_sequence
from .sequences import generate_long

# 2: jumps land where they are meant to (in place, or their distance ahead); long sequences
# 3: path sequences (short clips and long sequences unchanged)
# 4: 46 more action families (styles, transitions, mimed, gestures, combat, exercise; the first 21 unchanged), and
#    body parts other than the feet that may rest on the floor (kneeling, sitting, lying, falling)
# 5: (never shipped) stops and speed changes the caption does not name, inside the path sequences
# 6: control sequences after the path sequences, listed in dataset.json's "control_only" (everything else unchanged)
GENERATOR_VERSION = 6
SPLITS = (("train", 0.80), ("val", 0.15), ("test", 0.05))
LONG_EVERY = 10  # by default one long sequence per 10 short clips
PATH_EVERY = 10  # and one path sequence
CONTROL_EVERY = 10  # and one control sequence
# generator streams, np.random.default_rng([seed, ..., stream]): a new kind of draw gets a new stream, so
# adding it changes nothing drawn before (short clips are [seed, index]; family_plan uses 1 and 2)
SPLIT_STREAM, LONG_STREAM, LONG_SPLIT_STREAM, PATH_STREAM, PATH_SPLIT_STREAM = 3, 4, 5, 6, 7
CONTROL_STREAM, CONTROL_SPLIT_STREAM = 8, 9


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


def _generate(index: int, plan: list[tuple[str, ...]], num_long: int, num_path: int,
              seed: int) -> tuple[Clip, bool]:
    """Clip `index`: the short clips of `plan` first, then `num_long` long sequences, then `num_path` path
    sequences, then the control sequences; -> (clip, is it timed: a long, path or control sequence)."""
    if index < len(plan):
        return generate_clip(plan[index], np.random.default_rng([seed, index])), False
    index -= len(plan)
    if index < num_long:
        return generate_long(np.random.default_rng([seed, index, LONG_STREAM])), True
    index -= num_long
    if index < num_path:
        return generate_path_sequence(np.random.default_rng([seed, index, PATH_STREAM])), True
    rng = np.random.default_rng([seed, index - num_path, CONTROL_STREAM])
    return generate_path_sequence(rng, CONTROL_KINDS), True


def _write_clip(index: int, plan: list[tuple[str, ...]], num_long: int, num_path: int, seed: int,
                root: Path) -> tuple[str, str, int, list | None]:
    """Write clip `index`'s files; -> (id, label, frames, its segments if it is a long, path or control
    sequence)."""
    clip_id = f"{index:06d}"
    (joints, captions, segments), long = _generate(index, plan, num_long, num_path, seed)
    features = extract_features(joints, HUMANML3D)
    np.save(root / "new_joint_vecs" / f"{clip_id}.npy", features)
    np.save(root / "new_joints" / f"{clip_id}.npy", canonicalize(joints, HUMANML3D).astype(np.float32))
    lines = [caption_line(c) for c in captions]
    if long:  # HumanML3D's timed lines: what happens from start to end (seconds)
        lines += [caption_line(s.caption, s.start / FPS, s.end / FPS) for s in segments]
    (root / "texts" / f"{clip_id}.txt").write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    label = label_for(plan[index] if not long else tuple(s.family for s in segments))
    (root / "labels" / f"{clip_id}.txt").write_text(label + "\n", encoding="utf-8")
    spans = [{"family": s.family, "start": s.start, "end": s.end} for s in segments] if long else None
    return clip_id, label, len(joints), spans


def split_ids(ids: list[str], seed: int, stream: int = SPLIT_STREAM) -> dict[str, list[str]]:
    """Deterministic 80/15/5 split of clip ids (each split sorted); from 3 clips on, no split is empty."""
    n = len(ids)
    order = np.random.default_rng([seed, stream]).permutation(n)
    n_val = int(round(SPLITS[1][1] * n))
    n_test = n - int(round(SPLITS[0][1] * n)) - n_val
    if n >= 3:
        n_val, n_test = max(1, n_val), max(1, n_test)
    n_train = n - n_val - n_test
    parts = {"train": order[:n_train], "val": order[n_train:n_train + n_val], "test": order[n_train + n_val:]}
    return {name: sorted(ids[i] for i in idx) for name, idx in parts.items()}


def _frame_stats(frames: list[int]) -> dict:
    if not frames:
        return {}
    return {"min": int(min(frames)), "max": int(max(frames)), "mean": round(float(np.mean(frames)), 2)}


def _build_into(tmp: Path, num_clips: int, num_long: int, num_path: int, num_control: int, seed: int,
                progress: bool, workers: int) -> None:
    """Write every file of the dataset into `tmp` (see build_dataset)."""
    plan = family_plan(num_clips, seed)
    job = partial(_write_clip, plan=plan, num_long=num_long, num_path=num_path, seed=seed, root=tmp)
    total = num_clips + num_long + num_path + num_control
    bar = tqdm(total=total, desc="procedural clips", unit="clip", disable=not progress)
    results = []
    if workers > 1 and total > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            for r in pool.imap(job, range(total), chunksize=8):
                results.append(r)
                bar.update()
    else:
        for i in range(total):
            results.append(job(i))
            bar.update()
    bar.close()

    ends = np.cumsum([num_clips, num_long, num_path])
    short, long, path, control = results[:ends[0]], results[ends[0]:ends[1]], results[ends[1]:ends[2]], \
        results[ends[2]:]
    ids = [r[0] for r in short]
    splits = split_ids(ids, seed)
    # long, path and control sequences are split on their own, so adding them leaves the others' split as it was
    long_splits = split_ids([r[0] for r in long], seed, LONG_SPLIT_STREAM)
    path_splits = split_ids([r[0] for r in path], seed, PATH_SPLIT_STREAM)
    control_splits = split_ids([r[0] for r in control], seed, CONTROL_SPLIT_STREAM)
    for name, members in splits.items():
        members = members + long_splits[name] + path_splits[name] + control_splits[name]
        (tmp / f"{name}.txt").write_text("".join(m + "\n" for m in members), encoding="utf-8")
    # Statistics over the short clips only: long sequences are the same actions, with standing cross-fades
    # between them; with them Mean/Std would move with how many are built (200 hold a third of the frames).
    train = [tmp / "new_joint_vecs" / f"{m}.npy" for m in splits["train"] or ids]
    mean, std = mean_std(train, HUMANML3D.num_joints)
    np.save(tmp / "Mean.npy", mean)
    np.save(tmp / "Std.npy", std)

    labels = [r[1] for r in short]
    segments = {r[0]: r[3] for r in long + path + control}
    family_spans = [s["family"] for r in long for s in r[3]]
    path_spans = [s["family"] for r in path for s in r[3]]
    info = {
        "generator": "mogo_export.data.procedural",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "num_clips": num_clips,
        "splits": {k: len(v) + len(long_splits[k]) + len(path_splits[k]) + len(control_splits[k])
                   for k, v in splits.items()},
        "families": list(FAMILIES),
        "label_counts": {k: labels.count(k) for k in sorted(set(labels))},
        "label_format": "family name, or 'seq:<first>+<second>' for a two-action sequence (in order); a long "
                        "sequence's label is 'seq:' and its families in order; label_counts counts short clips",
        "num_sequences": sum(lab.startswith("seq:") for lab in labels),
        "fps": FPS,
        "frames": _frame_stats([r[2] for r in short]),
        "num_long_sequences": num_long,
        "long_frames": _frame_stats([r[2] for r in long]),
        "long_family_counts": {k: family_spans.count(k) for k in sorted(set(family_spans))},
        "num_path_sequences": num_path,
        "path_frames": _frame_stats([r[2] for r in path]),
        "path_family_counts": {k: path_spans.count(k) for k in sorted(set(path_spans))},
        "path_format": "path sequences (ids after the long sequences; paths.py: 20-60 s of walking, running, "
                       "turning, standing, backward, sideways and diagonal steps along a random path) are "
                       "labelled, captioned and segmented as long sequences are: 'seq:' and their segments' "
                       "families, a timed caption per segment, and their segments in \"segments\"",
        "num_control_sequences": num_control,
        "control_only": [r[0] for r in control],
        "control_format": "control sequences (ids after the path sequences) are path sequences that also stop "
                          "inside a walk or run and change speed without their caption saying so; they are "
                          "stored as path sequences are, and \"control_only\" lists them: a model learns from "
                          "them only with their own future root as its control (the control adapter)",
        "segments": segments,
        "segment_format": "long sequence id -> its actions in order, each shown on frames [start, end) of "
                          "new_joints/<id>.npy (the features have one frame fewer); consecutive segments meet "
                          "at the middle of the cross-fade between them; texts/<id>.txt has one line per "
                          "segment timed start / fps to end / fps seconds",
        "feature_dim": FeatureLayout(HUMANML3D.num_joints).dim,
        "skeleton": HUMANML3D.to_dict(),
        "std_convention": "HumanML3D mean_variance: std averaged within each feature group, weights 1.0; "
                          "computed over the train split of the short clips (long sequences left out)",
    }
    (tmp / "dataset.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n", encoding="utf-8")


def build_dataset(out_dir, num_clips: int = 2000, seed: int = 0, progress: bool = True, workers: int = 2,
                  overwrite: bool = False, long_sequences: int | None = None,
                  path_sequences: int | None = None, control_sequences: int | None = None) -> Path:
    """Write a procedural dataset in the HumanML3D folder layout and return its path.

    `num_clips` short clips (ids 0 .. num_clips-1: single actions, every 5th a two-action sequence, 2-10 s)
    and then `long_sequences` long ones (default num_clips // 10; 20-60 s, 3-8 actions, sequences.py), and
    then `path_sequences` path sequences (default num_clips // 10; 20-60 s of locomotion along a random path,
    a segment per move, paths.py; written as long sequences are), and then `control_sequences` control
    sequences (default num_clips // 10: path sequences that also stop and change speed unnamed, for the control
    adapter only; dataset.json's "control_only" lists them):
      new_joint_vecs/NNNNNN.npy  (T-1, 263) float32 features (mogo_export.data.humanml3d.extract_features)
      new_joints/NNNNNN.npy      (T, 22, 3) float32 joints, canonicalised as HumanML3D's are (floor y=0,
                                 frame 0 root at x=z=0 facing +z); the features have one frame fewer
      texts/NNNNNN.txt           lines `caption#word/POS ...#start#end`: 3-4 of the whole clip (0.0#0.0);
                                 a long (or path) sequence has 1-2 of the whole and one per action (or
                                 move), timed in seconds
      labels/NNNNNN.txt          the family (`squat`) or, for a sequence, `seq:first+second+...`
      train.txt val.txt test.txt clip ids, an 80/15/5 split (of the short clips, the long ones, the path ones)
      Mean.npy Std.npy           feature statistics over the short clips' train split (see `mean_std`)
      dataset.json               generator version, seed, counts, families, fps, skeleton, and each long
                                 or path sequence's segments (family, start and end frame)
    Everything is a function of (the counts and seed): the same call writes
    byte-identical files, whatever `workers` is. The dataset is built in a temporary sibling folder and
    renamed into place at the end.
    """
    out = Path(out_dir)
    if num_clips < 1:
        raise ValueError(f"num_clips must be >= 1, got {num_clips}")
    num_long = num_clips // LONG_EVERY if long_sequences is None else int(long_sequences)
    if num_long < 0:
        raise ValueError(f"long_sequences must be >= 0, got {long_sequences}")
    num_path = num_clips // PATH_EVERY if path_sequences is None else int(path_sequences)
    if num_path < 0:
        raise ValueError(f"path_sequences must be >= 0, got {path_sequences}")
    num_control = num_clips // CONTROL_EVERY if control_sequences is None else int(control_sequences)
    if num_control < 0:
        raise ValueError(f"control_sequences must be >= 0, got {control_sequences}")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass overwrite=True (--overwrite) to replace it")
    return write_whole(out, "building", ("new_joint_vecs", "new_joints", "texts", "labels"),
                       lambda tmp: _build_into(tmp, num_clips, num_long, num_path, num_control, seed, progress,
                                               workers))


def write_whole(out: Path, doing: str, subdirs: tuple[str, ...], fill: Callable[[Path], object]):
    """`fill(folder)` into a hidden sibling of `out` (with `subdirs`), renamed to `out` when it returns (replacing an
    `out` that exists), removed if it raises: a dataset appears whole or not at all. -> what `fill` returns, or out."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{doing}-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    for sub in subdirs:
        (tmp / sub).mkdir(parents=True)
    try:
        result = fill(tmp)
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
    return out if result is None else result


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m mogo_export.data.procedural",
                                 description="Write a procedural text-to-motion dataset in the HumanML3D layout.")
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--clips", type=int, default=2000)
    ap.add_argument("--long", type=int, default=None, help="long sequences (default: clips // 10)")
    ap.add_argument("--path-sequences", type=int, default=None,
                    help="path sequences: locomotion along random paths (default: clips // 10)")
    ap.add_argument("--control-sequences", type=int, default=None,
                    help="control sequences: path sequences with unnamed stops and speed changes, which train "
                         "only the control adapter (default: clips // 10)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--overwrite", action="store_true", help="replace OUT_DIR if it exists")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = build_dataset(args.out_dir, args.clips, args.seed, progress=not args.quiet, workers=args.workers,
                        overwrite=args.overwrite, long_sequences=args.long, path_sequences=args.path_sequences,
                        control_sequences=args.control_sequences)
    info = json.loads((out / "dataset.json").read_text(encoding="utf-8"))
    print(f"wrote {args.clips} clips, {info['num_long_sequences']} long sequences, "
          f"{info['num_path_sequences']} path sequences and {info['num_control_sequences']} control sequences to "
          f"{out} in {time.perf_counter() - t0:.1f} s")
