"""The fixed-capacity step graph's part of the manifest contract: the variants that use it, how many cache slots it
needs, and what a manifest must say about it (docs/bundle.md, "The portable variant" and "The int8_fixed variant").
Read through manifest.py, which names these as its own."""
from __future__ import annotations

from typing import TYPE_CHECKING

from .jsonfields import BundleError

if TYPE_CHECKING:
    from .manifest import Manifest, ModelDims, StreamingSpec

PORTABLE = "portable"          # the variant whose step graph has a fixed-capacity cache (section `portable`)
INT8_FIXED = "int8_fixed"      # the same step graph in per-row int8: batch-invariant, so a crowd can batch it
PER_ROW_INT8 = "mogo.per_row_dynamic"   # its quantization method: one activation scale per row (export/rowquant.py)
PORTABLE_OPSET = 17            # its graphs' opset: this or lower (LayerNormalization's first; docs/bundle.md)


def required_capacity(model: ModelDims, streaming: StreamingSpec | None) -> int:
    """Cache slots the generation loop can fill: a clip is BOS plus at most max_tokens - 1 fed tokens (the +1
    spares a consumer that also feeds the token picked at the last step), an endless stream's context is BOS
    plus at most window + refresh motion tokens (docs/bundle.md)."""
    return max(model.max_tokens + 1, 1 + streaming.window + streaming.refresh if streaming else 0)


def check_fixed_cache(manifest: Manifest, where: str) -> None:
    """The portable section and the portable variant come together; the step's I/O is the fixed cache."""
    if (manifest.portable is None) != (PORTABLE not in manifest.variants):
        raise BundleError(f"{where}: field portable: " + (
            "the bundle has no 'portable' variant for it to describe" if manifest.portable else
            "missing: variant 'portable' needs this section (its step graph's inputs, outputs and capacity)"))
    if INT8_FIXED in manifest.variants and PORTABLE not in manifest.variants:
        raise BundleError(f"{where}: field variants.{INT8_FIXED}: comes with variant {PORTABLE!r}, whose section "
                          f"'portable' describes its step graph")
    if manifest.portable is None:
        return
    quantized = [g for g, e in manifest.variants[PORTABLE].items() if e.quantized]
    if quantized:
        raise BundleError(f"{where}: field variants.{PORTABLE}.{quantized[0]}.quantization: the portable "
                          f"variant is fp32 only (no int8 operators)")
    step = manifest.variants[INT8_FIXED]["step"] if INT8_FIXED in manifest.variants else None
    if step is not None and (step.quantization or {}).get("method") != PER_ROW_INT8:
        raise BundleError(f"{where}: field variants.{INT8_FIXED}.step.quantization: its step graph is the "
                          f"portable step quantized per row (method {PER_ROW_INT8!r}), got {step.quantization!r}")
    m, spec, cap = manifest.model, manifest.portable.step, manifest.portable.capacity
    cache = [m.num_levels * m.n_heads, cap, m.head_dim]
    want = {"inputs": {"text_embedding": ("float32", [m.text_dim]), "tokens": ("int64", [1, m.num_levels]),
                       "position": ("int64", []), **dict.fromkeys(manifest.past_names, ("float32", cache))},
            "outputs": {"logits": ("float32", [1, m.num_levels, m.codebook_size + 1]),
                        **dict.fromkeys(manifest.present_names, ("float32", cache))}}
    for kind, expected in want.items():
        got = {s.name: s for s in getattr(spec, kind)}
        if list(got) != list(expected):
            raise BundleError(f"{where}: field portable.step.{kind}: names are {list(got)}, expected "
                              f"{list(expected)} (n_layers and the cache templates)")
        for i, (name, (dtype, dims)) in enumerate(expected.items()):
            s = got[name]
            # every dim but the batch is fixed: a consumer allocates the cache once, from these numbers
            if s.dtype != dtype or list(s.shape[1:]) != dims:
                raise BundleError(f"{where}: field portable.step.{kind}[{i}]: {name!r} is {s.dtype} "
                                  f"[{', '.join(map(str, s.shape))}], expected {dtype} "
                                  f"[{', '.join(map(str, ['batch', *dims]))}]")
