"""The torch reference generator: the runtime's generation loop driven by the PyTorch models.

The loop and the sampling policy live once, in `mogo_runtime.decoding`; this module only supplies a torch
`Backend`, so torch and onnxruntime differ in nothing but the arithmetic. It is the ground truth for parity.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from mogo_runtime.bundle.sampling import GREEDY, SamplingConfig
from mogo_runtime.bundle.sections import ControlSpec, StreamingSpec
from mogo_runtime.clock import NO_CLOCK, StageClock
from mogo_runtime.decoding import Generated, GenerationTask
from mogo_runtime.kinematics.skeleton import HUMANML3D, Skeleton, get_skeleton
from mogo_runtime.policy import expand_seeds

from .checkpoint import load_trained, model_dims
from .models.text_encoder import TextEncoder, get_text_encoder
from .models.transformer import RQHCTransformer
from .models.vq import MoSAVQ


class TorchBackend:
    """`mogo_runtime.decoding.Backend` on the torch modules. `kv_cache=False` recomputes the whole sequence every
    step (as T2M-GPT-style code does): same results up to an endless stream's first compaction (see `compact`), used
    as the benchmark's baseline."""

    def __init__(self, vq: MoSAVQ, transformer: RQHCTransformer, text_encoder: TextEncoder, mean: np.ndarray,
                 std: np.ndarray, fps: float, max_tokens: int, kv_cache: bool = True):
        self.vq, self.transformer, self.text_encoder = vq.eval(), transformer.eval(), text_encoder
        self.mean = torch.as_tensor(mean, dtype=torch.float32)
        self.std = torch.as_tensor(std, dtype=torch.float32)
        self.kv_cache = kv_cache
        self.dims = model_dims(vq, transformer, fps, max_tokens)
        c = transformer.cfg
        self.control = ControlSpec(c.control_horizon, c.control_dim) if c.control_dim else None
        self.decoder_state = None      # streams decode windows of tokens (decoding.FrameMaker)

    @torch.no_grad()
    def encode_text(self, texts: list[str]) -> np.ndarray:
        return self.text_encoder.encode(texts).float().numpy()

    def empty_past(self, rows: int):
        if not self.kv_cache:
            return None                       # the "past" is the token history itself
        return self.transformer.empty_past(rows)

    def compact(self, past, first: int, count: int):
        """As the runtime's backends (mogo_runtime.engine): slots first .. first + count - 1 to 1 .. count. Without a
        cache the kept steps' tokens are kept and recomputed, as a rebuild would: the recompute baseline's streams part
        from the cached ones at their first compaction (it is a timing baseline)."""
        def kept(t, dim):
            return None if t is None else torch.cat([t.narrow(dim, 0, 1), t.narrow(dim, first, count)], dim=dim)
        if not self.kv_cache:
            return kept(past[0], 1), kept(past[1], 1)
        return [tuple(kept(t, 2) for t in kv) for kv in past]

    @torch.no_grad()
    def step(self, text_emb: np.ndarray, tokens: np.ndarray, past, control: np.ndarray | None = None):
        emb, tok = torch.from_numpy(np.ascontiguousarray(text_emb)), torch.from_numpy(tokens)
        ctrl = None if control is None else torch.from_numpy(np.ascontiguousarray(control, dtype=np.float32))
        if self.kv_cache:
            logits, present = self.transformer.step(emb, tok, past, ctrl)
            return logits.numpy(), present
        # no cache: the "past" is the token history itself, and the controls it was fed with
        history = (tok, ctrl) if past is None else (torch.cat([past[0], tok], dim=1), None if ctrl is None else
                                                    torch.cat([past[1], ctrl], dim=1))
        logits = self.transformer(emb, *history)
        return logits[:, -tok.shape[1]:].numpy(), history

    @torch.no_grad()
    def decode(self, tokens: np.ndarray) -> np.ndarray:
        feats = self.vq.decode_indices(torch.from_numpy(tokens))                 # (B, T*ds, D) normalised
        return (feats * self.std + self.mean).numpy()


class TorchGenerator:
    """Text -> motion with the PyTorch models (reference for the exported bundle), through the runtime's
    `GenerationTask`; sampling None = greedy."""

    def __init__(self, backend: TorchBackend, skeleton: Skeleton = HUMANML3D, streaming: StreamingSpec | None = None):
        # streaming: the endless-stream policy the model was trained for; fixed lengths then run the EndlessLoop,
        # as the exported bundle does
        self.backend, self.skeleton, self.streaming = backend, skeleton, streaming

    @property
    def max_tokens(self) -> int:
        return self.backend.dims.max_tokens

    @classmethod
    def from_checkpoints(cls, ckpt_dir: str | Path, kv_cache: bool = True) -> "TorchGenerator":
        m = load_trained(ckpt_dir)
        backend = TorchBackend(m.vq, m.transformer, get_text_encoder(m.text_encoder_name), m.mean, m.std, fps=m.fps,
                               max_tokens=m.max_tokens, kv_cache=kv_cache)
        return cls(backend, skeleton=get_skeleton(m.skeleton),
                   streaming=StreamingSpec(**m.streaming) if m.streaming else None)

    def task(self, sampling: SamplingConfig | None = None, num_tokens: int | None = None,
             clock: StageClock = NO_CLOCK) -> GenerationTask:
        return GenerationTask(self.backend, self.skeleton, sampling or GREEDY, self.max_tokens, num_tokens,
                              self.streaming, clock)

    def generate_tokens(self, texts: list[str], seed: int | list[int] = 0, sampling: SamplingConfig | None = None,
                        num_tokens: int | None = None) -> list[np.ndarray]:
        emb = self.backend.encode_text(texts)
        return self.task(sampling, num_tokens).tokens(emb, expand_seeds(seed, len(texts)))

    def generate(self, texts: list[str], seed: int | list[int] = 0, sampling: SamplingConfig | None = None,
                 num_tokens: int | None = None, clock: StageClock = NO_CLOCK) -> list[Generated]:
        with clock("text"):
            emb = self.backend.encode_text(texts)
        return self.task(sampling, num_tokens, clock).run(emb, expand_seeds(seed, len(texts)))
