"""The inference engine: a bundle variant's graphs on onnxruntime, as the `decoding.Backend` the loop drives.

    backend = open_backend(bundle, "int8", threads=1)   # OrtBackend, wrapped in RowByRow for quantized graphs
    backend = open_backend(bundle, "portable")          # FixedCacheBackend: the fixed-capacity step graph
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bundle import Bundle, BundleError
from .manifest import GRAPHS, PER_ROW_INT8, ModelDims
from .text import TextEncoderSession, check_threads, session_options

class NonFiniteOutput(BundleError):
    """A graph returned NaN or inf: its bundle is broken, whatever the input."""




def open_backend(bundle: Bundle, variant: str = "fp32", threads: int = 1):
    """The backend for one variant: the portable step through FixedCacheBackend, graphs quantized per tensor one
    row at a time (see RowByRow; per-row int8 is batch-invariant and runs batched)."""
    portable = variant in bundle.manifest.variants and bundle.manifest.fixed_cache(variant)
    backend = (FixedCacheBackend if portable else OrtBackend)(bundle, variant, threads)
    row_by_row = {g for g in GRAPHS if bundle.manifest.graph_file(g, variant).quantized and
                  bundle.manifest.graph_file(g, variant).quantization.get("method") != PER_ROW_INT8}
    return RowByRow(backend, row_by_row) if row_by_row else backend


class OrtBackend:
    """One CPU session per graph of one bundle variant, every call batched.

    The KV cache is the list of `present.*` arrays a step returns, handed back as the next step's
    `past_key_values.*` inputs as they are (names from the manifest's cache templates). Neither direction
    copies: `run` returns numpy views of the buffers onnxruntime wrote, and takes contiguous float32 numpy input
    in place. (Keeping the cache as OrtValues through `run_with_ort_values` measured 20-50% slower per step
    here, in its Python overhead.)
    """

    def __init__(self, bundle: Bundle, variant: str = "fp32", threads: int = 1):
        if variant not in bundle.manifest.variants:
            raise ValueError(f"unknown variant {variant!r}; bundle {bundle.path} has {', '.join(bundle.variants)}")
        self.bundle, self.variant, self.threads = bundle, variant, check_threads(threads)
        self.dims: ModelDims = bundle.dims
        manifest = bundle.manifest
        try:
            graph, tokenizer = bundle.graph_file("text_encoder", variant), bundle.file(manifest.text_encoder.tokenizer)
            self.text = TextEncoderSession(bundle.read_verified(graph.name), bundle.read_verified(tokenizer.name),
                                           self.threads, names=(str(graph), str(tokenizer)))
        except ValueError as e:
            raise BundleError(str(e)) from None
        if self.text.dim != self.dims.text_dim or self.text.settings.max_length != manifest.text_encoder.max_length:
            raise BundleError(f"{bundle.graph_file('text_encoder', variant)}: embeds to {self.text.dim} values and "
                              f"cuts at {self.text.settings.max_length} tokens; manifest model.text_dim is "
                              f"{self.dims.text_dim}, text_encoder.max_length {manifest.text_encoder.max_length}")
        opts = session_options(self.threads)
        sessions = {graph: bundle.session(graph, variant, opts) for graph in ("step", "lookup", "decoder")}
        self.step_session, self.lookup_session, self.decoder_session = (sessions[g] for g in ("step", "lookup",
                                                                                                "decoder"))
        # the sessions we run are the ones checked against the manifest (Bundle.load may skip its own check)
        for graph, sess in (("text_encoder", self.text.session), *sessions.items()):
            bundle.check_session(graph, bundle.graph_file(graph, variant), sess, variant)
        self.past_names = manifest.past_names
        self.output_names = ["logits", *manifest.present_names]
        self.cache_heads = self.dims.num_levels * self.dims.n_heads   # [rows, L * n_heads, past, head_dim]

    def encode_text(self, texts: list[str]) -> np.ndarray:
        return self._finite("text_encoder", self.text.encode(texts))           # (B, text_dim)

    def empty_past(self, rows: int) -> list[np.ndarray]:
        empty = np.zeros((rows, self.cache_heads, 0, self.dims.head_dim), np.float32)
        return [empty] * len(self.past_names)

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past: list[np.ndarray]):
        feed = {"text_embedding": np.ascontiguousarray(text_emb, dtype=np.float32),
                "tokens": np.ascontiguousarray(tokens, dtype=np.int64), **dict(zip(self.past_names, past))}
        out = self.step_session.run(self.output_names, feed)
        return self._finite("step", out[0]), out[1:]                            # logits (B, S, L, K + 1), presents

    def lookup(self, tokens: np.ndarray) -> np.ndarray:
        (latent,) = self.lookup_session.run(["latent"], {"tokens": np.ascontiguousarray(tokens, dtype=np.int64)})
        return self._finite("lookup", latent)                                   # (B, T, latent_dim)

    def decode(self, tokens: np.ndarray) -> np.ndarray:
        (features,) = self.decoder_session.run(["features"], {"latent": self.lookup(tokens)})
        want = (len(tokens), tokens.shape[1] * self.dims.downsample, self.dims.feature_dim)
        if features.shape != want:   # a wrong model.downsample would otherwise drop or invent frames silently
            raise BundleError(f"{self.bundle.graph_file('decoder', self.variant)}: decoded {tokens.shape[1]} tokens "
                              f"to {features.shape[1:]} frames x features; manifest model.downsample "
                              f"{self.dims.downsample} and model.feature_dim {self.dims.feature_dim} promise {want[1:]}")
        return self._finite("decoder", features)                                # (B, T * downsample, D)

    def _finite(self, graph: str, out: np.ndarray) -> np.ndarray:
        """`out`, or NonFiniteOutput naming the graph: NaN or inf must never reach a motion, a file or a stream
        (a present cache is not checked: its NaN shows in the next step's logits). Costs microseconds a call."""
        if not np.isfinite(out).all():
            raise NonFiniteOutput(f"{self.bundle.graph_file(graph, self.variant)}: the {graph} graph produced NaN or "
                                  f"inf ({int((~np.isfinite(out)).sum())} of {out.size} values); the bundle is "
                                  f"broken (its weights or its export)")
        return out


@dataclass(frozen=True)
class FixedCache:
    """The portable step's cache: per layer key and value [rows, L * n_heads, capacity, head_dim] as the last
    step returned them, and how many of the slots hold steps (the next step writes slot `length`)."""

    arrays: list[np.ndarray]
    length: int


class FixedCacheBackend(OrtBackend):
    """The portable variant: its step graph takes one time step per call and a cache of fixed capacity, written at
    the `position` input and returned whole (docs/bundle.md, "The portable variant").

    Same `Backend` as OrtBackend, so the loop runs unchanged: `step` on S tokens (a context rebuild) makes S calls,
    one per token, and a cache that would overflow its capacity is an error, not a silent overwrite.
    """

    def __init__(self, bundle: Bundle, variant: str = "portable", threads: int = 1):
        super().__init__(bundle, variant, threads)
        if not bundle.manifest.fixed_cache(variant):
            raise ValueError(f"variant {variant!r} of {bundle.path} has the dynamic step graph: use OrtBackend")
        self.capacity = bundle.manifest.portable.capacity

    def empty_past(self, rows: int) -> FixedCache:
        zeros = np.zeros((rows, self.cache_heads, self.capacity, self.dims.head_dim), np.float32)
        return FixedCache([zeros] * len(self.past_names), 0)                   # read only: one buffer serves all

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past: FixedCache):
        rows, steps = tokens.shape[:2]
        if past.length + steps > self.capacity:
            raise ValueError(f"the portable step's cache holds {self.capacity} steps; {past.length} are cached and "
                             f"{steps} more were fed (the manifest's portable.capacity covers the generation loop)")
        text_emb = np.ascontiguousarray(text_emb, dtype=np.float32)
        tokens = np.asarray(tokens, dtype=np.int64)
        cache, logits = past.arrays, []
        for s in range(steps):
            feed = {"text_embedding": text_emb, "tokens": np.ascontiguousarray(tokens[:, s:s + 1]),
                    "position": np.full(rows, past.length + s, np.int64), **dict(zip(self.past_names, cache))}
            out = self.step_session.run(self.output_names, feed)
            logits.append(self._finite("step", out[0]))                         # (rows, 1, L, K + 1)
            cache = out[1:]
        return np.concatenate(logits, axis=1), FixedCache(cache, past.length + steps)


class RowByRow:
    """A backend whose chosen graphs run one row (one prompt, one guidance branch) per call.

    Dynamic quantization scales activations by the range of the whole input tensor, so a quantized graph
    gives a prompt different numbers depending on the other prompts in its batch (measured: int8 tokens parted
    from a lone run's within 2-13 steps). Row by row, a prompt's motion depends on its seed alone, batched or
    not. The step's cache is then one list of arrays per row.
    """

    def __init__(self, inner: OrtBackend, graphs: set[str]):
        self.inner, self.graphs = inner, graphs
        self.dims, self.variant, self.bundle, self.text = inner.dims, inner.variant, inner.bundle, inner.text

    def encode_text(self, texts: list[str]) -> np.ndarray:
        if "text_encoder" not in self.graphs:
            return self.inner.encode_text(texts)
        return np.concatenate([self.inner.encode_text([t]) for t in texts])

    def empty_past(self, rows: int) -> list:
        if "step" not in self.graphs:
            return self.inner.empty_past(rows)
        return [self.inner.empty_past(1) for _ in range(rows)]

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past: list):
        if "step" not in self.graphs:
            return self.inner.step(text_emb, tokens, past)
        outs = [self.inner.step(text_emb[r:r + 1], tokens[r:r + 1], past[r]) for r in range(len(tokens))]
        return np.concatenate([logits for logits, _ in outs]), [presents for _, presents in outs]

    def decode(self, tokens: np.ndarray) -> np.ndarray:
        if not self.graphs & {"lookup", "decoder"}:
            return self.inner.decode(tokens)
        return np.concatenate([self.inner.decode(tokens[r:r + 1]) for r in range(len(tokens))])
