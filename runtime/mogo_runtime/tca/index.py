"""The caption index: a bundle's training captions and their text embeddings (`captions.npz`, format
"mogo-caption-index" version 1), and reading it from a bundle (manifest section `tca`).

The exporter writes it with `CaptionIndex.save` (mogo_export/export/caption_index.py) and the runtime reads it
with `CaptionIndex.load`: one definition of the format. On disk the rows are int8 with one scale per row
(~dim + 4 bytes a caption) or float16; in memory float32 unit rows.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

INDEX_FORMAT = "mogo-caption-index"
INDEX_VERSION = 1


def quantize_rows(x: np.ndarray, dtype: str = "int8") -> tuple[np.ndarray, np.ndarray | None]:
    """(N, D) float -> stored rows: int8 with a per-row scale (symmetric, max |x| -> 127), or float16 (scale None)."""
    x = np.asarray(x, np.float32)
    if dtype == "float16":
        return x.astype(np.float16), None
    if dtype != "int8":
        raise ValueError(f"caption index dtype must be 'int8' or 'float16', got {dtype!r}")
    scale = np.abs(x).max(axis=1) / 127.0
    scale = np.where(scale > 0, scale, 1.0).astype(np.float32)
    q = np.clip(np.rint(x / scale[:, None]), -127, 127).astype(np.int8)
    return q, scale


def unit(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


@dataclass
class CaptionIndex:
    """Training captions and their unit embeddings (float32 in memory; int8 + per-row scale or float16 on disk)."""
    captions: list[str]
    embeddings: np.ndarray              # (N, dim) float32, unit rows
    labels: list[str] | None = None     # action family per caption ("seq:a+b" for two-action clips), if known
    encoder: str = ""
    dtype: str = "float32"

    def __post_init__(self):
        self.embeddings = unit(np.asarray(self.embeddings, np.float32))
        if self.embeddings.ndim != 2 or len(self.embeddings) != len(self.captions):
            raise ValueError(f"caption index: {len(self.captions)} captions but embeddings of shape "
                             f"{self.embeddings.shape}")
        if self.labels is not None and len(self.labels) != len(self.captions):
            raise ValueError(f"caption index: {len(self.labels)} labels for {len(self.captions)} captions")

    def __len__(self) -> int:
        return len(self.captions)

    @property
    def dim(self) -> int:
        return int(self.embeddings.shape[1])

    def save(self, path: str | Path, dtype: str = "int8") -> dict:
        """Write `path` (.npz, no pickles); -> the facts a manifest records about it."""
        path = Path(path)
        rows, scale = quantize_rows(self.embeddings, dtype)
        arrays = {"format": np.array(INDEX_FORMAT), "version": np.array(INDEX_VERSION, np.int64),
                  "encoder": np.array(self.encoder), "captions": np.array(self.captions, dtype=np.str_),
                  "embeddings": rows}
        if scale is not None:
            arrays["scales"] = scale
        if self.labels is not None:
            arrays["labels"] = np.array([lb or "" for lb in self.labels], dtype=np.str_)
        with open(path, "wb") as f:
            np.savez_compressed(f, **arrays)
        return {"file": path.name, "count": len(self), "dim": self.dim, "dtype": dtype, "encoder": self.encoder,
                "labels": self.labels is not None}

    @classmethod
    def load(cls, path: str | Path) -> "CaptionIndex":
        path = Path(path)
        try:
            z = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a readable caption index ({e})") from None
        with z:
            if "format" not in z.files or str(z["format"]) != INDEX_FORMAT:
                raise ValueError(f"{path}: not a {INDEX_FORMAT} file (arrays: {sorted(z.files)})")
            if int(z["version"]) != INDEX_VERSION:
                raise ValueError(f"{path}: caption index version {int(z['version'])}, this runtime reads "
                                 f"{INDEX_VERSION}")
            rows = z["embeddings"]                  # the dtype names how they are stored: int8, float16, ...
            emb = rows.astype(np.float32)
            if rows.dtype == np.int8:
                if "scales" not in z.files:
                    raise ValueError(f"{path}: int8 embeddings without 'scales'")
                emb = emb * z["scales"][:, None]
            labels = [lb or None for lb in z["labels"].tolist()] if "labels" in z.files else None
            return cls(z["captions"].tolist(), emb, labels, str(z["encoder"]), str(rows.dtype))

    def search(self, queries: np.ndarray, k: int, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(Q, dim) queries -> (indices (Q, k), cosine similarities (Q, k)), best first; `mask` (N,) restricts rows."""
        q = unit(np.atleast_2d(np.asarray(queries, np.float32)))
        if q.shape[1] != self.dim:
            raise ValueError(f"query embeddings have {q.shape[1]} values, the caption index {self.dim}")
        sims = q @ self.embeddings.T                                           # (Q, N)
        if mask is not None:
            sims = np.where(mask[None, :], sims, -np.inf)
        k = min(k, int(mask.sum()) if mask is not None else len(self))
        idx = np.argsort(-sims, axis=1, kind="stable")[:, :k]
        return idx, np.take_along_axis(sims, idx, axis=1)


def load_bundle_index(bundle) -> tuple[CaptionIndex | None, dict]:
    """The caption index and `tca` manifest section of a bundle (a mogo_runtime.Bundle), or (None, {})."""
    from ..bundle import BundleError

    section = dict(bundle.manifest.tca or {})
    if not section:
        return None, {}
    path = bundle.file(section["file"])         # the manifest's parser checked that the file is listed
    index = CaptionIndex.load(path)
    te = bundle.manifest.text_encoder.name
    if index.encoder and te and index.encoder != te:
        raise BundleError(f"{path}: embeddings from text encoder {index.encoder!r}, the bundle's is {te!r}; "
                          f"re-export the bundle")
    if index.dim != bundle.dims.text_dim:
        raise BundleError(f"{path}: {index.dim}-dim embeddings, model.text_dim is {bundle.dims.text_dim}")
    return index, section
