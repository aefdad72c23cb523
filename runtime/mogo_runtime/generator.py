"""Text to motion on onnxruntime: `OrtBackend` runs a bundle's graphs, `MotionGenerator` is the user's API.

    from mogo_runtime import MotionGenerator
    gen = MotionGenerator("bundles/base", variant="fp32", threads=1)
    motion = gen.generate("a person walks forward and then jumps", seconds=6, seed=1)
    motion.save("walk.bvh")
    for frame in gen.stream("a person waves", seed=2):       # frames as soon as they are decoded
        send_to_game(frame.joints)                           # (J, 3) metres, y up
    motion = gen.generate("yo make the dude do a lil hop", align=True)   # TCA (tca.py): prompt in caption style
    print(motion.aligned_text)                               # what the model was conditioned on

The loop itself (steps, END, guidance, sampling) is `decoding.py`'s, shared with the torch reference; this
module only computes (the backend) and checks what a user asks for (the generator).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

import numpy as np

from .bundle import GRAPHS, Bundle, BundleError
from .decoding import FrameStreamer, ModelDims, collect_tokens, decode_tokens, generate_tokens, make_rngs
from .features import recover_from_ric
from .motion import Motion, RootIntegrator
from .sessions import session_options
from .sampling import SamplingConfig
from .text import TextEncoderSession, check_texts

if TYPE_CHECKING:  # tca is imported when alignment is first used: its patterns cost ~50 ms of every cold start
    from .tca import AlignedPrompt, Aligner

_PAST, _PRESENT = "past_key_values.", "present."


class OrtBackend:
    """The `decoding.Backend` protocol on onnxruntime: one CPU session per graph of one bundle variant.

    The KV cache is the list of `present.{i}.*` arrays a step returns (one such list per row for graphs
    run row by row, see `row_by_row`), handed back as the next step's
    `past_key_values.{i}.*` inputs as they are. Neither direction copies: `run` returns numpy views of the
    buffers onnxruntime wrote, and takes contiguous float32 numpy input in place. (Keeping the cache as
    OrtValues through `run_with_ort_values` measured 20-50% slower per step here, in its Python overhead.)
    """

    def __init__(self, bundle: Bundle, variant: str = "fp32", threads: int = 1):
        import onnxruntime as ort

        if variant not in bundle.variants:
            raise ValueError(f"unknown variant {variant!r}; bundle {bundle.path} has {', '.join(bundle.variants)}")
        if not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
            raise ValueError(f"threads must be an int >= 1, got {threads!r}")
        self.bundle, self.variant, self.threads = bundle, variant, threads
        self.dims: ModelDims = bundle.dims
        model = bundle.manifest["model"]
        tokenizer = bundle.manifest.get("text_encoder", {}).get("tokenizer")
        if not isinstance(tokenizer, str):
            raise BundleError(f"{bundle.path / 'manifest.json'}: field text_encoder.tokenizer missing or not a "
                              f"file name")
        self.text = TextEncoderSession(bundle.graph_file("text_encoder", variant), bundle.file(tokenizer), threads)
        if self.text.dim != self.dims.text_dim:
            raise BundleError(f"{bundle.graph_file('text_encoder', variant)}: embeds to {self.text.dim} values, "
                              f"manifest model.text_dim is {self.dims.text_dim}")
        opts = session_options(threads)
        cpu = ["CPUExecutionProvider"]
        self.step_session = ort.InferenceSession(str(bundle.graph_file("step", variant)), opts, providers=cpu)
        self.lookup_session = ort.InferenceSession(str(bundle.graph_file("lookup", variant)), opts, providers=cpu)
        self.decoder_session = ort.InferenceSession(str(bundle.graph_file("decoder", variant)), opts, providers=cpu)
        # the sessions we run are the ones checked against the manifest (Bundle.load may skip its own check)
        for graph, sess in (("text_encoder", self.text.session), ("step", self.step_session),
                            ("lookup", self.lookup_session), ("decoder", self.decoder_session)):
            bundle.check_session(graph, bundle.graph_file(graph, variant), sess)

        # Cache names from the manifest: every present.X output feeds the past_key_values.X input.
        spec = bundle.graph_spec("step")
        where = f"{bundle.path / 'manifest.json'} graphs['step']"
        inputs = [d["name"] for d in spec["inputs"]]
        outputs = [d["name"] for d in spec["outputs"]]
        self.present_names = [n for n in outputs if n.startswith(_PRESENT)]
        self.past_names = [_PAST + n[len(_PRESENT):] for n in self.present_names]
        unmatched = [n for n, p in zip(self.present_names, self.past_names) if p not in inputs]
        if unmatched:
            raise BundleError(f"{where}: outputs {unmatched} have no matching past_key_values.* inputs")
        expected = 2 * int(model["n_layers"])
        if len(self.present_names) != expected or len(set(inputs) - set(self.past_names)) != 2:
            raise BundleError(f"{where}: expected text_embedding, tokens and {expected} past_key_values.* inputs "
                              f"(2 per layer, n_layers={model['n_layers']}); found {inputs}")
        self.output_names = ["logits"] + self.present_names
        # [rows, L * n_heads, 0, head_dim]: the cache's width, straight from the manifest.
        self.cache_heads = int(model["num_levels"]) * int(model["n_heads"])
        self.head_dim = int(model["head_dim"])
        # Dynamic quantization scales activations by the range of the whole input tensor, so a quantized graph
        # gives a prompt different numbers depending on the other prompts in its batch (measured: int8 tokens
        # parted from a lone run's within 2-13 steps). Quantized graphs therefore run one row at a time: a
        # prompt's motion depends on its seed alone, batched or not.
        variant_spec = bundle.manifest["variants"][variant]
        self.row_by_row = {g: bool(variant_spec[g].get("quantization")) for g in GRAPHS}

    def encode_text(self, texts: list[str]) -> np.ndarray:
        if self.row_by_row["text_encoder"]:
            return np.concatenate([self.text.encode([t]) for t in texts])
        return self.text.encode(texts)                                          # (B, text_dim)

    def empty_past(self, rows: int) -> list:
        if self.row_by_row["step"]:   # one cache per row, each (1, L * n_heads, past, head_dim)
            return [self.empty_past_rows(1) for _ in range(rows)]
        return self.empty_past_rows(rows)

    def empty_past_rows(self, rows: int) -> list[np.ndarray]:
        empty = np.zeros((rows, self.cache_heads, 0, self.head_dim), np.float32)
        return [empty] * len(self.past_names)

    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past: list):
        if self.row_by_row["step"]:
            outs = [self._step(text_emb[r:r + 1], tokens[r:r + 1], past[r]) for r in range(len(tokens))]
            return np.concatenate([logits for logits, _ in outs]), [presents for _, presents in outs]
        return self._step(text_emb, tokens, past)

    def _step(self, text_emb: np.ndarray, tokens: np.ndarray, past: list[np.ndarray]):
        feed = {"text_embedding": np.ascontiguousarray(text_emb, dtype=np.float32),
                "tokens": np.ascontiguousarray(tokens, dtype=np.int64), **dict(zip(self.past_names, past))}
        out = self.step_session.run(self.output_names, feed)
        return out[0], out[1:]                                                  # logits (B, S, L, K + 1), presents

    def decode(self, tokens: np.ndarray) -> np.ndarray:
        if self.row_by_row["lookup"] or self.row_by_row["decoder"]:
            return np.concatenate([self._decode(tokens[r:r + 1]) for r in range(len(tokens))])
        return self._decode(tokens)

    def _decode(self, tokens: np.ndarray) -> np.ndarray:
        (latent,) = self.lookup_session.run(["latent"], {"tokens": np.ascontiguousarray(tokens, dtype=np.int64)})
        (features,) = self.decoder_session.run(["features"], {"latent": latent})
        return features                                                         # (B, T * downsample, D)


@dataclass
class Frame:
    """One streamed motion frame."""

    index: int                    # frame number from the start of the motion
    time: float                   # index / fps, seconds
    features: np.ndarray          # (D,) de-normalised features
    joints: np.ndarray            # (J, 3) metres, y up


class FrameStream:
    """What `MotionGenerator.stream` returns: an iterator of Frames, plus the prompt and its aligned text."""

    def __init__(self, frames: Iterator[Frame], text: str, aligned_text: str | None):
        self._frames, self.text, self.aligned_text = frames, text, aligned_text

    def __iter__(self) -> "FrameStream":
        return self

    def __next__(self) -> Frame:
        return next(self._frames)

    def close(self) -> None:
        self._frames.close()


class MotionGenerator:
    """Generate motions from text with a bundle; settings left as None take the bundle's sampling_defaults.

    `aligner`: the text condition alignment `align=True` uses (tca.py); default the bundle's OfflineAligner.
    """

    def __init__(self, bundle: Bundle | str | Path, variant: str = "fp32", threads: int = 1,
                 aligner: Aligner | None = None):
        # Only the chosen variant's files are hashed and checked: an int8 run never reads the fp32 text encoder.
        # The backend checks the sessions it opens against the manifest, so loading skips its own graph check.
        self.bundle = (bundle if isinstance(bundle, Bundle) else
                       Bundle.load(bundle, variants=[variant], check_graphs=False))
        self.backend = OrtBackend(self.bundle, variant, threads)
        self.dims = self.bundle.dims
        self.skeleton = self.bundle.skeleton
        self.max_tokens = int(self.bundle.manifest["model"]["max_tokens"])
        self.defaults = dict(self.bundle.manifest.get("sampling_defaults") or {})
        self._aligner = aligner

    @property
    def aligner(self) -> Aligner:
        """The aligner of `align=True`: the one given, else the bundle's offline one (built on first use)."""
        if self._aligner is None:
            from .tca import OfflineAligner

            self._aligner = OfflineAligner(self.bundle, self.backend)
        return self._aligner

    @aligner.setter
    def aligner(self, aligner: Aligner) -> None:
        self._aligner = aligner

    def align(self, texts: list[str], align: bool | Aligner = True) -> list[AlignedPrompt] | None:
        """The aligned prompts for `texts` (None when `align` is False): `align` is True or an Aligner."""
        if align is False or align is None:
            return None
        from .tca import Aligner

        aligner = self.aligner if align is True else align
        if not isinstance(aligner, Aligner):
            raise ValueError(f"align must be True, False or a mogo_runtime.tca.Aligner, got {align!r}")
        return aligner.align_batch(texts)

    def _condition(self, texts: list[str], align) -> tuple[np.ndarray, list[str | None]]:
        prompts = self.align(texts, align)
        if prompts is None:
            return self.backend.encode_text(texts), [None] * len(texts)
        from .tca import apply_alignment

        return apply_alignment(prompts, self.backend.encode_text), [p.text for p in prompts]

    @property
    def variant(self) -> str:
        return self.backend.variant

    @property
    def max_seconds(self) -> float:
        return self.max_tokens * self.dims.downsample / self.dims.fps

    def generate(self, text: str | list[str], seconds: float | None = None, seed: int | list[int] = 0,
                 temperature: float | None = None, top_k: int | None = None, top_p: float | None = None,
                 guidance: float | None = None, progress: Callable[[int, int], None] | None = None,
                 align: bool | Aligner = False) -> Motion | list[Motion]:
        """One motion per prompt (a list for a list), all prompts in one batched loop.

        Prompt i of a list uses seed `seed + i` (or `seed[i]`), so it gets the motion a lone run with that
        seed gets. `seconds` fixes the length (rounded to whole tokens, END never chosen); None lets the
        model end the motion, at most `max_seconds`. `progress(step, limit)` is called after every step.
        `align=True` (or an Aligner) rewrites each prompt into the training captions' style first (TCA,
        tca.py); the motion's `aligned_text` says what the model was conditioned on.
        """
        texts = [text] if isinstance(text, str) else text
        texts = check_texts(texts)
        fixed = self.tokens_for(seconds)
        sampling = self.sampling_config(temperature, top_k, top_p, guidance)
        seeds = _check_seeds(seed, len(texts))
        emb, aligned = self._condition(texts, align)
        steps = generate_tokens(self.backend, emb, sampling, make_rngs(seeds, len(texts)), self.max_tokens, fixed)
        if progress is not None:
            steps = _report(steps, progress, fixed or self.max_tokens)
        token_seqs = collect_tokens(steps, len(texts), self.dims.num_levels)
        features = decode_tokens(self.backend, token_seqs)
        motions = [Motion(text=t, features=f, joints=recover_from_ric(f, self.skeleton.num_joints),
                          fps=self.dims.fps, tokens=tok, skeleton=self.skeleton, seed=s, aligned_text=a)
                   for t, f, tok, s, a in zip(texts, features, token_seqs, seeds, aligned)]
        return motions[0] if isinstance(text, str) else motions

    def stream(self, text: str, seconds: float | None = None, seed: int = 0, temperature: float | None = None,
               top_k: int | None = None, top_p: float | None = None,
               guidance: float | None = None, align: bool | Aligner = False, chunk: int = 4) -> FrameStream:
        """Yield the frames of one prompt's motion as its tokens are sampled and decoded.

        The first token's frames come at once; after that frames come `chunk` tokens at a time (chunk=1: every
        token, at ~1.6x the decoding work; see decoding.FrameStreamer).
        The causal decoder makes them equal to `generate(text, ..., seed=seed)`'s frames (to float rounding).
        Arguments are checked, and the prompt aligned (`align`, as in generate), when this is called, before
        the first frame is asked for; the returned stream's `aligned_text` says what the model follows.
        """
        if not isinstance(text, str):
            raise TypeError(f"stream() takes one prompt (str), got {type(text).__name__}; use generate() for a batch")
        check_texts([text])
        fixed = self.tokens_for(seconds)
        sampling = self.sampling_config(temperature, top_k, top_p, guidance)
        seeds = _check_seeds(seed, 1)
        streamer = FrameStreamer(self.backend, 1, chunk)
        emb, aligned = self._condition([text], align)
        return FrameStream(self._stream(emb, fixed, sampling, seeds, streamer), text, aligned[0])

    def _stream(self, emb, fixed, sampling, seeds, streamer: FrameStreamer) -> Iterator[Frame]:
        def decoded() -> Iterator[np.ndarray]:  # (n, D) features as they become ready, n may be 0
            for picked, alive in generate_tokens(self.backend, emb, sampling, make_rngs(seeds, 1), self.max_tokens,
                                                 fixed):
                if not alive[0]:
                    break
                yield streamer.push(picked)[0]
            yield streamer.flush()[0]

        integrator = RootIntegrator(self.skeleton.num_joints)
        index = 0
        for features in decoded():
            if not len(features):
                continue
            for f, j in zip(features, integrator.push(features)):
                yield Frame(index=index, time=index / self.dims.fps, features=f, joints=j)
                index += 1

    def tokens_for(self, seconds: float | None) -> int | None:
        """Seconds -> a fixed number of tokens (half up), or None; ValueError outside the bundle's range."""
        if seconds is None:
            return None
        per_token = self.dims.downsample / self.dims.fps
        allowed = (f"between {per_token:g} and {self.max_seconds:g} seconds for this bundle ({self.dims.downsample} "
                   f"frames per token at {self.dims.fps:g} fps, at most {self.max_tokens} tokens)")
        try:
            value = float(seconds)
        except (TypeError, ValueError):
            raise ValueError(f"seconds must be a number {allowed}, got {seconds!r}") from None
        if not math.isfinite(value) or value <= 0:
            raise ValueError(f"seconds must be {allowed}, got {seconds!r}")
        tokens = math.floor(value / per_token + 0.5 + 1e-9)   # the epsilon keeps 6.0 s from landing just below
        if not 1 <= tokens <= self.max_tokens:
            raise ValueError(f"seconds must be {allowed}, got {seconds!r}")
        return tokens

    def sampling_config(self, temperature=None, top_k=None, top_p=None, guidance=None) -> SamplingConfig:
        """The settings to use: each None replaced by the bundle's default. top_k=0 means no top-k cut."""
        d = self.defaults
        temperature = d.get("temperature", 1.0) if temperature is None else temperature
        top_k = d.get("top_k") if top_k is None else top_k
        top_p = d.get("top_p") if top_p is None else top_p
        guidance = d.get("guidance", 1.0) if guidance is None else guidance
        for name, value in (("temperature", temperature), ("top_p", top_p), ("guidance", guidance)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise ValueError(f"{name} must be a number, got {value!r}")
        if top_k is not None and (isinstance(top_k, bool) or not isinstance(top_k, (int, np.integer)) or top_k < 0):
            raise ValueError(f"top_k must be an int >= 1 (or 0 for no top-k cut), got {top_k!r}")
        return SamplingConfig(temperature=float(temperature), top_k=int(top_k) if top_k else None,
                              top_p=None if top_p is None else float(top_p), guidance=float(guidance))


def _check_seeds(seed, batch: int) -> list[int]:
    seeds = list(seed) if isinstance(seed, (list, tuple)) else None
    if seeds is None:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an int >= 0 or a list of them, got {seed!r}")
        seeds = [int(seed) + i for i in range(batch)]
    if len(seeds) != batch:
        raise ValueError(f"got {len(seeds)} seeds for {batch} prompts")
    for s in seeds:
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise ValueError(f"seeds must be ints >= 0, got {s!r}")
    return [int(s) for s in seeds]


def _report(steps, progress: Callable[[int, int], None], limit: int):
    for t, item in enumerate(steps):
        yield item
        progress(t + 1, limit)
