"""Token sampling policy: temperature, top-k, top-p, classifier-free guidance; numpy only.

Kept apart from the network (as whisper's decoding.py does) so the same policy drives the torch reference
generator and the onnxruntime runtime, and a seed means the same tokens in both.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


def _number(name: str, value, optional: bool = False) -> float | None:
    """A real number (Python or numpy scalar), or None where allowed; bools and strings are refused."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number{' or None' if optional else ''}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class SamplingConfig:
    temperature: float = 1.0      # 0 = greedy (argmax), no randomness
    top_k: int | None = None      # keep the k most likely codes (None or 0 = all)
    top_p: float | None = None    # nucleus: keep the smallest set with this much mass (None = all)
    guidance: float = 1.0         # classifier-free guidance scale; 1 = off (no unconditional pass)

    def __post_init__(self):
        # one check for the API, the CLI and the manifest; values are stored as plain Python numbers
        temperature = _number("temperature", self.temperature)
        top_p, guidance = _number("top_p", self.top_p, optional=True), _number("guidance", self.guidance)
        top_k = self.top_k
        if top_k is not None and (isinstance(top_k, (bool, np.bool_)) or not isinstance(top_k, (int, np.integer))
                                  or top_k < 0):
            raise ValueError(f"top_k must be an int >= 1 (0 or None: no top-k cut), got {top_k!r}")
        if not math.isfinite(temperature) or not 0 <= temperature <= 100:
            raise ValueError(f"temperature must be in [0, 100] (0 = greedy), got {self.temperature!r}")
        if top_p is not None and not 0.0 < top_p <= 1.0:
            raise ValueError(f"top_p must be in (0, 1] or None, got {self.top_p!r}")
        if not math.isfinite(guidance) or not 0 <= guidance <= 100:
            raise ValueError(f"guidance must be in [0, 100] (1 = off), got {self.guidance!r}")
        object.__setattr__(self, "temperature", temperature)
        object.__setattr__(self, "top_k", int(top_k) if top_k else None)
        object.__setattr__(self, "top_p", top_p)
        object.__setattr__(self, "guidance", guidance)

    @property
    def greedy(self) -> bool:
        return self.temperature == 0.0

    def to_dict(self) -> dict:
        return asdict(self)


GREEDY = SamplingConfig(temperature=0.0)


def apply_guidance(cond: np.ndarray, uncond: np.ndarray, scale: float) -> np.ndarray:
    """Classifier-free guidance on logits: uncond + scale * (cond - uncond)."""
    return uncond + scale * (cond - uncond)


def sample(logits: np.ndarray, config: SamplingConfig, rngs: list[np.random.Generator]) -> np.ndarray:
    """Pick one token per row.

    logits: (B, L, V) float, one row of L level streams per prompt; rngs: one generator per prompt, so a
    prompt's tokens do not depend on which other prompts share its batch. Returns (B, L) int64.
    """
    B, L, V = logits.shape
    if len(rngs) != B:
        raise ValueError(f"need one random generator per prompt: {B} prompts, {len(rngs)} generators")
    if config.greedy:
        return logits.argmax(-1).astype(np.int64)
    z = logits.astype(np.float64) / config.temperature                       # (B, L, V)
    order = np.argsort(-z, axis=-1, kind="stable")                           # (B, L, V) best first
    z_sorted = np.take_along_axis(z, order, axis=-1)
    if config.top_k is not None and config.top_k < V:
        z_sorted[..., config.top_k:] = -np.inf
    probs = np.exp(z_sorted - z_sorted[..., :1])
    probs /= probs.sum(-1, keepdims=True)
    if config.top_p is not None and config.top_p < 1.0:
        # Keep a code while the mass before it is below top_p: the most likely code always survives.
        mass_before = np.cumsum(probs, axis=-1) - probs
        probs = np.where(mass_before < config.top_p, probs, 0.0)
        probs /= probs.sum(-1, keepdims=True)
    cdf = np.cumsum(probs, axis=-1)                                          # (B, L, V)
    u = np.stack([rng.random(L) for rng in rngs])[..., None]                # (B, L, 1)
    pick = np.minimum((cdf < u * cdf[..., -1:]).sum(-1), V - 1)              # (B, L) index into sorted
    return np.take_along_axis(order, pick[..., None], axis=-1)[..., 0].astype(np.int64)
