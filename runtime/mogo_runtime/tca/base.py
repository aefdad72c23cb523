"""The aligner interface: `Aligner` (raw prompt -> `AlignedPrompt`) and `apply_alignment` (-> conditioning).

Kept apart from the aligners so that checking `align=` against the interface, or writing a custom aligner, loads
no lexicon and no caption index.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import KW_ONLY, dataclass, field
from typing import Callable

import numpy as np


@dataclass
class AlignedPrompt:
    """What the model is conditioned on for one prompt.

    text: the aligned prompt, encoded by the bundle's text encoder (shown to the user, returned as
    `Motion.aligned_text`); method: how it was made ("none": the prompt as typed, "normalize", "nearest",
    "chat", or a custom aligner's name); details: the intermediate steps (clauses, neighbours and their
    similarities, fallback reason ...) for inspection and logs.
    """
    text: str
    _: KW_ONLY          # AlignedPrompt(text, None, method) of the removed `embedding` field fails loudly
    method: str
    details: dict = field(default_factory=dict)


class Aligner(ABC):
    """Raw prompt -> AlignedPrompt. Implementations never raise on odd wording; they return their best try."""

    @abstractmethod
    def align(self, text: str) -> AlignedPrompt:
        ...

    def align_batch(self, texts: list[str]) -> list[AlignedPrompt]:
        return [self.align(t) for t in texts]


def apply_alignment(prompts: list[AlignedPrompt], encode: Callable[[list[str]], np.ndarray]) -> np.ndarray:
    """The conditioning embeddings of aligned prompts: their texts encoded, (N, text_dim) float32."""
    return np.array(encode([p.text for p in prompts]), np.float32, copy=True)
