"""The bundle manifest (`manifest.json`), typed: the one home of the contract that docs/bundle.md describes.

The exporter (and the tests' hand-built bundle) build a `Manifest` and write `to_dict()`; everything else reads
one through `Manifest.parse`, which checks every field it reads (type, range, agreement between sections) and
names the file and the field when one is wrong. Nothing else reads manifest.json. The sections are typed in
sections.py; this module puts them together and checks that they agree.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass

from ..checks import Fields, kind, shown
from ..kinematics.features import FeatureLayout
from ..kinematics.skeleton import SKELETONS, Skeleton
from .sampling import SamplingConfig
from .sections import (NORMALIZATION, PER_ROW_INT8, WEIGHT_INT8, BundleError, CacheNames, ControlSpec, GraphFile,
                       GraphSpec, ModelDims, Normalization, OrtFormat, PortableSpec, StreamingSpec, TcaSpec,
                       TextEncoderSpec, parse_files, parse_sampling, parse_variants, present_graphs)

SCHEMA = "mogo-bundle"
# 2: cache-name templates; `normalization` always an object; text_encoder numbers stored as numbers.
SCHEMA_VERSION = 2
# name -> rank of each graph's fixed inputs and outputs (the step graph's cache names come from `cache`)
GRAPH_IO = {"text_encoder": ({"input_ids": 2, "attention_mask": 2}, {"text_embedding": 2}),
            "step": ({"text_embedding": 2, "tokens": 3}, {"logits": 4}),
            "lookup": ({"tokens": 3}, {"latent": 3}),
            "decoder": ({"latent": 3}, {"features": 3})}
DECODER_STATE = ("decoder_state.{}", "next_decoder_state.{}")   # decoder_step's state inputs and outputs, i = 0, 1, ...
ORT_SUFFIX = ".ort"            # graph files in onnxruntime's ORT format (section `ort`)
PORTABLE = "portable"          # the variant whose step graph has a fixed-capacity cache (section `portable`)
INT8_FIXED = "int8_fixed"      # the same step graph in per-row int8: batch-invariant, so a crowd can batch it
COMPACT = "compact"            # the portable variant with int8-stored weights and float32 arithmetic (WEIGHT_INT8)
FIXED_CACHE = (PORTABLE, INT8_FIXED, COMPACT)   # the variants whose step graph is the portable one (in some form)


def _json(v) -> str:
    """Compare JSON values as JSON: true is not 1, 20 is not 20.0."""
    return json.dumps(v, sort_keys=True)


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
    tca: TcaSpec | None = None                  # the caption index of text condition alignment; None: none
    streaming: StreamingSpec | None = None      # None: not trained for endless streams
    portable: PortableSpec | None = None        # the portable variant's step graph; None: no such variant
    ort: OrtFormat | None = None                # ORT-format variants; None: none
    control: ControlSpec | None = None          # the step graph's `control` input; None: the model has none

    @property
    def layout(self) -> FeatureLayout:
        return FeatureLayout.for_skeleton(self.skeleton)

    @property
    def past_names(self) -> list[str]:
        return self.cache.names(self.cache.past, self.model.n_layers)

    @property
    def present_names(self) -> list[str]:
        return self.cache.names(self.cache.present, self.model.n_layers)

    @property
    def graph_names(self) -> tuple[str, ...]:
        """The graphs this bundle has (in every variant): GRAPHS, and the optional ones it has."""
        return present_graphs(self.graphs)

    @property
    def decoder_state(self) -> tuple[tuple[int, int], ...] | None:
        """decoder_step's state, [reach, channels] per input (zeros at a motion's start); None: no decoder_step."""
        spec = self.graphs.get("decoder_step")
        return None if spec is None else tuple(tuple(s.shape[1:]) for s in spec.inputs[1:])

    def graph_file(self, graph: str, variant: str) -> GraphFile:
        if variant not in self.variants:
            raise BundleError(f"unknown variant {variant!r}; this bundle has {', '.join(self.variants)}")
        return self.variants[variant][graph]

    def source_variant(self, variant: str) -> str:
        """The variant an ORT-format variant was converted from; any other variant is its own source."""
        return self.ort.variants.get(variant, variant) if self.ort else variant

    def fixed_cache(self, variant: str) -> bool:
        """Whether the variant's step graph is the portable one, its per-row int8 or its compact form
        (fixed-capacity cache, `position` input)."""
        return self.source_variant(variant) in FIXED_CACHE

    def row_by_row(self, variant: str) -> set[str]:
        """The variant's graphs that run one row per call: those quantized per tensor, whose numbers for a row
        would depend on the other rows of its batch (docs/bundle.md, step 2 of the loop)."""
        return {g for g, e in self.variants[variant].items() if e.quantized and not e.quantization.batch_invariant}

    def graph_spec(self, graph: str, variant: str) -> GraphSpec:
        """The inputs and outputs a variant's graph has: the portable step's differ from `graphs.step`."""
        return self.portable.step if graph == "step" and self.fixed_cache(variant) else self.graphs[graph]

    def to_dict(self) -> dict:
        return {
            "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "producer": self.producer or {},
            "model": self.model.to_dict(), "skeleton": self.skeleton.to_dict(),
            "features": self.layout.to_dict(), "normalization": {"mode": NORMALIZATION, **asdict(self.normalization)},
            "text_encoder": asdict(self.text_encoder), "sampling_defaults": self.sampling_defaults.to_dict(),
            "cache": asdict(self.cache), **({"tca": asdict(self.tca)} if self.tca else {}),
            **({"streaming": asdict(self.streaming)} if self.streaming else {}),
            **({"control": asdict(self.control)} if self.control else {}),
            "graphs": {g: asdict(s) for g, s in self.graphs.items()},          # tuples are written as lists
            **({"portable": asdict(self.portable)} if self.portable else {}),
            **({"ort": asdict(self.ort)} if self.ort else {}),
            "variants": {v: {g: e.to_dict() for g, e in gs.items()} for v, gs in self.variants.items()},
            "files": {n: {"bytes": b, "sha256": h} for n, (b, h) in self.files.items()},
        }

    @classmethod
    def parse(cls, data, where: str) -> "Manifest":
        """Check and type a manifest read from JSON; `where` (the file) starts every error message."""
        f = Fields(data, where, error=BundleError)
        if f.get("schema", None) != SCHEMA:
            f.fail("schema", f"is {f.get('schema', None)!r}, expected {SCHEMA!r} (not a mogo bundle)")
        if f.get("schema_version", None) != SCHEMA_VERSION:
            f.fail("schema_version", f"is {f.get('schema_version', None)!r}; this runtime reads version "
                                     f"{SCHEMA_VERSION} (re-export the bundle with `mogo-export export`)")
        producer = f.get("producer", {})
        if not isinstance(producer, dict):
            f.fail("producer", f"expected an object, got {kind(producer)}")
        model = ModelDims.parse(f.sub("model"))
        streaming = None if f.get("streaming", None) is None else StreamingSpec.parse(f.sub("streaming"), model)
        optional = {"tca": lambda s: TcaSpec.parse(s, model), "ort": OrtFormat.parse, "control": ControlSpec.parse,
                    "portable": lambda s: PortableSpec.parse(s, model, streaming)}
        return cls(model=model, skeleton=_parse_skeleton(f.sub("skeleton"), f.sub("features"), model),
                   normalization=Normalization.parse(f.sub("normalization"), model),
                   text_encoder=TextEncoderSpec.parse(f.sub("text_encoder")),
                   sampling_defaults=parse_sampling(f.sub("sampling_defaults")),
                   cache=CacheNames.parse(f.sub("cache")), producer=producer, files=parse_files(f.sub("files")),
                   graphs={g: GraphSpec.parse(f.sub("graphs").sub(g)) for g in present_graphs(f.get("graphs"))},
                   variants=parse_variants(f.sub("variants")), streaming=streaming,
                   **{k: None if f.get(k, None) is None else parse(f.sub(k)) for k, parse in optional.items()}
                   ).checked(where)

    def checked(self, where: str) -> "Manifest":
        """Agreement between sections: files named by variants are listed, the step graph's I/O is the cache."""
        for v, graphs in self.variants.items():
            if set(graphs) != set(self.graph_names):
                odd = sorted(set(graphs) ^ set(self.graph_names))[0]
                raise BundleError(f"{where}: field variants.{v}.{odd}: " + (
                    "the bundle's 'graphs' section does not describe this graph" if odd in graphs else
                    "missing: every variant has each graph the 'graphs' section describes"))
            for g, entry in graphs.items():
                if entry.file not in self.files:
                    raise BundleError(f"{where}: field variants.{v}.{g}.file: {entry.file!r} is not in 'files'")
        for name in (self.text_encoder.tokenizer, *([self.tca.file] if self.tca else []),
                     *([self.ort.required_operators] if self.ort else [])):
            if name not in self.files:
                raise BundleError(f"{where}: {name!r} is named by the manifest but not listed in 'files'")
        step, m = self.graphs["step"], self.model
        for graph, (inputs, outputs) in GRAPH_IO.items():
            cache = graph == "step"
            control = {"control": 3} if cache and self.control else {}
            for kind_, specs, want in (("inputs", self.graphs[graph].inputs, {**inputs, **control, **dict.fromkeys(
                    self.past_names if cache else (), 4)}), ("outputs", self.graphs[graph].outputs, {
                    **outputs, **dict.fromkeys(self.present_names if cache else (), 4)})):
                got = {s.name: len(s.shape) for s in specs}
                if list(got) != list(want) or got != want:
                    raise BundleError(f"{where}: field graphs.{graph}.{kind_}: names and ranks are {shown(got, 300)}, "
                                      f"expected {shown(want, 300)}" + (" (n_layers and the cache templates)"
                                                                         if cache else ""))
        if self.control and (step.inputs[2].dtype, step.inputs[2].shape[2]) != ("float32", self.control.dim):
            raise BundleError(f"{where}: field graphs.step.inputs[2]: 'control' is {step.inputs[2].dtype} "
                              f"{list(step.inputs[2].shape)}, expected float32 [batch, steps, {self.control.dim}] "
                              f"(control.dim)")
        logits = step.outputs[0].shape
        if len(logits) != 4 or logits[2:] != (m.num_levels, m.codebook_size + 1):
            raise BundleError(f"{where}: field graphs.step.outputs[0].shape: {list(logits)} should end in "
                              f"[{m.num_levels}, {m.codebook_size + 1}] (levels, codes + END)")
        self._check_decoder_step(where)
        self._check_fixed_cache(where)
        self._check_ort(where)
        return self

    def _check_decoder_step(self, where: str) -> None:
        """decoder_step: latent, then its state inputs decoder_state.0, 1, ...; features, then next_decoder_state.i
        of the same fixed shapes [batch, reach, channels]: what a consumer allocates, zeros, for a new motion."""
        spec = self.graphs.get("decoder_step")
        if spec is None:
            return
        n = len(spec.inputs) - 1
        names = {"inputs": ["latent", *(DECODER_STATE[0].format(i) for i in range(n))],
                 "outputs": ["features", *(DECODER_STATE[1].format(i) for i in range(n))]}
        for kind_, want in names.items():
            got = [s.name for s in getattr(spec, kind_)]
            if got != want or n < 1:
                raise BundleError(f"{where}: field graphs.decoder_step.{kind_}: names are {shown(got, 300)}, "
                                  f"expected {shown(want, 300)} (at least one state)")
        m = self.model
        if [len(s.shape) for s in spec.inputs] != [3] * (n + 1) or spec.inputs[0].shape[2] != m.latent_dim:
            raise BundleError(f"{where}: field graphs.decoder_step.inputs: latent is [batch, tokens, "
                              f"{m.latent_dim}] and each state [batch, reach, channels]")
        for i, (s_in, s_out) in enumerate(zip(spec.inputs[1:], spec.outputs[1:])):
            dims = s_in.shape[1:]
            if (s_in.dtype != "float32" or not all(isinstance(d, int) and 1 <= d <= 4096 for d in dims)
                    or s_out.shape != s_in.shape or s_out.dtype != s_in.dtype):
                raise BundleError(f"{where}: field graphs.decoder_step.inputs[{i + 1}]: {s_in.name!r} is "
                                  f"{s_in.dtype} {list(s_in.shape)} and its output {list(s_out.shape)}; expected "
                                  f"float32 [batch, reach, channels] with fixed sizes 1..4096, the same both ways")
        features = spec.outputs[0]
        if len(features.shape) != 3 or features.shape[2] != m.feature_dim:
            raise BundleError(f"{where}: field graphs.decoder_step.outputs[0]: features is {list(features.shape)}, "
                              f"expected [batch, frames, {m.feature_dim}]")

    def _check_fixed_cache(self, where: str) -> None:
        """The portable section and the portable variant come together; the step's I/O is the fixed cache."""
        if (self.portable is None) != (PORTABLE not in self.variants):
            raise BundleError(f"{where}: field portable: " + (
                "the bundle has no 'portable' variant for it to describe" if self.portable else
                "missing: variant 'portable' needs this section (its step graph's inputs, outputs and capacity)"))
        for v in (INT8_FIXED, COMPACT):
            if v in self.variants and PORTABLE not in self.variants:
                raise BundleError(f"{where}: field variants.{v}: comes with variant {PORTABLE!r}, whose section "
                                  f"'portable' describes its step graph")
        if self.portable is None:
            return
        quantized = [g for g, e in self.variants[PORTABLE].items() if e.quantized]
        if quantized:
            raise BundleError(f"{where}: field variants.{PORTABLE}.{quantized[0]}.quantization: the portable "
                              f"variant is fp32 only (no int8 operators)")
        step = self.variants[INT8_FIXED]["step"] if INT8_FIXED in self.variants else None
        if step is not None and not (step.quantized and step.quantization.method == PER_ROW_INT8):
            raise BundleError(f"{where}: field variants.{INT8_FIXED}.step.quantization: its step graph is the "
                              f"portable step quantized per row (method {PER_ROW_INT8!r}), got "
                              f"{step.quantization.to_dict() if step.quantization else None!r}")
        for g, e in self.variants.get(COMPACT, {}).items():
            if not (e.quantized and e.quantization.method == WEIGHT_INT8):
                raise BundleError(f"{where}: field variants.{COMPACT}.{g}.quantization: every graph of the compact "
                                  f"variant stores its weights in int8 (method {WEIGHT_INT8!r}), got "
                                  f"{e.quantization.to_dict() if e.quantization else None!r}")
        m, spec, cap = self.model, self.portable.step, self.portable.capacity
        cache = [m.num_levels * m.n_heads, cap, m.head_dim]
        control = {"control": ("float32", [1, self.control.dim])} if self.control else {}
        want = {"inputs": {"text_embedding": ("float32", [m.text_dim]), "tokens": ("int64", [1, m.num_levels]),
                           **control, "position": ("int64", []), **dict.fromkeys(self.past_names, ("float32", cache))},
                "outputs": {"logits": ("float32", [1, m.num_levels, m.codebook_size + 1]),
                            **dict.fromkeys(self.present_names, ("float32", cache))}}
        for kind_, expected in want.items():
            got = {s.name: s for s in getattr(spec, kind_)}
            if list(got) != list(expected):
                raise BundleError(f"{where}: field portable.step.{kind_}: names are {list(got)}, expected "
                                  f"{list(expected)} (n_layers and the cache templates)")
            for i, (name, (dtype, dims)) in enumerate(expected.items()):
                s = got[name]
                # every dim but the batch is fixed: a consumer allocates the cache once, from these numbers
                if s.dtype != dtype or list(s.shape[1:]) != dims:
                    raise BundleError(f"{where}: field portable.step.{kind_}[{i}]: {name!r} is {s.dtype} "
                                      f"[{', '.join(map(str, s.shape))}], expected {dtype} "
                                      f"[{', '.join(map(str, ['batch', *dims]))}]")

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
