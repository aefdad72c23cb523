"""The step policy: what every loop (clips, endless streams, crowds) does with one step's logits, written once.

A loop runs `rows` step rows per stream (its prompt, and with classifier-free guidance the all-zero text embedding
the model was trained to see as "no text"), stream b's rows next to each other. From the newest step's logits the
policy picks each stream's tokens as whisper's decoding filters logits: guidance, then END allowed to the coarsest
level only (and there only where the loop allows the motion to end), then temperature, top-k and top-p, and one
uniform draw per level from the stream's own generator. numpy only, so the torch reference, onnxruntime and the
JavaScript runtime (js/src/policy.js, float for float) give the same tokens for a seed.
"""
from __future__ import annotations

import numpy as np

from .bundle.sampling import SamplingConfig
from .bundle.sections import ModelDims


class StepPolicy:
    """`condition` and `feed` lay out a batch's step rows; `pick` turns their logits into tokens."""

    def __init__(self, sampling: SamplingConfig, dims: ModelDims):
        self.sampling, self.dims = sampling, dims
        self.rows = 2 if sampling.guided else 1               # step rows per stream

    def condition(self, emb: np.ndarray) -> np.ndarray:
        """(B, text_dim) prompt embeddings -> (B * rows, text_dim): each prompt, then its unconditional row."""
        if self.rows == 1:
            return emb
        rows = np.zeros((2 * len(emb),) + emb.shape[1:], emb.dtype)
        rows[0::2] = emb
        return rows

    def feed(self, tokens: np.ndarray) -> np.ndarray:
        """(B, ...) tokens per stream -> the same for each of its rows."""
        return tokens if self.rows == 1 else np.repeat(tokens, 2, axis=0)

    def pick(self, logits: np.ndarray, may_end: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        """logits (B * rows, L, K + 1) of the newest step, may_end (B,) bool, one generator per stream -> (B, L)."""
        if self.rows == 2:
            logits = apply_guidance(logits[0::2], logits[1::2], self.sampling.guidance)
        logits = np.array(logits, dtype=np.float32)                              # own copy: masked below
        logits[:, 1:, self.dims.end_id] = -np.inf      # only the coarsest level may end the motion
        logits[~np.asarray(may_end, bool), 0, self.dims.end_id] = -np.inf
        return sample(logits, self.sampling, rngs)


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
    order, z_sorted = best_first(logits, z)
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


def best_first(logits: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's codes best first, in the order a stable sort of -z gives (ties by code: the JavaScript runtime's
    order), and z in that order; z is `logits` divided by a temperature > 0.

    numpy's unstable argsort is 2-3x faster (SIMD; 1.8 against 5.4-6.3 ms for 64 x 4 x 513 float32 logits on this
    project's machine, 11-17% of a crowd's tick). Where a row has no tie every sort gives the same order, and the
    logits' order is z's (dividing by a temperature > 0 keeps it); a row with a tie in z is sorted again, stably."""
    order = np.argsort(-logits, axis=-1, kind="quicksort")
    z_sorted = np.take_along_axis(z, order, axis=-1)
    tied = (z_sorted[..., 1:] == z_sorted[..., :-1]).any(-1)
    if tied.any():
        order[tied] = np.argsort(-z[tied], axis=-1, kind="stable")
        z_sorted[tied] = np.take_along_axis(z[tied], order[tied], axis=-1)
    return order, z_sorted


def expand_seeds(seed: int | list[int], batch: int) -> list[int]:
    """One seed per prompt: prompt i of a batch with seed s draws exactly what a lone run with s + i does."""
    if isinstance(seed, (list, tuple)):
        seeds = list(seed)
    elif isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be an int >= 0 or a list of them, got {seed!r}")
    else:
        seeds = [int(seed) + i for i in range(batch)]
    if len(seeds) != batch:
        raise ValueError(f"got {len(seeds)} seeds for {batch} prompts")
    for s in seeds:
        if isinstance(s, (bool, np.bool_)) or not isinstance(s, (int, np.integer)) or not 0 <= s < 2 ** 63:
            raise ValueError(f"seeds must be ints in [0, 2**63), got {s!r}")
    return [int(s) for s in seeds]


def make_rngs(seeds: list[int]) -> list[np.random.Generator]:
    """The random stream of each prompt: numpy's PCG64 seeded with the prompt's seed."""
    return [np.random.Generator(np.random.PCG64(s)) for s in seeds]
