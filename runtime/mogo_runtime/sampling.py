"""Token sampling policy: temperature, top-k, top-p, classifier-free guidance; numpy only.

Kept apart from the network (as whisper's decoding.py does) so the same policy drives the torch reference
generator and the onnxruntime runtime, and a seed means the same tokens in both.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass

import numpy as np


def shown(value, limit: int = 60) -> str:
    """repr for an error message: cut short, and safe for an int too long for str() (which raises ValueError)."""
    try:
        text = repr(value)
    except ValueError:
        return f"an int of {value.bit_length()} bits"
    return text if len(text) <= limit else text[:limit] + "..."


def as_real(name: str, value, must: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    """`value` as a float in [lo, hi], else ValueError "{name} must be [a number] {must}, got ...".

    Any real scalar is a number here (Python, numpy, Fraction); a bool is not (True would run as 1), nor a
    string, nor an int too large for a float (float() raises OverflowError on it). NaN and infinity are numbers
    outside every range."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a number {must}, got {shown(value)}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not (math.isfinite(x) and lo <= x <= hi):
        raise ValueError(f"{name} must be {must}, got {shown(value)}")
    return x


def as_int(name: str, value, must: str, lo: int, hi: int | None = None) -> int:
    """`value` as an int in [lo, hi] (any integral scalar, numpy's included, never a bool), else ValueError."""
    if (isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral)
            or not lo <= value <= (math.inf if hi is None else hi)):
        raise ValueError(f"{name} must be {must}, got {shown(value)}")
    return int(value)


@dataclass(frozen=True)
class SamplingConfig:
    temperature: float = 1.0      # 0 = greedy (argmax), no randomness
    top_k: int | None = None      # keep the k most likely codes (None or 0 = all)
    top_p: float | None = None    # nucleus: keep the smallest set with this much mass (None = all)
    guidance: float = 1.0         # classifier-free guidance scale; 1 = off (no unconditional pass)

    def __post_init__(self):
        # one check for the API, the CLI and the manifest; values are stored as plain Python numbers
        temperature = as_real("temperature", self.temperature, "in [0, 100] (0 = greedy)", 0, 100)
        top_k = self.top_k
        if top_k is not None:
            top_k = as_int("top_k", top_k, "an int >= 1 (0 or None: no top-k cut)", 0) or None
        top_p = self.top_p
        if top_p is not None:   # (0, 1]: ulp(0) is the smallest float above 0
            top_p = as_real("top_p", top_p, "in (0, 1] or None", math.ulp(0.0), 1.0)
        guidance = as_real("guidance", self.guidance, "in [0, 100] (1 = off)", 0, 100)
        object.__setattr__(self, "temperature", temperature)
        object.__setattr__(self, "top_k", top_k)
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
