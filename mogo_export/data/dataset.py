"""Loader for the HumanML3D / KIT-ML folder layout (which the procedural dataset also writes).

    root/
      train.txt val.txt test.txt   clip ids, one per line
      new_joint_vecs/<id>.npy      (T, D) features, D = 263 (HumanML3D) or 251 (KIT-ML)
      texts/<id>.txt               lines `caption#word/POS ...#start#end`
      labels/<id>.txt              optional: an action label (the procedural dataset writes these)
      Mean.npy Std.npy             (D,) feature statistics
      dataset.json                 optional: its "segments" give each long clip's actions (family, start
                                   and end frame), as the procedural dataset writes them

As in T2M's Text2MotionDataset: a caption with start = end = 0 describes the whole clip; one with a
time span describes frames [start * fps, end * fps) only, which become an item of their own; items
shorter than `min_frames` or not shorter than `max_frames` are dropped. A span item's label is the family
of the segment it covers where dataset.json has the clip's segments, else the clip's label. Unlike T2M,
every problem with the files is an error naming the file, not a silent skip.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, NamedTuple

import numpy as np

from mogo_runtime.kinematics.features import FeatureLayout
from mogo_runtime.kinematics.skeleton import get_skeleton

SPLITS = ("train", "val", "test")
# T2M's minimum motion lengths (frames); both datasets keep clips shorter than 200 frames
MIN_FRAMES = {"humanml3d": 40, "kit": 24}
MAX_FRAMES = 200


class MotionItem(NamedTuple):
    clip_id: str                 # "<id>" for a whole clip, "<id>:<first>-<stop>" for a captioned span
    features: np.ndarray         # (T, D) float32, not normalised
    captions: list[str]
    label: str | None

    @property
    def is_span(self) -> bool:
        return ":" in self.clip_id


class Segment(NamedTuple):
    family: str
    start: int                   # frames [start, end) of the clip
    end: int


class Caption(NamedTuple):
    text: str
    tokens: list[str]            # "word/POS"
    start: float                 # seconds; start = end = 0 means the whole clip
    end: float


def parse_caption_line(line: str, where: str) -> Caption:
    """One `caption#tokens#start#end` line; `where` (file:line) names it in errors."""
    parts = line.rstrip("\n").split("#")
    if len(parts) < 4:
        raise ValueError(f"{where}: expected 'caption#tokens#start#end', got {line.strip()!r}")
    text, tokens, start, end = parts[0].strip(), parts[1].split(), parts[2], parts[3]
    if not text:
        raise ValueError(f"{where}: empty caption")
    try:
        t0, t1 = float(start), float(end)
    except ValueError:
        raise ValueError(f"{where}: start/end must be numbers, got {start!r} and {end!r}") from None
    # T2M reads NaN tags as 0.0 (whole clip); a few HumanML3D lines have them
    t0 = 0.0 if math.isnan(t0) else t0
    t1 = 0.0 if math.isnan(t1) else t1
    return Caption(text, tokens, t0, t1)


def read_captions(path: Path) -> list[Caption]:
    if not path.is_file():
        raise FileNotFoundError(f"caption file missing: {path}")
    lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
    if not lines:
        raise ValueError(f"{path}: no captions")
    return [parse_caption_line(ln, f"{path}:{i + 1}") for i, ln in enumerate(lines)]


def read_features(path: Path, dim: int, dataset: str) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"features file missing: {path}")
    x = np.load(path, allow_pickle=False)
    if x.ndim != 2 or x.shape[1] != dim:
        raise ValueError(f"{path}: expected (T, {dim}) features for {dataset}, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        bad = int(np.argwhere(~np.isfinite(x))[0, 0])
        raise ValueError(f"{path}: contains NaN or inf (first at frame {bad})")
    return x.astype(np.float32, copy=False)


def read_segments(root: Path) -> dict[str, list[Segment]]:
    """clip id -> its segments, from dataset.json's "segments" ({} without the file or the key)."""
    path = root / "dataset.json"
    if not path.is_file():
        return {}
    try:
        table = json.loads(path.read_text(encoding="utf-8")).get("segments") or {}
        return {cid: [Segment(str(s["family"]), int(s["start"]), int(s["end"])) for s in segs]
                for cid, segs in table.items()}
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"{path}: unreadable segments ({e!r})") from None


def read_control_only(root: Path) -> frozenset[str]:
    """The clip ids that train only the control adapter (dataset.json's "control_only": a list of ids; none
    without the file or the key): their captions leave out stops and speed changes that only their root's
    future tells."""
    path = root / "dataset.json"
    if not path.is_file():
        return frozenset()
    ids = json.loads(path.read_text(encoding="utf-8")).get("control_only") or []
    if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
        raise ValueError(f"{path}: \"control_only\" must be a list of clip ids (strings)")
    return frozenset(ids)


def _segment_family(segments: list[Segment], a: int, b: int) -> str | None:
    """The family of the segment covering most of frames [a, b), if one covers at least half of them."""
    best, cover = None, 0
    for s in segments:
        c = min(b, s.end) - max(a, s.start)
        if c > cover:
            best, cover = s.family, c
    return best if 2 * cover >= b - a else None


def read_split(root: Path, split: str) -> list[str]:
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {SPLITS}")
    path = root / f"{split}.txt"
    if not path.is_file():
        raise FileNotFoundError(f"split file missing: {path}")
    ids = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
    if not ids:
        raise ValueError(f"{path}: lists no clips")
    return ids


@dataclass
class MotionDataset:
    root: Path
    split: str
    skeleton: str
    fps: float
    mean: np.ndarray             # (D,) float32
    std: np.ndarray
    items: list[MotionItem] = field(default_factory=list)
    segments: dict[str, list[Segment]] = field(default_factory=dict)  # clip id -> its actions, in order

    @classmethod
    def load(cls, root, split: str = "train", skeleton: str = "humanml3d", min_frames: int | None = None,
             max_frames: int = MAX_FRAMES, control_sequences: bool = False) -> "MotionDataset":
        """Read one split. Keeps items with min_frames <= T < max_frames (T2M's rule; min_frames defaults to
        40 for humanml3d, 24 for kit). The control sequences (`read_control_only`) only with `control_sequences`:
        the control adapter's tokens and captions; the VQ, the classifier and every evaluation leave them out."""
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"dataset folder not found: {root}")
        skel = get_skeleton(skeleton)
        dim = FeatureLayout.for_skeleton(skel).dim
        min_frames = MIN_FRAMES[skel.name] if min_frames is None else int(min_frames)
        mean, std = load_mean_std(root, dim)
        labels_dir = root / "labels"
        skip = frozenset() if control_sequences else read_control_only(root)
        ids = [i for i in read_split(root, split) if i not in skip]
        all_segments = read_segments(root)
        segments = {cid: all_segments[cid] for cid in ids if cid in all_segments}

        items: list[MotionItem] = []
        for clip_id in ids:
            feat_path = root / "new_joint_vecs" / f"{clip_id}.npy"
            if not feat_path.is_file():
                raise FileNotFoundError(f"{root / (split + '.txt')} lists {clip_id!r} but {feat_path} does not exist")
            features = read_features(feat_path, dim, skel.name)
            captions = read_captions(root / "texts" / f"{clip_id}.txt")
            label = None
            label_path = labels_dir / f"{clip_id}.txt"
            if label_path.is_file():
                label = label_path.read_text(encoding="utf-8").strip() or None

            whole, spans = [], {}
            for c in captions:
                if c.start == 0.0 and c.end == 0.0:
                    whole.append(c.text)
                else:
                    span = (int(c.start * skel.fps), int(c.end * skel.fps))
                    spans.setdefault(span, []).append(c.text)
            if whole and min_frames <= len(features) < max_frames:
                items.append(MotionItem(clip_id, features, whole, label))
            for (a, b), texts in spans.items():
                part = features[a:b]
                if min_frames <= len(part) < max_frames:
                    family = _segment_family(segments.get(clip_id, []), a, b)
                    items.append(MotionItem(f"{clip_id}:{a}-{b}", part, texts, family or label))
        if not items:
            raise ValueError(f"{root / (split + '.txt')}: no clip of {len(ids)} has {min_frames} <= frames < "
                             f"{max_frames}")
        return cls(root, split, skel.name, skel.fps, mean, std, items, segments)

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> MotionItem:
        return self.items[i]

    def __iter__(self) -> Iterator[MotionItem]:
        return iter(self.items)

    @property
    def labels(self) -> list[str | None]:
        return [it.label for it in self.items]

    def normalize(self, features: np.ndarray) -> np.ndarray:
        """(features - Mean) / Std, with this dataset's statistics."""
        return normalize(features, self.mean, self.std)

    def denormalize(self, features: np.ndarray) -> np.ndarray:
        return denormalize(features, self.mean, self.std)


def normalize(features: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    _check_stats(features, mean, std)
    return (features - mean) / std


def denormalize(features: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    _check_stats(features, mean, std)
    return features * std + mean


def _check_stats(features, mean, std) -> None:
    d = np.shape(features)[-1]
    if np.shape(mean) != (d,) or np.shape(std) != (d,):
        raise ValueError(f"mean/std must be ({d},) for features (..., {d}), got {np.shape(mean)} and {np.shape(std)}")


def load_mean_std(directory, dim: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read a dataset's Mean.npy and Std.npy (float32, shape (D,)); check D against `dim` if given."""
    directory = Path(directory)
    arrays = []
    for name in ("Mean.npy", "Std.npy"):
        path = directory / name
        if not path.is_file():
            raise FileNotFoundError(f"feature statistics file missing: {path}")
        a = np.load(path, allow_pickle=False)
        if a.ndim != 1 or (dim is not None and a.shape[0] != dim):
            want = f"({dim},)" if dim is not None else "(D,)"
            raise ValueError(f"{path}: expected shape {want}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{path}: contains non-finite values")
        arrays.append(a.astype(np.float32))
    mean, std = arrays
    if mean.shape != std.shape:
        raise ValueError(f"{directory}: Mean.npy {mean.shape} and Std.npy {std.shape} differ in shape")
    if np.any(std <= 0):
        raise ValueError(f"{directory / 'Std.npy'}: has {int(np.sum(std <= 0))} entries <= 0")
    return mean, std
