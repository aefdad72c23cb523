"""A mogo bundle: one folder of ONNX graphs described by `manifest.json` (specified in docs/bundle.md).

`Bundle.load` trusts nothing: it checks the manifest's schema, that every listed file is present with the
recorded size and sha256, and that each graph declares exactly the inputs and outputs the manifest promises.
Every error names the file and the field.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from .decoding import ModelDims
from .features import FeatureLayout
from .skeleton import Skeleton, get_skeleton

SCHEMA = "mogo-bundle"
SCHEMA_VERSION = 1
GRAPHS = ("text_encoder", "step", "lookup", "decoder")
_ONNX_TYPES = {"float32": "tensor(float)", "int64": "tensor(int64)", "float16": "tensor(float16)"}


class BundleError(ValueError):
    pass


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _require(mapping: dict, key: str, where: str, kind=None):
    if not isinstance(mapping, dict) or key not in mapping:
        raise BundleError(f"{where}: missing field {key!r}")
    value = mapping[key]
    if kind is not None and not isinstance(value, kind):
        raise BundleError(f"{where}: field {key!r} should be {getattr(kind, '__name__', kind)}, "
                          f"got {type(value).__name__}")
    return value


@dataclass
class Bundle:
    path: Path
    manifest: dict
    dims: ModelDims
    skeleton: Skeleton
    layout: FeatureLayout

    @classmethod
    def load(cls, path: str | Path, verify_hashes: bool = True, check_graphs: bool = True,
             variants: list[str] | None = None) -> "Bundle":
        """`variants`: check only the files these variants use (plus every non-graph file); None = all.

        A generator that runs int8 then never reads (or hashes) the 90 MB fp32 text encoder: cold start drops
        from ~1.9 s to ~0.7 s on a base bundle (benchmarks/NOTES.md)."""
        path = Path(path)
        mpath = path / "manifest.json"
        if not path.is_dir():
            raise BundleError(f"{path}: bundle folder not found")
        if not mpath.is_file():
            raise BundleError(f"{mpath}: manifest missing (not a mogo bundle, or an export that did not finish)")
        try:
            manifest = json.loads(mpath.read_text())
        except json.JSONDecodeError as e:
            raise BundleError(f"{mpath}: not valid JSON ({e})") from None
        where = str(mpath)
        if manifest.get("schema") != SCHEMA:
            raise BundleError(f"{where}: field 'schema' is {manifest.get('schema')!r}, expected {SCHEMA!r}")
        if manifest.get("schema_version") != SCHEMA_VERSION:
            raise BundleError(f"{where}: field 'schema_version' is {manifest.get('schema_version')!r}; this runtime "
                              f"reads version {SCHEMA_VERSION}")
        files = _require(manifest, "files", where, dict)
        if variants is not None:
            declared = _require(manifest, "variants", where, dict)
            unknown = [v for v in variants if v not in declared]
            if unknown:
                raise BundleError(f"{path}: unknown variant {', '.join(map(repr, unknown))}; this bundle has "
                                  f"{', '.join(declared)}")
            used = {e.get("file") for v in variants for e in declared[v].values() if isinstance(e, dict)}
            files = {n: e for n, e in files.items() if n in used or not n.endswith(".onnx")}
        for name, entry in files.items():
            fpath = path / name
            if not fpath.is_file():
                raise BundleError(f"{fpath}: listed in manifest 'files' but missing")
            size = _require(entry, "bytes", f"{where} files[{name!r}]", int)
            if fpath.stat().st_size != size:
                raise BundleError(f"{fpath}: size {fpath.stat().st_size} bytes, manifest says {size}")
            if verify_hashes:
                digest = sha256_file(fpath)
                expected = _require(entry, "sha256", f"{where} files[{name!r}]", str)
                if digest != expected:
                    raise BundleError(f"{fpath}: sha256 {digest[:12]}... does not match manifest "
                                      f"{expected[:12]}... (file corrupted or replaced)")
        model = _require(manifest, "model", where, dict)
        try:
            dims = ModelDims(**{k: model[k] for k in ("num_levels", "codebook_size", "downsample", "receptive_field",
                                                       "feature_dim", "text_dim", "fps")})
        except KeyError as e:
            raise BundleError(f"{where}: field 'model' lacks {e.args[0]!r}") from None
        skeleton = get_skeleton(_require(_require(manifest, "skeleton", where, dict), "name", f"{where} skeleton"))
        layout = FeatureLayout.for_skeleton(skeleton)
        if layout.dim != dims.feature_dim:
            raise BundleError(f"{where}: model.feature_dim {dims.feature_dim} does not match skeleton "
                              f"{skeleton.name!r} ({layout.dim})")
        bundle = cls(path, manifest, dims, skeleton, layout)
        for variant in _require(manifest, "variants", where, dict):
            for graph in GRAPHS:
                bundle.graph_file(graph, variant)   # every variant names every graph, and the file is listed
        if check_graphs:
            bundle.check_graph_signatures(variants)
        return bundle

    @property
    def variants(self) -> list[str]:
        return list(self.manifest["variants"])

    def graph_file(self, graph: str, variant: str = "fp32") -> Path:
        variants = self.manifest["variants"]
        if variant not in variants:
            raise BundleError(f"{self.path}: unknown variant {variant!r}; this bundle has {sorted(variants)}")
        entry = _require(variants[variant], graph, f"manifest variants[{variant!r}]", dict)
        name = _require(entry, "file", f"manifest variants[{variant!r}][{graph!r}]", str)
        if name not in self.manifest["files"]:
            raise BundleError(f"{self.path}: variants[{variant!r}][{graph!r}] names {name!r}, absent from 'files'")
        return self.path / name

    def file(self, name: str) -> Path:
        if name not in self.manifest["files"]:
            raise BundleError(f"{self.path}: {name!r} is not part of this bundle")
        return self.path / name

    def check_graph_signatures(self, variants: list[str] | None = None) -> None:
        """Each graph file declares the inputs/outputs (names, element types, ranks) that the manifest lists."""
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        seen: set[Path] = set()
        for variant in variants or self.variants:
            for graph in GRAPHS:
                fpath = self.graph_file(graph, variant)
                if fpath in seen:
                    continue
                seen.add(fpath)
                try:
                    sess = ort.InferenceSession(str(fpath), opts, providers=["CPUExecutionProvider"])
                except Exception as e:
                    raise BundleError(f"{fpath}: onnxruntime cannot load it ({e})") from None
                self.check_session(graph, fpath, sess)

    def check_session(self, graph: str, fpath: Path, sess) -> None:
        """An onnxruntime session of `graph` declares the inputs/outputs (names, element types, ranks) that
        the manifest lists. A runtime that opens its sessions anyway checks them here, rather than opening
        every graph twice (check_graph_signatures does, for callers that run nothing)."""
        spec = _require(_require(self.manifest, "graphs", "manifest", dict), graph, "manifest graphs", dict)
        for kind, actual in (("inputs", sess.get_inputs()), ("outputs", sess.get_outputs())):
            declared = _require(spec, kind, f"manifest graphs[{graph!r}]", list)
            got = {a.name: a for a in actual}
            if sorted(got) != sorted(d["name"] for d in declared):
                raise BundleError(f"{fpath}: {kind} are {sorted(got)}, manifest graphs[{graph!r}].{kind} "
                                  f"lists {sorted(d['name'] for d in declared)}")
            for d in declared:
                a = got[d["name"]]
                if a.type != _ONNX_TYPES.get(d["dtype"], d["dtype"]):
                    raise BundleError(f"{fpath}: {kind[:-1]} {d['name']!r} has type {a.type}, manifest "
                                      f"says {d['dtype']}")
                if len(a.shape) != len(d["shape"]):
                    raise BundleError(f"{fpath}: {kind[:-1]} {d['name']!r} has rank {len(a.shape)}, "
                                      f"manifest shape is {d['shape']}")

    def graph_spec(self, graph: str) -> dict:
        return self.manifest["graphs"][graph]

    def total_bytes(self, variant: str = "fp32") -> int:
        names = {self.graph_file(g, variant).name for g in GRAPHS}
        extra = [n for n in self.manifest["files"] if not n.endswith(".onnx")]
        return sum(self.manifest["files"][n]["bytes"] for n in names | set(extra))

