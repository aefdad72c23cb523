"""The manifest's sections, typed: one dataclass per section, each with the parser that checks every field it reads
and names the file and the field when one is wrong (docs/bundle.md, "manifest.json"). `manifest.py` puts them
together and checks that they agree."""
from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, fields
from pathlib import PurePosixPath

from ..checks import NAME_MAX, Fields, kind, shown
from .sampling import SamplingConfig

GRAPHS = ("text_encoder", "step", "lookup", "decoder")     # every bundle's
# graphs a bundle may have, in every variant or none: the decoder with its causal state explicit (docs/bundle.md)
OPTIONAL_GRAPHS = ("decoder_step",)
DECODING_GRAPHS = ("lookup", "decoder", "decoder_step")    # tokens -> frames: all a decode-only client opens


def present_graphs(obj) -> tuple[str, ...]:
    """The graphs a `graphs` (or variant) object names: GRAPHS, and the optional ones it has."""
    return GRAPHS + tuple(g for g in OPTIONAL_GRAPHS if isinstance(obj, dict) and g in obj)

DTYPES = {"float32": "tensor(float)", "int64": "tensor(int64)", "float16": "tensor(float16)"}  # -> onnxruntime
PER_ROW_INT8 = "mogo.per_row_dynamic"   # int8 with one activation scale per row (export/rowquant.py): batchable
WEIGHT_INT8 = "mogo.weight_only_int8"   # int8 weights turned back to float32 in the graph, float32 arithmetic
BATCH_INVARIANT = (PER_ROW_INT8, WEIGHT_INT8)   # methods whose rows never depend on the rest of their batch
PORTABLE_OPSET = 17            # the portable variant's graphs' opset: this or lower (LayerNormalization's first)
NORMALIZATION = "decoder-output-denormalised"   # decoder.onnx multiplies by Std and adds Mean itself
_SHA256 = re.compile(r"[0-9a-f]{64}")
MODEL_MAX = {"num_levels": 64, "n_layers": 1024, "n_heads": 1024, "head_dim": 65536, "text_dim": 65536,
             "codebook_size": 2 ** 24, "feature_dim": 65536, "latent_dim": 65536}


class BundleError(ValueError):
    """A bundle that cannot be used: the message names the file and the field."""


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
        # sizes a reader allocates or names things by (a cache name per layer) are bounded: 2**31 layers would make
        # billions of names before any check could fail
        dims = cls(**{x.name: f.num(x.name, 0, 1000) if x.name == "fps" else
                      f.int(x.name, lo=0 if x.name == "receptive_field" else 1, hi=MODEL_MAX.get(x.name, 2 ** 31))
                      for x in fields(cls)})
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
        io = {kind_: tuple(TensorSpec.parse(Fields(d, f.where, f"{f.path}.{kind_}[{i}]", f.error))
                           for i, d in enumerate(f.list(kind_))) for kind_ in ("inputs", "outputs")}
        for kind_, specs in io.items():
            names = [s.name for s in specs]
            if not specs or len(set(names)) != len(names):
                f.fail(kind_, f"expected a non-empty list of distinct names, got {names}")
        return cls(**io)


@dataclass(frozen=True)
class Quantization:
    """How a variant's graph was quantized: `method` is what a reader acts on (the BATCH_INVARIANT methods run
    batched, any other method one row per call: docs/bundle.md); the exporter's other options are kept as written,
    for people."""

    method: str
    options: dict

    @property
    def batch_invariant(self) -> bool:
        return self.method in BATCH_INVARIANT

    def to_dict(self) -> dict:
        return {"method": self.method, **self.options}

    @classmethod
    def parse(cls, f: Fields) -> "Quantization":
        return cls(f.str("method"), {k: v for k, v in f.obj.items() if k != "method"})


@dataclass(frozen=True)
class GraphFile:
    """One graph of one variant: its file, and the quantization applied (None for fp32)."""

    file: str
    quantization: Quantization | None = None

    @property
    def quantized(self) -> bool:
        return self.quantization is not None

    def to_dict(self) -> dict:
        return {"file": self.file, "quantization": self.quantization.to_dict() if self.quantization else None}


@dataclass(frozen=True)
class CacheNames:
    """I/O name templates of the step graph's KV cache (onnxruntime-genai style): `present.*` outputs of one
    step are fed back as the `past_key_values.*` inputs of the next, layer by layer, key then value."""

    past: str = "past_key_values.{layer}.{kind}"
    present: str = "present.{layer}.{kind}"

    def names(self, template: str, n_layers: int) -> list[str]:
        return [template.format(layer=i, kind=kind) for i in range(n_layers) for kind in ("key", "value")]

    @classmethod
    def parse(cls, f: Fields) -> "CacheNames":
        cache = cls(past=f.str("past"), present=f.str("present"))
        for key in ("past", "present"):
            template = getattr(cache, key)
            try:
                names = cache.names(template, 2)
            except (KeyError, IndexError, ValueError):
                names = []
            if len(set(names)) != 4 or template.format(layer=0, kind="key") == template:
                f.fail(key, f"a name template with {{layer}} and {{kind}} fields, got {template!r}")
        return cache


@dataclass(frozen=True)
class TextEncoderSpec:
    name: str
    tokenizer: str                   # the bundle file holding the tokenizer (HuggingFace `tokenizers` JSON)
    max_length: int                  # tokens incl. special tokens; longer prompts are cut
    pooling: str = "mean"

    @classmethod
    def parse(cls, f: Fields) -> "TextEncoderSpec":
        if f.str("pooling", "mean") != "mean":
            f.fail("pooling", f"only mean pooling is supported, got {f.get('pooling')!r}")
        return cls(name=f.str("name"), tokenizer=f.str("tokenizer"), max_length=f.int("max_length", 2, 65536))


@dataclass(frozen=True)
class Normalization:                 # mode NORMALIZATION: the decoder applies them itself; listed for reference
    mean: tuple[float, ...]          # (feature_dim,)
    std: tuple[float, ...]

    @classmethod
    def parse(cls, f: Fields, model: ModelDims) -> "Normalization":
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
        return cls(**stats)


@dataclass(frozen=True)
class StreamingSpec:
    """The context policy of endless streams the model was trained for (docs/bundle.md, "Endless streams"): the
    current prompt's prefix plus at most window + refresh motion tokens, rebuilt from the last `window` tokens
    when full or when the prompt changes."""

    window: int
    refresh: int

    @classmethod
    def parse(cls, f: Fields, model: ModelDims) -> "StreamingSpec":
        spec = cls(window=f.int("window", 1), refresh=f.int("refresh", 1))
        if spec.window + spec.refresh > model.max_rel_dist:   # as trained: every distance to the prefix is distinct
            f.fail("refresh", f"window + refresh is {spec.window + spec.refresh}, more than model.max_rel_dist "
                              f"{model.max_rel_dist}")
        return spec


@dataclass(frozen=True)
class ControlSpec:
    """Where the character should go, as the step graph's `control` input reads it (docs/bundle.md, "Control";
    mogo_runtime/control/vector.py): the wanted root poses of the next `horizon` tokens, in the root's frame."""

    horizon: int             # tokens of wanted trajectory per step
    dim: int                 # the control input's width: 1 + 4 * horizon

    @classmethod
    def parse(cls, f: Fields) -> "ControlSpec":
        spec = cls(horizon=f.int("horizon", 1, 64), dim=f.int("dim", 1, 1 + 4 * 64))
        if spec.dim != 1 + 4 * spec.horizon:
            f.fail("dim", f"is {spec.dim}; a horizon of {spec.horizon} tokens makes {1 + 4 * spec.horizon} "
                          f"(present, then x, z, sin, cos per token)")
        return spec


def required_capacity(model: ModelDims, streaming: StreamingSpec | None) -> int:
    """Cache slots the generation loop can fill: a clip is BOS plus at most max_tokens - 1 fed tokens (the +1
    spares a consumer that also feeds the token picked at the last step), an endless stream's context is BOS
    plus at most window + refresh motion tokens (docs/bundle.md)."""
    return max(model.max_tokens + 1, 1 + streaming.window + streaming.refresh if streaming else 0)


@dataclass(frozen=True)
class PortableSpec:
    """The `portable` variant's step graph (docs/bundle.md, "The portable variant"): one time step per call over
    a KV cache of `capacity` slots per layer, written at `position`; every dim fixed but the batch."""

    capacity: int                    # cache slots; at least required_capacity(model, streaming)
    opset: int                       # ai.onnx opset of the variant's graphs (at most PORTABLE_OPSET)
    step: GraphSpec                  # inputs text_embedding, tokens, [control], position, the past names;
                                     # outputs logits, the present names (shapes in docs/bundle.md)

    @classmethod
    def parse(cls, f: Fields, model: ModelDims, streaming: StreamingSpec | None) -> "PortableSpec":
        need = required_capacity(model, streaming)
        capacity = f.get("capacity")
        if isinstance(capacity, int) and not isinstance(capacity, bool) and 1 <= capacity < need:
            f.fail("capacity", f"is {capacity}; the generation loop can hold {need} steps "
                               f"(max(max_tokens + 1, 1 + streaming window + refresh))")
        return cls(capacity=f.int("capacity", need), opset=f.int("opset", 7, PORTABLE_OPSET),
                   step=GraphSpec.parse(f.sub("step")))


@dataclass(frozen=True)
class OrtFormat:
    """Variants converted to onnxruntime's ORT format (`*.ort` graphs) for a minimal onnxruntime build, and the
    operator list such a build is configured with (`--include_ops_by_config`)."""

    required_operators: str          # the bundle file listing the operators of every .ort graph
    variants: dict[str, str]         # ORT variant -> the variant it was converted from
    onnxruntime: str                 # the version that converted them; a minimal build should be this or newer

    @classmethod
    def parse(cls, f: Fields) -> "OrtFormat":
        variants = f.sub("variants")
        if not variants.obj:
            f.fail("variants", "expected at least one ORT-format variant")
        return cls(required_operators=f.str("required_operators"),
                   variants={v: variants.str(v) for v in variants.obj}, onnxruntime=f.str("onnxruntime"))


@dataclass(frozen=True)
class TcaSpec:
    """The caption index that text condition alignment reads (docs/tca.md): its file and what it holds, and the
    offline aligner's settings. Keys older exports wrote and nothing reads (method, top_k, temperature) are
    ignored."""

    file: str
    count: int                       # captions
    dim: int                         # embedding width: model.text_dim
    dtype: str                       # how rows are stored: "int8" (with a scale per row) or "float16"
    encoder: str                     # the text encoder that embedded them: text_encoder.name
    labels: bool                     # whether each caption's action label is stored too
    split: str = "train"             # the data split the captions come from
    lexical_weight: float = 0.05     # how much direction words count in the aligner's re-ranking
    split_margin: float = 0.02       # how much better two clauses must match than the whole to split a prompt

    @classmethod
    def parse(cls, f: Fields, model: ModelDims) -> "TcaSpec":
        for key in ("lexical_weight", "split_margin"):
            v = f.get(key, getattr(cls, key))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 1:
                f.fail(key, f"expected a number in [0, 1], got {v!r}")
        if f.get("dtype") not in ("int8", "float16"):
            f.fail("dtype", f"expected 'int8' or 'float16', got {f.get('dtype')!r}")
        if f.get("dim") != model.text_dim:
            f.fail("dim", f"is {f.get('dim')!r}, model.text_dim is {model.text_dim}")
        if not isinstance(f.get("labels"), bool):
            f.fail("labels", f"expected true or false, got {f.get('labels')!r}")
        return cls(file=f.str("file"), count=f.int("count", 1), dim=model.text_dim, dtype=f.get("dtype"),
                   encoder=f.str("encoder"), labels=f.get("labels"), split=f.str("split", "train"),
                   lexical_weight=float(f.get("lexical_weight", cls.lexical_weight)),
                   split_margin=float(f.get("split_margin", cls.split_margin)))


def parse_sampling(f: Fields) -> SamplingConfig:
    unknown = set(f.obj) - {x.name for x in fields(SamplingConfig)}
    if unknown:
        f.fail(sorted(unknown)[0], "unknown sampling setting")
    try:
        return SamplingConfig(**f.obj)
    except (TypeError, ValueError) as e:
        raise f.error(f"{f.where}: field {f.path}: {e}") from None


def parse_files(f: Fields) -> dict[str, tuple[int, str]]:
    files = {}
    for name in f.obj:
        entry = f.sub(name)
        p = PurePosixPath(name)
        # bundle files are plain names inside the bundle folder: no directories, no way out of it
        if not name or p.name != name or name in (".", "..") or "\\" in name or "\0" in name:
            f.fail(name, "a bundle file must be a plain file name inside the bundle folder")
        if len(name.encode("utf-8", "surrogatepass")) > NAME_MAX:
            f.fail(shown(name), f"a file name of more than {NAME_MAX} bytes (no file system takes it)")
        digest = entry.str("sha256")
        if not _SHA256.fullmatch(digest):
            entry.fail("sha256", f"expected 64 lowercase hex digits, got {digest!r}")
        files[name] = (entry.int("bytes", 0, 2 ** 40), digest)
    if not files:
        f.fail("", "lists no files")
    return files


def parse_variants(f: Fields) -> dict[str, dict[str, GraphFile]]:
    if "fp32" not in f.obj:
        f.fail("fp32", "missing: every bundle has the fp32 variant")
    variants = {}
    for v in f.obj:
        graphs = f.sub(v)
        entries = {}
        for g in present_graphs(graphs.obj):
            e = graphs.sub(g)
            q = e.get("quantization", None)
            if q is not None and not isinstance(q, dict):
                e.fail("quantization", f"expected an object or null, got {kind(q)}")
            entries[g] = GraphFile(file=e.str("file"), quantization=Quantization.parse(e.sub("quantization"))
                                   if q else None)
        variants[v] = entries
    return variants
