"""One face for every way this project generates, so evaluation and quality judge torch and bundles alike."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from mogo_runtime.bundle.sampling import SamplingConfig

if TYPE_CHECKING:
    from mogo_export.reference import TorchGenerator


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
    per_token = gen.dims.downsample / gen.dims.fps

    def generate(texts, seeds, num_tokens):
        motions = gen.generate(texts, seconds=None if num_tokens is None else num_tokens * per_token, seed=seeds,
                               sampling=sampling, align=align)
        return [m.features for m in motions]

    return FeatureGenerator(generate, gen.dims.downsample)
