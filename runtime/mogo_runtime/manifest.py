"""The bundle manifest (`manifest.json`), typed: the one home of the contract that docs/bundle.md describes.

The exporter (and the tests' hand-built bundle) build a `Manifest` and write `to_dict()`; everything else reads
one through `Manifest.parse`, which checks every field it reads (type, range, agreement between sections) and
names the file and the field when one is wrong. Nothing else reads manifest.json.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, fields
from pathlib import PurePosixPath

from .features import FeatureLayout
from .fixed_cache import (INT8_FIXED, PER_ROW_INT8, PORTABLE, PORTABLE_OPSET,  # noqa: F401  (contract)
                          check_fixed_cache, required_capacity)
from .jsonfields import BundleError, Fields, kind
from .sampling import SamplingConfig
from .skeleton import SKELETONS, Skeleton

SCHEMA = "mogo-bundle"
# 2: cache-name templates; `normalization` always an object; text_encoder numbers stored as numbers.
SCHEMA_VERSION = 2
GRAPHS = ("text_encoder", "step", "lookup", "decoder")
# name -> rank of each graph's fixed inputs and outputs (the step graph's cache names come from `cache`)
GRAPH_IO = {"text_encoder": ({"input_ids": 2, "attention_mask": 2}, {"text_embedding": 2}),
            "step": ({"text_embedding": 2, "tokens": 3}, {"logits": 4}),
            "lookup": ({"tokens": 3}, {"latent": 3}),
            "decoder": ({"latent": 3}, {"features": 3})}
DTYPES = {"float32": "tensor(float)", "int64": "tensor(int64)", "float16": "tensor(float16)"}  # -> onnxruntime
ORT_SUFFIX = ".ort"            # graph files in onnxruntime's ORT format (section `ort`)
NORMALIZATION = "decoder-output-denormalised"   # decoder.onnx multiplies by Std and adds Mean itself
_SHA256 = re.compile(r"[0-9a-f]{64}")


def _json(v) -> str:
    """Compare JSON values as JSON: true is not 1, 20 is not 20.0."""
    return json.dumps(v, sort_keys=True)


class SpecialTokens:
    """Token ids past the codebook, for a class with a `codebook_size` field: codes are 0..K-1, END = K ends the
    motion, BOS = K+1 is the prompt prefix in a level's slot, PAD = K+2 pads training batches."""

    codebook_size: int

    @property
    def end_id(self) -> int:
        return self.codebook_size

    @property
    def bos_id(self) -> int:
        return self.codebook_size + 1

    @property
    def pad_id(self) -> int:
        return self.codebook_size + 2


@dataclass(frozen=True)
class ModelDims(SpecialTokens):
    """The manifest's `model` section: the network's sizes, as the loop and a consumer need them."""

    num_levels: int          # L: one token per level and time step
    codebook_size: int       # K (see SpecialTokens)
    n_layers: int            # transformer layers: one cached key and value each
    n_heads: int
    head_dim: int
    text_dim: int            # width of the text embedding the step graph takes
    max_rel_dist: int        # relative positions are clipped here (Transformer-XL)
    downsample: int          # motion frames per token
    fps: float
    receptive_field: int     # tokens of history (besides its own) that a decoded frame depends on
    feature_dim: int         # 263 for HumanML3D features
    latent_dim: int          # width of the decoder's input
    max_tokens: int          # the longest motion the model was trained for, in tokens

    @property
    def max_seconds(self) -> float:
        return self.max_tokens * self.downsample / self.fps

    def to_dict(self) -> dict:
        return {**asdict(self), "d_model": self.n_heads * self.head_dim, "end_id": self.end_id,
                "bos_id": self.bos_id, "pad_id": self.pad_id}

    @classmethod
    def parse(cls, f: Fields) -> "ModelDims":
        dims = cls(**{x.name: f.num(x.name, 0, 1000) if x.name == "fps" else
                      f.int(x.name, lo=0 if x.name == "receptive_field" else 1) for x in fields(cls)})
        for key, want in (("end_id", dims.end_id), ("bos_id", dims.bos_id), ("pad_id", dims.pad_id),
                          ("d_model", dims.n_heads * dims.head_dim)):
            if f.get(key, want) != want:
                f.fail(key, f"is {f.get(key)!r}, the other sizes imply {want}")
        return dims


@dataclass(frozen=True)
class TensorSpec:
    name: str
    dtype: str                       # a key of DTYPES
    shape: tuple                     # ints, or strings for symbolic dims

    @classmethod
    def parse(cls, f: Fields) -> "TensorSpec":
        dtype, shape = f.str("dtype"), f.list("shape")
        if dtype not in DTYPES:
            f.fail("dtype", f"expected one of {sorted(DTYPES)}, got {dtype!r}")
        if len(shape) > 8 or not all(isinstance(d, str) or (isinstance(d, int) and not isinstance(d, bool)
                                                              and d >= 1) for d in shape):
            f.fail("shape", f"expected at most 8 dims, each a name or an integer >= 1, got {shape!r}")
        return cls(f.str("name"), dtype, tuple(shape))


@dataclass(frozen=True)
class GraphSpec:
    inputs: tuple[TensorSpec, ...]
    outputs: tuple[TensorSpec, ...]

    @classmethod
    def parse(cls, f: Fields) -> "GraphSpec":
        io = {}
        for kind in ("inputs", "outputs"):
            specs = [TensorSpec.parse(Fields(d, f.where, f"{f.path}.{kind}[{i}]")) for i, d in enumerate(f.list(kind))]
            names = [s.name for s in specs]
            if not specs or len(set(names)) != len(names):
                f.fail(kind, f"expected a non-empty list of distinct names, got {names}")
            io[kind] = tuple(specs)
        return cls(**io)


@dataclass(frozen=True)
class GraphFile:
    """One graph of one variant: its file, and the quantization applied (None for fp32)."""

    file: str
    quantization: dict | None = None

    @property
    def quantized(self) -> bool:
        return bool(self.quantization)


@dataclass(frozen=True)
class CacheNames:
    """I/O name templates of the step graph's KV cache (onnxruntime-genai style): `present.*` outputs of one
    step are fed back as the `past_key_values.*` inputs of the next, layer by layer, key then value."""

    past: str = "past_key_values.{layer}.{kind}"
    present: str = "present.{layer}.{kind}"

    def names(self, template: str, n_layers: int) -> list[str]:
        return [template.format(layer=i, kind=kind) for i in range(n_layers) for kind in ("key", "value")]


@dataclass(frozen=True)
class TextEncoderSpec:
    name: str
    tokenizer: str                   # the bundle file holding the tokenizer (HuggingFace `tokenizers` JSON)
    max_length: int                  # tokens incl. special tokens; longer prompts are cut
    pooling: str = "mean"


@dataclass(frozen=True)
class Normalization:                 # mode NORMALIZATION: the decoder applies them itself; listed for reference
    mean: tuple[float, ...]          # (feature_dim,)
    std: tuple[float, ...]


@dataclass(frozen=True)
class StreamingSpec:
    """The context policy of endless streams the model was trained for (docs/bundle.md, "Endless streams"): the
    current prompt's prefix plus at most window + refresh motion tokens, rebuilt from the last `window` tokens
    when full or when the prompt changes."""

    window: int
    refresh: int


@dataclass(frozen=True)
class PortableSpec:
    """The `portable` variant's step graph (docs/bundle.md, "The portable variant"): one time step per call over
    a KV cache of `capacity` slots per layer, written at `position`; every dim fixed but the batch."""

    capacity: int                    # cache slots; at least required_capacity(model, streaming)
    opset: int                       # ai.onnx opset of the variant's graphs (at most PORTABLE_OPSET)
    step: GraphSpec                  # inputs text_embedding, tokens, position, the past names; outputs logits,
                                     # the present names (shapes in docs/bundle.md)


@dataclass(frozen=True)
class OrtFormat:
    """Variants converted to onnxruntime's ORT format (`*.ort` graphs) for a minimal onnxruntime build, and the
    operator list such a build is configured with (`--include_ops_by_config`)."""

    required_operators: str          # the bundle file listing the operators of every .ort graph
    variants: dict[str, str]         # ORT variant -> the variant it was converted from
    onnxruntime: str                 # the version that converted them; a minimal build should be this or newer


@dataclass(frozen=True)
class Manifest:
    model: ModelDims
    skeleton: Skeleton
    normalization: Normalization
    text_encoder: TextEncoderSpec
    sampling_defaults: SamplingConfig
    graphs: dict[str, GraphSpec]
    variants: dict[str, dict[str, GraphFile]]
    files: dict[str, tuple[int, str]]           # name -> (bytes, sha256)
    cache: CacheNames = CacheNames()
    producer: dict | None = None                # informative only: who wrote the bundle, from what
    tca: dict | None = None                     # the caption index section, read by mogo_runtime.tca
    streaming: StreamingSpec | None = None      # None: not trained for endless streams
    portable: PortableSpec | None = None        # the portable variant's step graph; None: no such variant
    ort: OrtFormat | None = None                # ORT-format variants; None: none

    @property
    def layout(self) -> FeatureLayout:
        return FeatureLayout.for_skeleton(self.skeleton)

    @property
    def past_names(self) -> list[str]:
        return self.cache.names(self.cache.past, self.model.n_layers)

    @property
    def present_names(self) -> list[str]:
        return self.cache.names(self.cache.present, self.model.n_layers)

    def graph_file(self, graph: str, variant: str) -> GraphFile:
        if variant not in self.variants:
            raise BundleError(f"unknown variant {variant!r}; this bundle has {', '.join(self.variants)}")
        return self.variants[variant][graph]

    def source_variant(self, variant: str) -> str:
        """The variant an ORT-format variant was converted from; any other variant is its own source."""
        return self.ort.variants.get(variant, variant) if self.ort else variant

    def fixed_cache(self, variant: str) -> bool:
        """Whether the variant's step graph is the portable one or its per-row int8 form (fixed-capacity cache,
        `position` input)."""
        return self.source_variant(variant) in (PORTABLE, INT8_FIXED)

    def graph_spec(self, graph: str, variant: str) -> GraphSpec:
        """The inputs and outputs a variant's graph has: the portable step's differ from `graphs.step`."""
        return self.portable.step if graph == "step" and self.fixed_cache(variant) else self.graphs[graph]

    def to_dict(self) -> dict:
        return {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "producer": self.producer or {},
            "model": self.model.to_dict(), "skeleton": self.skeleton.to_dict(),
            "features": self.layout.to_dict(),
            "normalization": {"mode": NORMALIZATION, **asdict(self.normalization)},
            "text_encoder": asdict(self.text_encoder), "sampling_defaults": self.sampling_defaults.to_dict(),
            "cache": asdict(self.cache), **({"tca": self.tca} if self.tca else {}),
            **({"streaming": asdict(self.streaming)} if self.streaming else {}),
            "graphs": {g: asdict(s) for g, s in self.graphs.items()},          # tuples are written as lists
            **({"portable": asdict(self.portable)} if self.portable else {}),
            **({"ort": asdict(self.ort)} if self.ort else {}),
            "variants": {v: {g: asdict(e) for g, e in gs.items()} for v, gs in self.variants.items()},
            "files": {n: {"bytes": b, "sha256": h} for n, (b, h) in self.files.items()},
        }

    @classmethod
    def parse(cls, data, where: str) -> "Manifest":
        """Check and type a manifest read from JSON; `where` (the file) starts every error message."""
        f = Fields(data, where)
        if f.get("schema", None) != SCHEMA:
            f.fail("schema", f"is {f.get('schema', None)!r}, expected {SCHEMA!r} (not a mogo bundle)")
        if f.get("schema_version", None) != SCHEMA_VERSION:
            f.fail("schema_version", f"is {f.get('schema_version', None)!r}; this runtime reads version "
                                     f"{SCHEMA_VERSION} (re-export the bundle with `mogo-export export`)")
        producer = f.get("producer", {})
        if not isinstance(producer, dict):
            f.fail("producer", f"expected an object, got {kind(producer)}")
        model = ModelDims.parse(f.sub("model"))
        skeleton = _parse_skeleton(f.sub("skeleton"), f.sub("features"), model)
        streaming = None if f.get("streaming", None) is None else _parse_streaming(f.sub("streaming"), model)
        return cls(model=model, skeleton=skeleton, normalization=_parse_normalization(f.sub("normalization"), model),
                   text_encoder=_parse_text_encoder(f.sub("text_encoder")),
                   sampling_defaults=_parse_sampling(f.sub("sampling_defaults")),
                   cache=_parse_cache(f.sub("cache")), producer=producer, files=_parse_files(f.sub("files")),
                   graphs={g: GraphSpec.parse(f.sub("graphs").sub(g)) for g in GRAPHS},
                   variants=_parse_variants(f.sub("variants")),
                   tca=None if f.get("tca", None) is None else f.sub("tca").obj,
                   streaming=streaming,
                   portable=None if f.get("portable", None) is None else _parse_portable(f.sub("portable"), model,
                                                                                          streaming),
                   ort=None if f.get("ort", None) is None else _parse_ort(f.sub("ort"))).checked(where)

    def checked(self, where: str) -> "Manifest":
        """Agreement between sections: files named by variants are listed, the step graph's I/O is the cache."""
        for v, graphs in self.variants.items():
            for g, entry in graphs.items():
                if entry.file not in self.files:
                    raise BundleError(f"{where}: field variants.{v}.{g}.file: {entry.file!r} is not in 'files'")
        for name in (self.text_encoder.tokenizer, *([self.tca.get("file")] if self.tca else []),
                     *([self.ort.required_operators] if self.ort else [])):
            if name not in self.files:
                raise BundleError(f"{where}: {name!r} is named by the manifest but not listed in 'files'")
        step, m = self.graphs["step"], self.model
        for graph, (inputs, outputs) in GRAPH_IO.items():
            cache = graph == "step"
            for kind, specs, want in (("inputs", self.graphs[graph].inputs, {**inputs, **dict.fromkeys(
                    self.past_names if cache else (), 4)}), ("outputs", self.graphs[graph].outputs, {
                    **outputs, **dict.fromkeys(self.present_names if cache else (), 4)})):
                got = {s.name: len(s.shape) for s in specs}
                if list(got) != list(want) or got != want:
                    raise BundleError(f"{where}: field graphs.{graph}.{kind}: names and ranks are {got}, expected "
                                      f"{want}" + (" (n_layers and the cache templates)" if cache else ""))
        logits = step.outputs[0].shape
        if len(logits) != 4 or logits[2:] != (m.num_levels, m.codebook_size + 1):
            raise BundleError(f"{where}: field graphs.step.outputs[0].shape: {list(logits)} should end in "
                              f"[{m.num_levels}, {m.codebook_size + 1}] (levels, codes + END)")
        check_fixed_cache(self, where)
        self._check_ort(where)
        return self

    def _check_ort(self, where: str) -> None:
        """ORT-format variants: each listed with its source, every file an .ort, quantized as its source."""
        ort = self.ort.variants if self.ort else {}
        for v, graphs in self.variants.items():
            in_ort = [e.file.endswith(ORT_SUFFIX) for e in graphs.values()]
            if any(in_ort) != (v in ort) or any(in_ort) != all(in_ort):
                raise BundleError(f"{where}: field variants.{v}: " + (
                    f"an ORT-format variant has only {ORT_SUFFIX} files" if v in ort else
                    f"{ORT_SUFFIX} files belong to variants listed in ort.variants with their source"))
        for v, source in ort.items():
            if v not in self.variants or source not in self.variants or source in ort:
                raise BundleError(f"{where}: field ort.variants.{v}: {v!r} converted from {source!r}: both must be "
                                  f"variants, the source not itself in ORT format")
            for g, e in self.variants[v].items():
                if e.quantization != self.variants[source][g].quantization:
                    raise BundleError(f"{where}: field variants.{v}.{g}.quantization: differs from variant "
                                      f"{source!r}, which it was converted from")


def _parse_skeleton(f: Fields, features: Fields, model: ModelDims) -> Skeleton:
    """The skeleton must be one this runtime knows, stored exactly (as Skeleton.to_dict writes it): the joints
    code relies on its tables."""
    name = f.str("name")
    if name not in SKELETONS:
        f.fail("name", f"unknown skeleton {name!r}; this runtime knows {sorted(SKELETONS)}")
    skeleton = SKELETONS[name]
    for key, want in skeleton.to_dict().items():
        if _json(f.get(key)) != _json(want):
            f.fail(key, f"differs from the {name!r} skeleton this runtime knows ({_json(want)[:60]}...)")
    layout = FeatureLayout.for_skeleton(skeleton)
    if _json(features.obj) != _json(layout.to_dict()):
        features.fail("", f"differs from the feature layout of the {name!r} skeleton this runtime knows")
    if layout.dim != model.feature_dim:
        f.fail("name", f"{name!r} has {layout.dim} features per frame, model.feature_dim is {model.feature_dim}")
    return skeleton


def _parse_normalization(f: Fields, model: ModelDims) -> Normalization:
    if f.str("mode") != NORMALIZATION:
        f.fail("mode", f"expected {NORMALIZATION!r}, got {f.get('mode')!r}")
    stats = {}
    for key in ("mean", "std"):
        v = f.list(key)
        if len(v) != model.feature_dim or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                  and math.isfinite(x) for x in v):
            f.fail(key, f"expected {model.feature_dim} finite numbers")
        if key == "std" and min(v) <= 0:   # features are scaled by it: 0 flattens a feature, < 0 mirrors it
            f.fail(key, f"every value must be > 0, got {min(v)!r} at index {v.index(min(v))}")
        stats[key] = tuple(float(x) for x in v)
    return Normalization(**stats)


def _parse_text_encoder(f: Fields) -> TextEncoderSpec:
    if f.str("pooling", "mean") != "mean":
        f.fail("pooling", f"only mean pooling is supported, got {f.get('pooling')!r}")
    return TextEncoderSpec(name=f.str("name"), tokenizer=f.str("tokenizer"), max_length=f.int("max_length", 2, 65536))


def _parse_sampling(f: Fields) -> SamplingConfig:
    unknown = set(f.obj) - {x.name for x in fields(SamplingConfig)}
    if unknown:
        f.fail(sorted(unknown)[0], "unknown sampling setting")
    try:
        return SamplingConfig(**f.obj)
    except (TypeError, ValueError) as e:
        raise BundleError(f"{f.where}: field {f.path}: {e}") from None


def _parse_cache(f: Fields) -> CacheNames:
    cache = CacheNames(past=f.str("past"), present=f.str("present"))
    for key in ("past", "present"):
        template = getattr(cache, key)
        try:
            names = cache.names(template, 2)
        except (KeyError, IndexError, ValueError):
            names = []
        if len(set(names)) != 4 or template.format(layer=0, kind="key") == template:
            f.fail(key, f"a name template with {{layer}} and {{kind}} fields, got {template!r}")
    return cache


def _parse_files(f: Fields) -> dict[str, tuple[int, str]]:
    files = {}
    for name in f.obj:
        entry = f.sub(name)
        p = PurePosixPath(name)
        # bundle files are plain names inside the bundle folder: no directories, no way out of it
        if not name or p.name != name or name in (".", "..") or "\\" in name or "\0" in name:
            f.fail(name, "a bundle file must be a plain file name inside the bundle folder")
        digest = entry.str("sha256")
        if not _SHA256.fullmatch(digest):
            entry.fail("sha256", f"expected 64 lowercase hex digits, got {digest!r}")
        files[name] = (entry.int("bytes", 0, 2 ** 40), digest)
    if not files:
        f.fail("", "lists no files")
    return files


def _parse_variants(f: Fields) -> dict[str, dict[str, GraphFile]]:
    if "fp32" not in f.obj:
        f.fail("fp32", "missing: every bundle has the fp32 variant")
    variants = {}
    for v in f.obj:
        graphs = f.sub(v)
        entries = {}
        for g in GRAPHS:
            e = graphs.sub(g)
            q = e.get("quantization", None)
            if q is not None and not isinstance(q, dict):
                e.fail("quantization", f"expected an object or null, got {kind(q)}")
            entries[g] = GraphFile(file=e.str("file"), quantization=q or None)
        variants[v] = entries
    return variants


def _parse_portable(f: Fields, model: ModelDims, streaming: StreamingSpec | None) -> PortableSpec:
    need = required_capacity(model, streaming)
    capacity = f.get("capacity")
    if isinstance(capacity, int) and not isinstance(capacity, bool) and 1 <= capacity < need:
        f.fail("capacity", f"is {capacity}; the generation loop can hold {need} steps "
                           f"(max(max_tokens + 1, 1 + streaming window + refresh))")
    return PortableSpec(capacity=f.int("capacity", need), opset=f.int("opset", 7, PORTABLE_OPSET),
                        step=GraphSpec.parse(f.sub("step")))


def _parse_ort(f: Fields) -> OrtFormat:
    variants = f.sub("variants")
    if not variants.obj:
        f.fail("variants", "expected at least one ORT-format variant")
    return OrtFormat(required_operators=f.str("required_operators"),
                     variants={v: variants.str(v) for v in variants.obj}, onnxruntime=f.str("onnxruntime"))


def _parse_streaming(f: Fields, model: ModelDims) -> StreamingSpec:
    spec = StreamingSpec(window=f.int("window", 1), refresh=f.int("refresh", 1))
    if spec.window + spec.refresh > model.max_rel_dist:   # as trained: every distance to the prefix is distinct
        f.fail("refresh", f"window + refresh is {spec.window + spec.refresh}, more than model.max_rel_dist "
                          f"{model.max_rel_dist}")
    return spec
