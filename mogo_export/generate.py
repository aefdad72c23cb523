"""The torch reference generator: the runtime's generation loop driven by the PyTorch models.

The loop and the sampling policy live once, in `mogo_runtime.decoding`; this module only supplies a torch
`Backend`, so torch and onnxruntime differ in nothing but the arithmetic. It is the ground truth for parity.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from mogo_runtime.decoding import ModelDims, collect_tokens, decode_tokens, generate_tokens, make_rngs
from mogo_runtime.features import recover_from_ric
from mogo_runtime.sampling import SamplingConfig
from mogo_runtime.skeleton import HUMANML3D, Skeleton

from .checkpoint import build_from_checkpoint
from .models.text_encoder import TextEncoder, get_text_encoder
from .models.transformer import RQHCTransformer, TransformerConfig
from .models.vq import MoSAVQ, VQConfig


class TorchBackend:
    """`mogo_runtime.decoding.Backend` on the torch modules. `kv_cache=False` recomputes the whole sequence every
    step (as T2M-GPT-style code does): same results, used as the benchmark's baseline."""

    def __init__(self, vq: MoSAVQ, transformer: RQHCTransformer, text_encoder: TextEncoder, mean: np.ndarray,
                 std: np.ndarray, fps: float = 20.0, kv_cache: bool = True):
        self.vq, self.transformer, self.text_encoder = vq.eval(), transformer.eval(), text_encoder
        self.mean = torch.as_tensor(mean, dtype=torch.float32)
        self.std = torch.as_tensor(std, dtype=torch.float32)
        self.kv_cache = kv_cache
        tc = transformer.cfg
        self.dims = ModelDims(num_levels=tc.num_levels, codebook_size=tc.codebook_size,
                              downsample=vq.cfg.downsample, receptive_field=vq.receptive_field,
                              feature_dim=vq.cfg.input_dim, text_dim=tc.text_dim, fps=fps)

    @torch.no_grad()
    def encode_text(self, texts: list[str]) -> np.ndarray:
        return self.text_encoder.encode(texts).float().numpy()

    def empty_past(self, rows: int):
        if not self.kv_cache:
            return None                       # the "past" is the token history itself
        return self.transformer.empty_past(rows)

    @torch.no_grad()
    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past):
        emb, tok = torch.from_numpy(np.ascontiguousarray(text_emb)), torch.from_numpy(tokens)
        if self.kv_cache:
            logits, present = self.transformer.step(emb, tok, past)
            return logits.numpy(), present
        history = tok if past is None else torch.cat([past, tok], dim=1)
        logits = self.transformer(emb, history)
        return logits[:, -tok.shape[1]:].numpy(), history

    @torch.no_grad()
    def decode(self, tokens: np.ndarray) -> np.ndarray:
        feats = self.vq.decode_indices(torch.from_numpy(tokens))                 # (B, T*ds, D) normalised
        return (feats * self.std + self.mean).numpy()


@dataclass
class TorchMotion:
    text: str
    tokens: np.ndarray        # (T', L)
    features: np.ndarray      # (T, D) de-normalised
    joints: np.ndarray        # (T, J, 3) metres


class TorchGenerator:
    """Text -> motion with the PyTorch models (reference for the exported bundle)."""

    def __init__(self, backend: TorchBackend, skeleton: Skeleton = HUMANML3D, max_tokens: int = 50):
        self.backend, self.skeleton, self.max_tokens = backend, skeleton, max_tokens

    @classmethod
    def from_checkpoints(cls, ckpt_dir: str | Path, kv_cache: bool = True) -> "TorchGenerator":
        ckpt_dir = Path(ckpt_dir)
        vq, vq_cfg, vq_payload = build_from_checkpoint(ckpt_dir / "vq.pt", "vq", VQConfig, MoSAVQ)
        tr, _, tr_payload = build_from_checkpoint(ckpt_dir / "transformer.pt", "transformer", TransformerConfig,
                                                  RQHCTransformer)
        meta = tr_payload["meta"]
        encoder = get_text_encoder(meta.get("text_encoder", "all-MiniLM-L6-v2"))
        mean = np.asarray(vq_payload["meta"]["mean"], np.float32)
        std = np.asarray(vq_payload["meta"]["std"], np.float32)
        backend = TorchBackend(vq, tr, encoder, mean, std, fps=vq_payload["meta"].get("fps", 20.0), kv_cache=kv_cache)
        return cls(backend, max_tokens=int(meta.get("max_tokens", 50)))

    def generate_tokens(self, texts: list[str], seed: int | list[int] = 0, sampling: SamplingConfig | None = None,
                        num_tokens: int | None = None) -> list[np.ndarray]:
        sampling = sampling or SamplingConfig(temperature=0.0)
        emb = self.backend.encode_text(texts)
        rngs = make_rngs(seed, len(texts))
        steps = generate_tokens(self.backend, emb, sampling, rngs, self.max_tokens, fixed_tokens=num_tokens)
        return collect_tokens(steps, len(texts), self.backend.dims.num_levels)

    def generate(self, texts: list[str], seed: int | list[int] = 0, sampling: SamplingConfig | None = None,
                 num_tokens: int | None = None) -> list[TorchMotion]:
        tokens = self.generate_tokens(texts, seed, sampling, num_tokens)
        feats = decode_tokens(self.backend, tokens)
        return [TorchMotion(t, tok, f, recover_from_ric(f, self.skeleton.num_joints))
                for t, tok, f in zip(texts, tokens, feats)]


# -----------------------------------------------------------------------------
# One face for every way this project generates, so evaluation and quality judge torch and bundles alike.

@dataclass
class FeatureGenerator:
    """`generate(texts, seeds, num_tokens)` -> de-normalised features per text (num_tokens None: the model
    ends each motion), and the frames per token."""
    generate: Callable[[list[str], list[int], int | None], list[np.ndarray]]
    downsample: int


def torch_features(gen: TorchGenerator, sampling: SamplingConfig) -> FeatureGenerator:
    def generate(texts, seeds, num_tokens):
        return [m.features for m in gen.generate(texts, seed=seeds, sampling=sampling, num_tokens=num_tokens)]

    return FeatureGenerator(generate, gen.backend.dims.downsample)


def bundle_features(bundle: str | Path, variant: str, sampling: SamplingConfig | None = None, threads: int = 2,
                    align: bool = False) -> FeatureGenerator:
    """A bundle through mogo_runtime's MotionGenerator, the code a game runs; sampling None = the bundle's own
    defaults. `align`: condition on the TCA-aligned prompts."""
    from mogo_runtime.generator import MotionGenerator

    gen = MotionGenerator(bundle, variant=variant, threads=threads)
    s = sampling or gen.sampling_config()
    per_token = gen.dims.downsample / gen.dims.fps

    def generate(texts, seeds, num_tokens):
        # top_k=0 and top_p=1.0 mean "no cut" (None would mean the bundle's default)
        motions = gen.generate(texts, seconds=None if num_tokens is None else num_tokens * per_token, seed=seeds,
                               temperature=s.temperature, top_k=s.top_k or 0, top_p=s.top_p or 1.0,
                               guidance=s.guidance, align=align)
        return [m.features for m in motions]

    return FeatureGenerator(generate, gen.dims.downsample)
