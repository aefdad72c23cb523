"""The caption index a bundle ships for text condition alignment (TCA, `mogo_runtime.tca`).

    from mogo_export.models.text_encoder import get_text_encoder
    from mogo_export.export.caption_index import build_caption_index
    facts = build_caption_index("data/procedural", get_text_encoder("all-MiniLM-L6-v2"), "bundle/captions.npz")

Writes the unique TRAINING captions, their embeddings by the bundle's own text encoder (int8 with a per-row
scale by default: ~dim + 4 bytes a caption; or float16) and each caption's action label when the dataset has
labels, as one `.npz` that loads with allow_pickle=False. The format is `mogo_runtime.tca.CaptionIndex`'s, so
writer and reader share one definition. Returns the facts for the manifest's `tca` section.
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import torch

from mogo_runtime.bundle.sections import TcaSpec
from mogo_runtime.tca import CaptionIndex

from ..data.dataset import MotionDataset


def training_captions(dataset_root: str | Path, split: str = "train") -> tuple[list[str], list[str | None]]:
    """Unique captions of a split in first-seen order, and for each the label it most often comes with."""
    ds = MotionDataset.load(dataset_root, split)
    labels: dict[str, Counter] = {}
    for item in ds.items:
        for c in item.captions:
            labels.setdefault(c.strip(), Counter())[item.label] += 1
    captions = list(labels)
    return captions, [labels[c].most_common(1)[0][0] for c in captions]


def build_caption_index(dataset_root: str | Path, text_encoder, out_path: str | Path, dtype: str = "int8",
                        split: str = "train", batch_size: int = 256) -> dict:
    """Embed the unique `split` captions of `dataset_root` with `text_encoder` (a mogo_export TextEncoder) and
    write them to `out_path`; -> {file, count, dim, dtype, encoder, labels, split, bytes}."""
    captions, labels = training_captions(dataset_root, split)
    rows = []
    with torch.no_grad():
        for i in range(0, len(captions), batch_size):
            rows.append(text_encoder.encode(captions[i:i + batch_size]).float().cpu().numpy())
    emb = np.concatenate(rows).astype(np.float32)
    has_labels = any(lb is not None for lb in labels)
    index = CaptionIndex(captions, emb, labels if has_labels else None, text_encoder.name)
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    facts = index.save(out_path, dtype)
    return {**facts, "split": split, "bytes": out_path.stat().st_size}


def tca_manifest_section(facts: dict) -> TcaSpec:
    """The manifest's `tca` section: the index's facts, and the offline aligner's defaults (docs/tca.md)."""
    return TcaSpec(file=facts["file"], count=facts["count"], dim=facts["dim"], dtype=facts["dtype"],
                   encoder=facts["encoder"], labels=facts["labels"], split=facts.get("split", "train"))