"""A mogo bundle: one folder of ONNX graphs described by `manifest.json` (docs/bundle.md; typed in manifest.py).

    bundle = Bundle.load("bundles/base")                   # everything checked: every file hashed, every graph
                                                           # opened and its inputs and outputs held to the manifest
    bundle = Bundle.load("bundles/base", variant="int8")   # what MotionGenerator does: only what the variant uses

A bundle is untrusted: the manifest is parsed and checked field by field, every listed file must be a plain file
directly in the folder (no link, nothing outside) of its recorded size, and every byte the runtime uses is checked
against the manifest's sha256 as it is read (`read_verified`), never read again by path: a graph is opened from the
bytes that were checked, so what runs is what was verified. A graph must be self-contained: one whose tensors point
to external-data files is refused (onnxruntime would read them from the model's folder, unlisted and unhashed).
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from ..checks import read_file
from .manifest import Manifest
from .onnxfile import ProtobufError, external_data
from .sections import DTYPES, GRAPHS, OPTIONAL_GRAPHS, BundleError, ModelDims

MANIFEST_MAX_BYTES = 16 << 20   # a real manifest is ~30 KB; refuse to parse anything huge
GRAPH_MAX_BYTES = (2 << 30) - 1  # protobuf's limit: onnxruntime cannot parse a larger self-contained ONNX file


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_manifest(folder: str | Path) -> Manifest:
    """A bundle folder's manifest, parsed and checked (no other file is opened)."""
    path = Path(folder)
    mpath = path / "manifest.json"
    if not path.is_dir():
        raise BundleError(f"{path}: bundle folder not found")
    if not (mpath.exists() or mpath.is_symlink()):
        raise BundleError(f"{mpath}: manifest missing (not a mogo bundle, or an export that did not finish)")
    try:
        data = json.loads(read_file(mpath, MANIFEST_MAX_BYTES, links=False, error=BundleError))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise BundleError(f"{mpath}: not valid JSON ({type(e).__name__}: {e})") from None
    return Manifest.parse(data, str(mpath))


@dataclass
class Bundle:
    path: Path
    manifest: Manifest

    @property
    def dims(self) -> ModelDims:
        return self.manifest.model

    @property
    def skeleton(self):
        return self.manifest.skeleton

    @property
    def variants(self) -> list[str]:
        return list(self.manifest.variants)

    @classmethod
    def load(cls, path: str | Path, variant: str | None = None, graphs: tuple[str, ...] | None = None) -> "Bundle":
        """The bundle in folder `path`. Without `variant` every listed file is checked now: hashed, and each graph
        opened and held to the manifest's inputs and outputs. With `variant`, only that variant's files must be
        there, at their sizes; their bytes are checked as they are read, each once (an int8 generator never reads
        the 90 MB fp32 text encoder: cold start ~1.9 s -> ~0.2 s on base, benchmarks/NOTES.md). `graphs`: of that
        variant, the graphs used (a decode-only client ships the lookup and the decoders alone); None: all."""
        bundle = cls(Path(path), read_manifest(path))
        if variant is not None and variant not in bundle.manifest.variants:
            raise BundleError(f"{path}: unknown variant {variant!r}; this bundle has {', '.join(bundle.variants)}")
        unknown = sorted(set(graphs or ()) - set(GRAPHS + OPTIONAL_GRAPHS))
        if unknown:
            raise ValueError(f"unknown graphs {unknown}; a bundle's graphs are {', '.join(GRAPHS + OPTIONAL_GRAPHS)}")
        graphs = bundle.manifest.graph_names if graphs is None else graphs
        graph_files = {e.file for gs in bundle.manifest.variants.values() for e in gs.values()}
        used = graph_files if variant is None else {e.file for g, e in bundle.manifest.variants[variant].items()
                                                    if g in graphs}
        extras = variant is None or set(GRAPHS) <= set(graphs)     # the tokenizer, the TCA index: prompts' files
        for name in bundle.manifest.files:
            if name in used or (extras and name not in graph_files):
                if variant is None and name not in graph_files:   # graphs are hashed as their sessions open
                    bundle.read_verified(name)
                else:
                    bundle._listed_path(name)
        if variant is None:
            bundle.check_graph_signatures()
        return bundle

    def read_verified(self, name: str) -> bytes:
        """A listed file's bytes, checked against the manifest's size and sha256 after reading (so the bytes used
        are the bytes checked); an ONNX graph must also be self-contained (no external data)."""
        size, digest = self.manifest.files[name]
        fpath = self._listed_path(name)
        data = read_file(fpath, size, links=False, error=BundleError)      # a link swapped in since is refused
        if len(data) != size:                      # the size was checked a moment ago: the file is being changed
            raise BundleError(f"{fpath}: size {len(data)} bytes when read, manifest says {size}")
        if hashlib.sha256(data).hexdigest() != digest:
            raise BundleError(f"{fpath}: sha256 does not match the manifest (file corrupted or replaced)")
        if name.endswith(".onnx"):
            try:
                outside = external_data(data)
            except ProtobufError as e:
                raise BundleError(f"{fpath}: not an ONNX file ({e})") from None
            if outside:
                raise BundleError(f"{fpath}: keeps tensors in external-data files ({', '.join(map(repr, outside))}); "
                                  f"bundle graphs must be self-contained")
        return data

    def _listed_path(self, name: str) -> Path:
        """The path of listed file `name`: a regular file directly in the bundle folder, of the recorded size."""
        size, _ = self.manifest.files[name]
        fpath = self.path / name
        if fpath.is_symlink() or (fpath.exists() and not fpath.is_file()):
            raise BundleError(f"{fpath}: not a regular file (bundle files cannot be links or folders)")
        if not fpath.is_file():
            raise BundleError(f"{fpath}: listed in manifest 'files' but missing")
        if fpath.resolve().parent != self.path.resolve():
            raise BundleError(f"{fpath}: not directly inside the bundle folder {self.path}")
        if fpath.stat().st_size != size:
            raise BundleError(f"{fpath}: size {fpath.stat().st_size} bytes, manifest says {size}")
        if name.endswith(".onnx") and size > GRAPH_MAX_BYTES:   # refused before a byte is read or hashed
            raise BundleError(f"{fpath}: {size} bytes; an ONNX graph without external data is at most "
                              f"{GRAPH_MAX_BYTES} bytes")
        return fpath

    def graph_path(self, graph: str, variant: str = "fp32") -> Path:
        """Where a variant's graph file is, for messages (its bytes come from `read_verified`)."""
        return self.path / self.manifest.graph_file(graph, variant).file

    def check_graph_signatures(self, variants: list[str] | None = None) -> None:
        """Each graph file declares the inputs/outputs (names, element types, ranks) that the manifest lists."""
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        opts.log_severity_level = 4    # our own errors name the file; onnxruntime's lines would only add to them
        seen: set[str] = set()
        for variant in variants or self.variants:
            for graph in self.manifest.graph_names:
                name = self.manifest.graph_file(graph, variant).file
                if name not in seen:
                    seen.add(name)
                    self.check_session(graph, self.session(graph, variant, opts), variant)

    def session(self, graph: str, variant: str, options):
        """An onnxruntime CPU session of `variant`'s `graph`, from the verified bytes of its file."""
        import onnxruntime as ort

        data = self.read_verified(self.manifest.graph_file(graph, variant).file)
        try:
            return ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
        except Exception as e:   # onnxruntime raises its own types for a file it cannot parse
            raise BundleError(f"{self.graph_path(graph, variant)}: onnxruntime cannot load it ({e})") from None

    def check_session(self, graph: str, sess, variant: str = "fp32") -> None:
        """An onnxruntime session of `variant`'s `graph` declares the inputs/outputs (names, element types, ranks,
        fixed sizes) that the manifest lists. A runtime that opens its sessions anyway checks them here, rather
        than opening every graph twice (check_graph_signatures does, for callers that run nothing)."""
        fpath = self.graph_path(graph, variant)
        spec = self.manifest.graph_spec(graph, variant)
        where = "portable.step" if spec is not self.manifest.graphs[graph] else f"graphs.{graph}"
        for kind, actual in (("inputs", sess.get_inputs()), ("outputs", sess.get_outputs())):
            declared = getattr(spec, kind)
            got = {a.name: a for a in actual}
            if sorted(got) != sorted(d.name for d in declared):
                raise BundleError(f"{fpath}: {kind} are {sorted(got)}, manifest {where}.{kind} "
                                  f"lists {sorted(d.name for d in declared)}")
            for d in declared:
                a = got[d.name]
                if a.type != DTYPES[d.dtype]:
                    raise BundleError(f"{fpath}: {kind[:-1]} {d.name!r} has type {a.type}, manifest says {d.dtype}")
                # a fixed size in the manifest is what a consumer allocates (the portable cache): the graph's own
                if len(a.shape) != len(d.shape) or any(isinstance(want, int) and have != want
                                                       for want, have in zip(d.shape, a.shape)):
                    raise BundleError(f"{fpath}: {kind[:-1]} {d.name!r} has shape {list(a.shape)}, "
                                      f"manifest {where} says {list(d.shape)}")
        meta = sess.get_modelmeta().custom_metadata_map
        for key, value in self.dims.to_dict().items():   # facts a graph carries must be the manifest's
            if f"mogo.{key}" in meta and meta[f"mogo.{key}"] != str(value):
                raise BundleError(f"{fpath}: metadata mogo.{key} is {meta[f'mogo.{key}']!r}, manifest model.{key} "
                                  f"is {value!r}")

    def total_bytes(self, variant: str = "fp32") -> int:
        names = {self.manifest.graph_file(g, variant).file for g in self.manifest.graph_names}
        graph_files = {e.file for gs in self.manifest.variants.values() for e in gs.values()}
        extra = [n for n in self.manifest.files if n not in graph_files]
        return sum(self.manifest.files[n][0] for n in names | set(extra))
