"""The inference engine: a bundle variant's graphs on onnxruntime, as the `decoding.Backend` the loop drives.

    backend = open_backend(bundle, "int8", threads=1)   # OrtBackend: the step graph with a growing cache
    backend = open_backend(bundle, "portable")          # FixedCacheBackend: the fixed-capacity step graph

Graphs quantized per tensor run one row per call (one prompt, one guidance branch): dynamic quantization scales
activations by the range of the whole input tensor, so such a graph would give a prompt different numbers depending
on the other prompts in its batch (measured: int8 tokens parted from a lone run's within 2-13 steps). Row by row, a
prompt's motion depends on its seed alone, batched or not; the step's cache is then one list of arrays per row.
Per-row int8 (`int8_fixed`) and int8-stored weights (`compact`, float32 arithmetic) are batch-invariant and run
batched.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .bundle.folder import Bundle
from .bundle.manifest import DECODER_STATE
from .bundle.sections import DECODING_GRAPHS, BundleError, ControlSpec, ModelDims
from .checks import shown
from .text import TextEncoderSession, check_threads, session_options


TEXT_CACHE = 1024     # prompts whose embedding a backend keeps (1.5 MB on base)


class NonFiniteOutput(BundleError):
    """A graph returned NaN or inf: its bundle is broken, whatever the input."""


def open_backend(bundle: Bundle, variant: str = "fp32", threads: int = 1) -> "OrtBackend":
    """The backend for one variant: the portable step's fixed cache through FixedCacheBackend, else OrtBackend."""
    return (FixedCacheBackend if bundle.manifest.fixed_cache(variant) else OrtBackend)(bundle, variant, threads)


class MotionDecoder:
    """The decoding half of a bundle variant: its codebook lookup and motion decoder on onnxruntime, tokens in,
    features out. All a client needs that only shows motion generated elsewhere (wire/client.py): no step graph, no
    text encoder (on `base`'s compact variant, 0.9 MB of graphs against 32 MB). A bundle with a decoder_step graph
    also decodes a stream's new tokens from its decoder state (`decode_step`; `decoder_state` its shapes)."""

    def __init__(self, bundle: Bundle, variant: str = "fp32", threads: int = 1):
        if variant not in bundle.manifest.variants:
            raise ValueError(f"unknown variant {variant!r}; bundle {bundle.path} has {', '.join(bundle.variants)}")
        self.bundle, self.variant, self.threads = bundle, variant, check_threads(threads)
        self.dims: ModelDims = bundle.dims
        self.one_row = bundle.manifest.row_by_row(variant)       # graphs that run one row per call
        opts = session_options(self.threads)
        self.decoder_state = bundle.manifest.decoder_state      # None: streams decode windows of tokens
        graphs = DECODING_GRAPHS[:3 if self.decoder_state else 2]
        sessions = [bundle.session(graph, variant, opts) for graph in graphs]
        for graph, sess in zip(graphs, sessions):
            bundle.check_session(graph, sess, variant)
        self.lookup_session, self.decoder_session = sessions[:2]
        self.decoder_step_session = sessions[2] if self.decoder_state else None

    def decode(self, tokens: np.ndarray) -> np.ndarray:
        """Codebook lookup + causal decoder: (B, T, L) tokens -> de-normalised features (B, T * downsample, D)."""
        if self.one_row & {"lookup", "decoder"}:
            return np.concatenate([self._decode(tokens[r:r + 1]) for r in range(len(tokens))])
        return self._decode(tokens)

    def lookup(self, tokens: np.ndarray) -> np.ndarray:
        """The codebook lookup alone: (B, T, L) tokens -> the decoder's input (B, T, latent_dim)."""
        (latent,) = self._run("lookup", self.lookup_session.run, ["latent"],
                              {"tokens": np.ascontiguousarray(tokens, dtype=np.int64)})
        return self._finite("lookup", latent)

    def _decode(self, tokens: np.ndarray) -> np.ndarray:
        (features,) = self._run("decoder", self.decoder_session.run, ["features"], {"latent": self.lookup(tokens)})
        return self._features("decoder", tokens, features)

    def _features(self, graph: str, tokens: np.ndarray, features: np.ndarray) -> np.ndarray:
        """A decoder graph's output for `tokens` (B, T, L), checked: (B, T * downsample, D), finite."""
        want = (len(tokens), tokens.shape[1] * self.dims.downsample, self.dims.feature_dim)
        if features.shape != want:   # a wrong model.downsample would otherwise drop or invent frames silently
            raise BundleError(f"{self.bundle.graph_path(graph, self.variant)}: decoded {tokens.shape[1]} tokens "
                              f"to {features.shape[1:]} frames x features; manifest model.downsample "
                              f"{self.dims.downsample} and model.feature_dim {self.dims.feature_dim} promise {want[1:]}")
        return self._finite(graph, features)

    def decode_step(self, tokens: np.ndarray, state: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
        """Streams' next tokens (B, T, L) from their decoder state (each (B, reach, channels); zeros at a motion's
        start) -> (features (B, T * downsample, D), the state after them). The frames equal `decode`'s of the
        whole motion within float32 rounding, and each row's and each token's are the same bits however they are
        batched (tests/export/test_decoder_step.py)."""
        if "decoder_step" in self.one_row or "lookup" in self.one_row:
            rows = [self.decode_step(tokens[r:r + 1], [s[r:r + 1] for s in state]) for r in range(len(tokens))]
            return (np.concatenate([f for f, _ in rows]),
                    [np.concatenate(s) for s in zip(*(st for _, st in rows))])
        feed = {"latent": self.lookup(tokens), **{DECODER_STATE[0].format(i): np.ascontiguousarray(s, np.float32)
                                                  for i, s in enumerate(state)}}
        features, *nxt = self._run("decoder_step", self.decoder_step_session.run, None, feed)
        return self._features("decoder_step", tokens, features), nxt

    def _run(self, graph: str, run, *args):
        """`run(*args)` of `graph`'s session; onnxruntime refusing to finish it (an output it cannot allocate, shapes
        that do not fit) is a BundleError naming the graph, as the bundle's graphs are what is wrong."""
        try:
            return run(*args)
        except Exception as e:      # onnxruntime's own error types (Fail, InvalidArgument, ...; a RuntimeError from a
            # run with IOBinding): `run` is onnxruntime's, so nothing else raises those here
            if type(e).__module__ != "onnxruntime.capi.onnxruntime_pybind11_state" and type(e) is not RuntimeError:
                raise
            raise BundleError(f"{self.bundle.graph_path(graph, self.variant)}: onnxruntime could not run the {graph} "
                              f"graph ({shown(str(e), 300)}); the bundle is broken") from None

    def _finite(self, graph: str, out: np.ndarray) -> np.ndarray:
        """`out`, or NonFiniteOutput naming the graph: NaN or inf must never reach a motion, a file or a stream
        (a present cache is not checked: its NaN shows in the next step's logits). Costs microseconds a call."""
        if not np.isfinite(out).all():
            raise NonFiniteOutput(f"{self.bundle.graph_path(graph, self.variant)}: the {graph} graph produced NaN or "
                                  f"inf ({int((~np.isfinite(out)).sum())} of {out.size} values); the bundle is "
                                  f"broken (its weights or its export)")
        return out


class OrtBackend(MotionDecoder):
    """One CPU session per graph of one bundle variant, every call batched (graphs quantized per tensor: a row per
    call, see the module docstring).

    The KV cache is the list of `present.*` arrays a step returns, handed back as the next step's
    `past_key_values.*` inputs as they are (names from the manifest's cache templates). Neither direction
    copies: `run` returns numpy views of the buffers onnxruntime wrote, and takes contiguous float32 numpy input
    in place. (Keeping the cache as OrtValues through `run_with_ort_values` measured 20-50% slower per step
    here, in its Python overhead.)
    """

    def __init__(self, bundle: Bundle, variant: str = "fp32", threads: int = 1):
        super().__init__(bundle, variant, threads)
        manifest = bundle.manifest
        self.control: ControlSpec | None = manifest.control     # the step graph's control input; None: none
        files = manifest.graph_file("text_encoder", variant).file, manifest.text_encoder.tokenizer
        try:
            self.text = TextEncoderSession(*map(bundle.read_verified, files), self.threads,
                                           names=tuple(str(bundle.path / f) for f in files))
        except ValueError as e:
            raise BundleError(str(e)) from None
        if self.text.dim != self.dims.text_dim or self.text.settings.max_length != manifest.text_encoder.max_length:
            raise BundleError(f"{bundle.graph_path('text_encoder', variant)}: embeds to {self.text.dim} values and "
                              f"cuts at {self.text.settings.max_length} tokens; manifest model.text_dim is "
                              f"{self.dims.text_dim}, text_encoder.max_length {manifest.text_encoder.max_length}")
        self.step_session = bundle.session("step", variant, session_options(self.threads))
        # the sessions we run are the ones checked against the manifest (Bundle.load for a variant does not)
        for graph, sess in (("text_encoder", self.text.session), ("step", self.step_session)):
            bundle.check_session(graph, sess, variant)
        self._embedded: OrderedDict[str, np.ndarray] = OrderedDict()     # prompt -> its embedding (1, text_dim)
        self._embedded_lock = threading.Lock()
        self.past_names = manifest.past_names
        self.output_names = ["logits", *manifest.present_names]
        self.cache_heads = self.dims.num_levels * self.dims.n_heads   # [rows, L * n_heads, past, head_dim]

    def encode_text(self, texts: list[str]) -> np.ndarray:
        if "text_encoder" in self.one_row:
            return np.concatenate([self._encode([t]) for t in texts])
        return self._encode(texts)

    def _encode(self, texts: list[str]) -> np.ndarray:
        """(B, text_dim). A prompt embedded alone is kept (TEXT_CACHE of them, the least recently used go first):
        a crowd's characters share few prompts, and a prompt costs ~5 ms on base's int8 encoder. Only a lone
        prompt's: in a batch, padding could change a prompt's last bits."""
        if len(texts) == 1:
            with self._embedded_lock:
                known = self._embedded.get(texts[0])
                if known is not None:
                    self._embedded.move_to_end(texts[0])
                    return known.copy()
        out = self._finite("text_encoder", self._run("text_encoder", self.text.encode, texts))
        if len(texts) == 1:
            with self._embedded_lock:
                self._embedded[texts[0]] = out.copy()
                while len(self._embedded) > TEXT_CACHE:
                    self._embedded.popitem(last=False)
        return out

    def empty_past(self, rows: int) -> list:
        empty = [np.zeros((1 if "step" in self.one_row else rows, self.cache_heads, 0, self.dims.head_dim),
                          np.float32)] * len(self.past_names)
        return [empty] * rows if "step" in self.one_row else empty

    def compact(self, past: list, first: int, count: int) -> list:
        """The cache with slots first .. first + count - 1 moved to 1 .. count and nothing after them (an endless
        stream's compaction, endless.StreamContext.compaction)."""
        def kept(arrays):
            return [np.concatenate([p[:, :, :1], p[:, :, first:first + count]], axis=2) for p in arrays]
        return [kept(row) for row in past] if "step" in self.one_row else kept(past)

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past: list, control: np.ndarray | None = None):
        """-> (logits (B, S, L, K + 1), the next past). `control` (B, S, control.dim): see `controls`."""
        control = self.controls(tokens, control)
        if "step" in self.one_row:
            outs = [self._step(text_emb[r:r + 1], tokens[r:r + 1], past[r], None if control is None else
                               control[r:r + 1]) for r in range(len(tokens))]
            return np.concatenate([logits for logits, _ in outs]), [presents for _, presents in outs]
        return self._step(text_emb, tokens, past, control)

    def controls(self, tokens: np.ndarray, control: np.ndarray | None) -> np.ndarray | None:
        """The control input of a step on `tokens` (B, S, L): `control` (B, S, control.dim) checked, zeros ("no
        control") for None; None for a model without control, which takes none."""
        if self.control is None:
            if control is not None:
                raise ValueError("this bundle's model was trained without control (its manifest has no 'control' "
                                 "section)")
            return None
        want = (*tokens.shape[:2], self.control.dim)
        if control is None:
            return np.zeros(want, np.float32)
        if control.shape != want:
            raise ValueError(f"control must be {want} for tokens {tokens.shape}, got {control.shape}")
        return np.ascontiguousarray(control, dtype=np.float32)

    def _step(self, text_emb: np.ndarray, tokens: np.ndarray, past: list[np.ndarray], control: np.ndarray | None):
        feed = {"text_embedding": np.ascontiguousarray(text_emb, dtype=np.float32),
                "tokens": np.ascontiguousarray(tokens, dtype=np.int64),
                **({} if control is None else {"control": control}), **dict(zip(self.past_names, past))}
        out = self._run("step", self.step_session.run, self.output_names, feed)
        (rows, steps), d = tokens.shape[:2], self.dims
        # what the graph returns is held to the manifest every step: a cache that grew by more than the steps fed (or
        # logits of another width) would be read wrongly, or fill the memory over minutes. The loop reads the last
        # position's logits: a graph may return only those.
        cache, logits = (rows, self.cache_heads, past[0].shape[2] + steps, d.head_dim), out[0].shape
        if (logits[0], *logits[2:]) != (rows, d.num_levels, d.codebook_size + 1) or not 1 <= logits[1] <= steps \
                or any(p.shape != cache for p in out[1:]):
            raise BundleError(f"{self.bundle.graph_path('step', self.variant)}: returned logits {logits} and a cache "
                              f"{out[1].shape} for {steps} step(s) after {past[0].shape[2]}; the manifest's model says "
                              f"{(rows, steps, d.num_levels, d.codebook_size + 1)} and {cache}")
        return self._finite("step", out[0]), out[1:]                            # logits (B, S, L, K + 1), presents


def compact_slots(arrays: list[np.ndarray], first: int, count: int, rows=slice(None)) -> None:
    """In place: cache slots first .. first + count - 1 of `rows` to slots 1 .. count (a compaction)."""
    for a in arrays:
        a[rows, :, 1:1 + count] = a[rows, :, first:first + count]


@dataclass(frozen=True)
class FixedCache:
    """The portable step's cache: per layer key and value [rows, L * n_heads, capacity, head_dim], written in place
    by every step, and how many of the slots hold steps (the next step writes slot `length`)."""

    arrays: list[np.ndarray]
    length: int


class FixedCacheBackend(OrtBackend):
    """The portable variant: its step graph takes one time step per call and a cache of fixed capacity, written at
    the `position` input and returned whole (docs/bundle.md, "The portable variant"). Its step graph is never run a
    row per call (portable is fp32, int8_fixed's step per-row int8, compact's float32 on int8-stored weights), so
    rows at different positions share a call.

    Same `Backend` as OrtBackend, so the loop runs unchanged: `step` on S tokens (a context rebuild) makes S calls,
    one per token, each writing its slot into the cache in place; a cache that would overflow its capacity is an
    error, not a silent overwrite.
    """

    def __init__(self, bundle: Bundle, variant: str = "portable", threads: int = 1):
        super().__init__(bundle, variant, threads)
        if not bundle.manifest.fixed_cache(variant):
            raise ValueError(f"variant {variant!r} of {bundle.path} has the dynamic step graph: use OrtBackend")
        self.capacity = bundle.manifest.portable.capacity
        self.cache_shape = (self.cache_heads, self.capacity, self.dims.head_dim)   # per row

    def empty_past(self, rows: int) -> FixedCache:
        return FixedCache([np.zeros((rows,) + self.cache_shape, np.float32) for _ in self.past_names], 0)

    def compact(self, past: FixedCache, first: int, count: int) -> FixedCache:
        compact_slots(past.arrays, first, count)
        return FixedCache(past.arrays, 1 + count)

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past: FixedCache, control: np.ndarray | None = None):
        """-> (logits (B, S, L, K + 1), the past one step on). `past`'s arrays are written in place."""
        rows, steps = tokens.shape[:2]
        if past.length + steps > self.capacity:
            raise ValueError(f"the portable step's cache holds {self.capacity} steps; {past.length} are cached and "
                             f"{steps} more were fed (the manifest's portable.capacity covers the generation loop)")
        control = self.controls(tokens, control)
        logits = [self.step_in_place(text_emb, tokens[:, s], np.full(rows, past.length + s, np.int64), past.arrays,
                                     None if control is None else control[:, s]) for s in range(steps)]
        return np.concatenate(logits, axis=1), FixedCache(past.arrays, past.length + steps)

    def step_in_place(self, text_emb: np.ndarray, tokens: np.ndarray, position: np.ndarray,
                      cache: list[np.ndarray], control: np.ndarray | None = None) -> np.ndarray:
        """One call: tokens (rows, L) at cache slot `position` (rows,), control (rows, control.dim) -> logits
        (rows, 1, L, K + 1).

        Each cache array (rows, L * n_heads, capacity, head_dim), C-contiguous float32, is bound as both the past
        and the present, so the graph's ScatterND writes the new slot where it is instead of copying the
        whole cache (that copy was half a step's time at batch 128 on base; the results are the same bits,
        tests/runtime/test_crowd.py). Slots past `position` are masked out of attention: what an earlier context
        left there changes nothing."""
        binding = self.step_session.io_binding()
        binding.bind_cpu_input("text_embedding", np.ascontiguousarray(text_emb, dtype=np.float32))
        binding.bind_cpu_input("tokens", np.ascontiguousarray(tokens[:, None], dtype=np.int64))
        binding.bind_cpu_input("position", np.ascontiguousarray(position, dtype=np.int64))
        control = self.controls(tokens[:, None], None if control is None else control[:, None])
        if control is not None:
            binding.bind_cpu_input("control", control)
        logits = np.empty((len(tokens), 1, self.dims.num_levels, self.dims.codebook_size + 1), np.float32)
        # every output bound to our arrays: fetching outputs from the binding would copy the caches back
        binding.bind_output("logits", "cpu", 0, np.float32, list(logits.shape), logits.ctypes.data)
        for past, present, array in zip(self.past_names, self.output_names[1:], cache):
            if array.dtype != np.float32 or not array.flags.c_contiguous or array.shape[1:] != self.cache_shape:
                raise ValueError(f"a fixed cache array is C-contiguous float32 (rows, {self.cache_shape}), got "
                                 f"{array.dtype} {array.shape}")
            binding.bind_cpu_input(past, array)
            binding.bind_output(present, "cpu", 0, np.float32, list(array.shape), array.ctypes.data)
        self._run("step", self.step_session.run_with_iobinding, binding)
        return self._finite("step", logits)
