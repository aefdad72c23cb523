"""The caption index: a bundle's training captions and their text embeddings (`captions.npz`, format
"mogo-caption-index" version 1), and reading it from a bundle (manifest section `tca`).

The exporter writes it with `CaptionIndex.save` (mogo_export/export/caption_index.py) and the runtime reads it
with `CaptionIndex.load`: one definition of the format. On disk the rows are int8 with one scale per row
(~dim + 4 bytes a caption) or float16; in memory float32 unit rows.
"""
from __future__ import annotations

import io
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bundle.sections import BundleError, TcaSpec
from ..kinematics.quaternion import unit

INDEX_FORMAT = "mogo-caption-index"
INDEX_VERSION = 1

# Bounds read from the zip directory and the .npy headers before anything is decompressed: np.load inflates a
# whole member, so a 382 KB file of zeros declaring 1,000,000 x 384 embeddings took 8.9 s and 3.4 GB to load (now
# refused in under 1 ms, from its zip directory). HumanML3D's training split has about 70k captions of at most a
# few hundred characters; 384 or 768 values a row.
MAX_CAPTIONS = 500_000
MAX_DIM = 4096
MAX_TEXT = 1000                 # characters of one caption, label, format or encoder name
MAX_VALUES = 2 ** 26            # embedding values (256 MiB as float32 in memory)
MAX_BYTES = 256 * 2 ** 20       # all members, decompressed
# member -> (numpy dtype kinds it may have, in words, its dimensions: "N" one per caption, "D" the embedding width)
MEMBERS = {"format": ("U", "text", ()), "version": ("iu", "an integer", ()), "encoder": ("U", "text", ()),
           "captions": ("U", "text", ("N",)), "embeddings": ("if", "int8 or float", ("N", "D")),
           "scales": ("f", "float", ("N",)), "labels": ("U", "text", ("N",))}


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
    def load(cls, source: str | Path | bytes, path: str | Path | None = None) -> "CaptionIndex":
        """Read a caption index from a file or its bytes (`path` names them in errors); BundleError for anything that
        is not one, or one past the bounds."""
        path = path if path is not None else source
        z = read_npz(io.BytesIO(source) if isinstance(source, bytes) else source, path)
        if "format" not in z or str(z["format"]) != INDEX_FORMAT:
            raise BundleError(f"{path}: not a {INDEX_FORMAT} file (arrays: {sorted(z)})")
        for name in ("version", "encoder", "captions", "embeddings"):
            if name not in z:
                raise BundleError(f"{path}: caption index without {name!r}")
        if int(z["version"]) != INDEX_VERSION:
            raise BundleError(f"{path}: caption index version {int(z['version'])}, this runtime reads {INDEX_VERSION}")
        rows = z["embeddings"]                  # the dtype names how they are stored: int8, float16, ...
        emb = rows.astype(np.float32)
        if rows.dtype == np.int8:
            if "scales" not in z:
                raise BundleError(f"{path}: int8 embeddings without 'scales'")
            emb = emb * z["scales"][:, None]
        labels = [lb or None for lb in z["labels"].tolist()] if "labels" in z else None
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


def read_npz(source, path) -> dict[str, np.ndarray]:
    """The arrays of a caption index `.npz` (a file or a file object), each member's size, dtype and shape checked
    against MEMBERS and the bounds above before it is decompressed; BundleError naming `path` for a file that is not
    a readable index."""
    try:
        with zipfile.ZipFile(source) as zf:
            infos = {i.filename[:-4]: i for i in zf.infolist() if i.filename.endswith(".npy")}
            infos = {k: i for k, i in infos.items() if k in MEMBERS}     # others (a later version's) are not read
            total = sum(i.file_size for i in infos.values())
            if total > MAX_BYTES:
                raise BundleError(f"{path}: caption index arrays of {total:,} bytes decompressed; at most "
                                  f"{MAX_BYTES:,} are read")
            sizes: dict[str, int] = {}
            for name, info in infos.items():
                with zf.open(info) as f:
                    _check_header(path, name, info.file_size, *_read_header(f), sizes)
            arrays = {}
            for name, info in infos.items():
                with zf.open(info) as f:
                    arrays[name] = np.lib.format.read_array(f, allow_pickle=False)
            return arrays
    except BundleError:
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError) as e:
        # RuntimeError: an encrypted member; NotImplementedError: an unknown compression method
        raise BundleError(f"{path}: not a readable caption index ({type(e).__name__}: {e})") from None


def _read_header(f) -> tuple[tuple, np.dtype, int]:
    """(shape, dtype, bytes of the header) of the .npy file open in `f`."""
    version = np.lib.format.read_magic(f)
    if version not in ((1, 0), (2, 0)):
        raise ValueError(f"unsupported .npy format version {version}")
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read(f)
    return shape, dtype, f.tell()


def _check_header(path: Path, name: str, file_size: int, shape: tuple, dtype: np.dtype, header: int,
                  sizes: dict[str, int]) -> None:
    """Refuse member `name` unless its dtype and shape are the format's and within the bounds; `sizes` collects
    N and D across members, which must agree."""
    kinds, words, dims = MEMBERS[name]
    where = f"{path}: caption index array {name!r}"
    if dtype.kind not in kinds or dtype.hasobject or (dtype.kind == "U" and dtype.itemsize > 4 * MAX_TEXT):
        raise BundleError(f"{where} has dtype {dtype.str}; expected {words}"
                          + (f" of at most {MAX_TEXT} characters" if kinds == "U" else ""))
    if len(shape) != len(dims):
        raise BundleError(f"{where} has shape {shape}, expected {len(dims)} dimension(s)")
    for d, n in zip(dims, shape):
        most = {"N": MAX_CAPTIONS, "D": MAX_DIM}[d]
        if not 0 < n <= most:
            raise BundleError(f"{where} has shape {shape}; {d} must be in [1, {most:,}]")
        if sizes.setdefault(d, n) != n:
            raise BundleError(f"{where} has shape {shape}, other arrays have {d} = {sizes[d]}")
    count = int(np.prod(shape, dtype=np.int64))
    if name == "embeddings" and count > MAX_VALUES:
        raise BundleError(f"{where} has {count:,} values; at most {MAX_VALUES:,} are read")
    if header + count * dtype.itemsize != file_size:
        # a header promising more than the member holds would be read past its end (or, lying, allocated)
        raise BundleError(f"{where}: its header says {count * dtype.itemsize:,} bytes of data, the member holds "
                          f"{file_size - header:,}")


def load_bundle_index(bundle) -> tuple[CaptionIndex | None, TcaSpec | None]:
    """The caption index and `tca` manifest section of a bundle (a mogo_runtime.Bundle), or (None, None). The index
    is read from the bytes whose sha256 was checked."""
    spec = bundle.manifest.tca
    if spec is None:
        return None, None
    path = bundle.path / spec.file
    index = CaptionIndex.load(bundle.read_verified(spec.file), path)
    te = bundle.manifest.text_encoder.name
    if index.encoder and te and index.encoder != te:
        raise BundleError(f"{path}: embeddings from text encoder {index.encoder!r}, the bundle's is {te!r}; "
                          f"re-export the bundle")
    if index.dim != bundle.dims.text_dim:
        raise BundleError(f"{path}: {index.dim}-dim embeddings, model.text_dim is {bundle.dims.text_dim}")
    return index, spec
