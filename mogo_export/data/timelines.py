"""Clips read whole with their timed captions (HumanML3D's `caption#tokens#start#end`): what streaming training
learns prompt switches from.

`MotionDataset` (dataset.py) follows T2M and turns every timed caption into an item of its own, dropping clips of
200 frames or more; a character that changes action mid-stream needs the opposite view: the whole clip, and where
each captioned segment starts and stops in it. Real HumanML3D has a few such clips; the procedural dataset's long
sequences (20-60 s, 3-8 actions) are made of them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mogo_runtime.kinematics.features import FeatureLayout
from mogo_runtime.kinematics.skeleton import get_skeleton

from .dataset import read_captions, read_control_only, read_features, read_split


@dataclass
class Segment:
    first: int                   # frames [first, stop) of the clip
    stop: int
    captions: list[str]


@dataclass
class Timeline:
    clip_id: str
    features: np.ndarray         # (T, D) float32, not normalised
    segments: list[Segment]      # in time order


def read_timelines(root: str | Path, split: str, skeleton: str = "humanml3d",
                   control_sequences: bool = False) -> list[Timeline]:
    """The clips of `split` with at least one timed caption, whole; segments sorted by start. The control sequences
    only with `control_sequences` (as MotionDataset.load)."""
    root, skel = Path(root), get_skeleton(skeleton)
    dim = FeatureLayout.for_skeleton(skel).dim
    out = []
    skip = frozenset() if control_sequences else read_control_only(root)
    for clip_id in (i for i in read_split(root, split) if i not in skip):
        spans: dict[tuple[int, int], list[str]] = {}
        for c in read_captions(root / "texts" / f"{clip_id}.txt"):
            if c.end > c.start:
                spans.setdefault((int(c.start * skel.fps), int(c.end * skel.fps)), []).append(c.text)
        if spans:
            features = read_features(root / "new_joint_vecs" / f"{clip_id}.npy", dim, skel.name)
            segments = [Segment(a, min(b, len(features)), texts) for (a, b), texts in sorted(spans.items())
                        if a < min(b, len(features))]
            out.append(Timeline(clip_id, features, segments))
    return out
