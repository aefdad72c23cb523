"""`mogo-export import-motion FOLDER --captions captions.tsv --out DATA`: a studio's motion capture (BVH, glTF
binary) as a dataset in the HumanML3D layout that `mogo-export train` reads (docs/rigs.md, "Importing your motion
capture").

Per file (every .bvh and .glb under FOLDER, in sorted order; hidden files and folders are skipped):
1. read it (mocap/bvh.py, mocap/gltf.py: the first animation) at its own frame rate;
2. find its rig (mocap/mapping.py): --rig (a shipped rig's name or a rig file), else the first shipped rig whose
   names it has (exactly, or ignoring case and punctuation: `mixamorig:Hips` = `mixamorigHips`); each of the 22 joints
   needs a bone, and the bones must keep HumanML3D's tree. Only the rig's names and sources are used: the rest
   pose comes from the file itself (BVH offsets, glTF node transforms), so one rig file serves every character
   with those bone names;
3. stand a BVH's rest pose upright (y up or z up files), invert the retarget (mocap/unretarget.py: HumanML3D
   joints in metres, on HumanML3D's skeleton, in the chosen `layout`) and resample to 20 fps, HumanML3D's rate;
4. write what the procedural writer writes for a clip (its `mean_std`, `split_ids` and `caption_line` are reused):
   new_joint_vecs/, new_joints/ (canonicalised), texts/, the 80/15/5 split, Mean.npy / Std.npy over the train
   split, and dataset.json (which file each clip came from, its rig and residual).
The dataset is written into a hidden sibling folder and renamed into place at the end, so a failure at any file
leaves nothing behind; every problem is one error naming the file (and line) and what is wrong.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
from tqdm import tqdm

from mogo_runtime.checks import read_file
from mogo_runtime.kinematics.features import FeatureLayout
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.outputs.rig import Rig, load_rig

from .humanml3d import canonicalize, extract_features
from .mocap import MotionFileError
from .mocap.bvh import read_bvh
from .mocap.gltf import read_glb
from .mocap.mapping import map_bones
from .mocap.unretarget import LAYOUTS, resample, unretarget, up_rotation
from .procedural.captions import caption_line
from .procedural.writer import mean_std, split_ids, write_whole

FORMAT_VERSION = 1
FPS = HUMANML3D.fps
READERS = {".bvh": read_bvh, ".glb": read_glb}
MAX_FILES = 100_000
MAX_CAPTIONS_BYTES = 64 << 20
MAX_CAPTION_CHARS = 1000
MAX_SECONDS = 1200.0        # 20 minutes a file
T2M_SECONDS = (2.0, 10.0)   # what `mogo-export train` keeps of a whole-clip caption (dataset.MIN/MAX_FRAMES)


class Caption(NamedTuple):
    text: str
    start: float                # seconds; start = end = 0: the whole clip
    end: float


@dataclass
class Report:
    out: Path
    clips: int = 0
    rigs: dict = field(default_factory=dict)        # rig name -> clips on it
    worst_residual_mm: float = 0.0
    notes: list = field(default_factory=list)


def read_captions_tsv(path) -> dict[str, list[Caption]]:
    """`file<TAB>caption`, or `file<TAB>caption<TAB>start<TAB>end` (seconds: a part of the clip), one a line, any
    number per file; blank lines and lines starting with # are skipped. -> relative path -> its captions."""
    path = Path(path)
    try:
        text = read_file(path, MAX_CAPTIONS_BYTES).decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not UTF-8 text (byte {e.start})") from None
    out: dict[str, list[Caption]] = {}
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        at, cols = f"{path}:{n}", line.split("\t")
        if len(cols) not in (2, 4):
            raise ValueError(f"{at}: expected 'file<TAB>caption' or 'file<TAB>caption<TAB>start<TAB>end', got "
                             f"{len(cols)} tab-separated columns")
        name, caption = cols[0].strip().replace("\\", "/"), " ".join(cols[1].split())
        if not name:
            raise ValueError(f"{at}: no file name before the tab")
        if not caption or len(caption) > MAX_CAPTION_CHARS or "#" in caption or not caption.isprintable():
            raise ValueError(f"{at}: the caption must be 1 to {MAX_CAPTION_CHARS} printable characters without '#' "
                             f"(HumanML3D's field separator), got {caption[:60]!r}")
        start = end = 0.0
        if len(cols) == 4:
            try:
                start, end = float(cols[2]), float(cols[3])
            except ValueError:
                start = end = float("nan")
            if not (0.0 <= start < end <= MAX_SECONDS):
                raise ValueError(f"{at}: start and end must be seconds with 0 <= start < end, got {cols[2]!r} and "
                                 f"{cols[3]!r}")
        out.setdefault(name, []).append(Caption(caption, start, end))
    if not out:
        raise ValueError(f"{path}: no captions")
    return out


def motion_files(folder) -> list[str]:
    """Every .bvh and .glb under `folder` (not following links to folders), as sorted relative POSIX paths."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    found = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for f in files:
            if not f.startswith(".") and Path(f).suffix.lower() in READERS:
                found.append((Path(root) / f).relative_to(folder).as_posix())
                if len(found) > MAX_FILES:
                    raise ValueError(f"{folder}: more than {MAX_FILES} motion files")
    if not found:
        raise ValueError(f"{folder}: no .bvh or .glb files")
    return sorted(found)


def read_motion(path, rig: "str | Path | Rig | None" = None, layout: str = "humanml3d") -> tuple[np.ndarray, dict]:
    """One file -> (HumanML3D joints (T, 22, 3) in metres at 20 fps, facts: rig, frames, file_fps, residual_mm)."""
    path = Path(path)
    take = READERS[path.suffix.lower()](path)
    seconds = (len(take.positions) - 1) / take.fps
    if not 0 < seconds <= MAX_SECONDS:
        raise MotionFileError(f"{path}: lasts {seconds:g} s ({len(take.positions)} frames at {take.fps:g} fps); "
                              f"2 frames to {MAX_SECONDS / 60:g} minutes are imported")
    rig, index = map_bones(take, rig)
    bones, rest = take.positions[:, index], take.rest[index]
    if path.suffix.lower() == ".bvh":     # glTF is y up by specification; BVH files come y up or z up
        up = up_rotation(rest, take.where)
        bones, rest = bones @ up.T, rest @ up.T
    try:   # at the file's own rate (the retarget's planted feet depend on it), then to HumanML3D's
        joints, residual = unretarget(bones, rest, take.fps, layout, where=take.where)
    except MotionFileError:
        raise
    except ValueError as e:          # the retarget refusing a degenerate pose
        raise MotionFileError(f"{path}: {e}") from None
    joints = resample(joints, take.fps, FPS, layout)
    if len(joints) < 2:
        raise MotionFileError(f"{path}: lasts {seconds:g} s, under 2 frames at {FPS:g} fps")
    return joints, {"rig": rig.name, "frames": len(joints), "file_fps": take.fps,
                    "residual_mm": round(residual * 1000, 4)}


def import_motion(folder, captions, out, rig=None, layout: str = "humanml3d", seed: int = 0,
                  overwrite: bool = False, progress: bool = True) -> Report:
    """Import every motion file of `folder` with its captions into a new dataset at `out` (module docstring)."""
    folder = Path(folder)
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    table, files = read_captions_tsv(captions), motion_files(folder)
    unknown = sorted(set(table) - set(files))
    if unknown:
        raise ValueError(f"{captions}: captions name {len(unknown)} files that are not .bvh or .glb files under "
                         f"{folder}: {', '.join(map(repr, unknown[:5]))}")
    bare = [f for f in files if f not in table]
    if bare:
        raise ValueError(f"{captions}: {len(bare)} motion files of {folder} have no caption: "
                         f"{', '.join(map(repr, bare[:5]))}{' ...' if len(bare) > 5 else ''}")
    if rig is not None:
        rig = load_rig(rig)            # once, and any problem with the rig file before any motion is read

    def clips():
        for rel in tqdm(files, desc="importing", unit="file", disable=not progress):
            joints, facts = read_motion(folder / rel, rig, layout)
            yield joints, table[rel], {"file": rel, **facts}

    return write_dataset(out, clips(), seed=seed, overwrite=overwrite, layout=layout)


def write_dataset(out, clips, seed: int = 0, overwrite: bool = False, layout: str = "humanml3d") -> Report:
    """Write `clips` (an iterable of (joints (T, 22, 3) metres at 20 fps, [Caption], facts for dataset.json's
    "sources")) as a dataset at `out`, the clip ids numbered in order: into a hidden sibling folder, renamed into
    place at the end (and removed on any failure)."""
    out = Path(out)
    if out.exists() and not overwrite:
        raise ValueError(f"{out} already exists; pass --overwrite to replace it")
    report = write_whole(out, "importing", ("new_joint_vecs", "new_joints", "texts"),
                         lambda tmp: _write_into(tmp, clips, seed, layout))
    report.out = out
    return report


def _write_into(tmp: Path, clips, seed: int, layout: str) -> Report:
    report, sources, short = Report(tmp), {}, []
    for i, (joints, captions, facts) in enumerate(clips):
        clip_id, seconds = f"{i:06d}", (len(joints) - 1) / FPS
        for c in captions:
            if c.end > seconds + 0.5 / FPS:
                raise ValueError(f"captions for {facts.get('file', clip_id)!r}: {c.text[:40]!r} ends at {c.end:g} s, "
                                 f"after the clip ({seconds:.2f} s)")
        features = extract_features(joints, HUMANML3D)
        if not np.isfinite(features).all():       # the readers bound every number; this is the last guard
            raise ValueError(f"{facts.get('file', clip_id)}: its motion gives non-finite features")
        np.save(tmp / "new_joint_vecs" / f"{clip_id}.npy", features)
        np.save(tmp / "new_joints" / f"{clip_id}.npy", canonicalize(joints, HUMANML3D).astype(np.float32))
        lines = [_caption_line(c) for c in captions]
        (tmp / "texts" / f"{clip_id}.txt").write_text("".join(ln + "\n" for ln in lines), encoding="utf-8")
        sources[clip_id] = facts
        if "rig" in facts:
            report.rigs[facts["rig"]] = report.rigs.get(facts["rig"], 0) + 1
        report.worst_residual_mm = max(report.worst_residual_mm, facts.get("residual_mm", 0.0))
        if any(c.start == c.end == 0.0 for c in captions) and not T2M_SECONDS[0] <= seconds < T2M_SECONDS[1]:
            short.append(facts.get("file", clip_id))
    if not sources:
        raise ValueError("no clips to write")
    ids = sorted(sources)
    splits = split_ids(ids, seed)
    for name, members in splits.items():
        (tmp / f"{name}.txt").write_text("".join(m + "\n" for m in members), encoding="utf-8")
    mean, std = mean_std([tmp / "new_joint_vecs" / f"{m}.npy" for m in splits["train"] or ids], HUMANML3D.num_joints)
    np.save(tmp / "Mean.npy", mean)
    np.save(tmp / "Std.npy", std)
    info = {"generator": "mogo_export.data.importer", "format_version": FORMAT_VERSION, "fps": FPS, "seed": seed,
            "layout": layout, "num_clips": len(ids), "splits": {k: len(v) for k, v in splits.items()},
            "feature_dim": FeatureLayout(HUMANML3D.num_joints).dim, "skeleton": HUMANML3D.to_dict(),
            "sources": sources,
            "source_format": "clip id -> the file it came from (relative to the imported folder), the rig its bones "
                             "were matched to, its frames at 20 fps, and residual_mm: how far the recovered joints "
                             "are from what the file's bones give when put back on the file's rig (retarget)",
            "std_convention": "HumanML3D mean_variance over the train split (mogo_export.data.procedural.writer)"}
    (tmp / "dataset.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    report.clips = len(ids)
    if short:
        report.notes.append(f"{len(short)} clips are outside {T2M_SECONDS[0]:g}-{T2M_SECONDS[1]:g} s and `mogo-export "
                            f"train` skips their whole-clip captions (T2M's rule); give them timed captions "
                            f"(file<TAB>caption<TAB>start<TAB>end) for their parts: {', '.join(short[:3])}"
                            f"{' ...' if len(short) > 3 else ''}")
    return report


def _caption_line(c: Caption) -> str:
    """The texts/ line, as the procedural writer writes it; words outside its part-of-speech lexicon are tagged X
    (Universal POS "other": nothing in training reads the tags)."""
    try:
        return caption_line(c.text, c.start, c.end)
    except ValueError:
        tokens = " ".join(f"{w}/X" for w in ("".join(ch for ch in word if ch.isalpha()) for word in
                                             c.text.lower().split()) if w)
        return f"{c.text}#{tokens}#{round(c.start, 2)!r}#{round(c.end, 2)!r}"
