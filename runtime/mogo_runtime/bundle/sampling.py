"""The sampling settings: what a user passes to generate, stream or a crowd, and what a manifest's
`sampling_defaults` section holds. The policy that applies them is `mogo_runtime.policy`."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from ..checks import as_int, as_real


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

    @property
    def guided(self) -> bool:
        """Whether each stream runs a second, unconditional step row (classifier-free guidance)."""
        return self.guidance != 1.0

    def to_dict(self) -> dict:
        return asdict(self)


GREEDY = SamplingConfig(temperature=0.0)


def sampling_or(defaults: SamplingConfig, sampling: SamplingConfig | None) -> SamplingConfig:
    """`sampling`, or `defaults` (the bundle's) for None; ValueError for anything else."""
    if sampling is not None and not isinstance(sampling, SamplingConfig):
        raise ValueError(f"sampling must be a SamplingConfig or None (the bundle's defaults), got {sampling!r}")
    return defaults if sampling is None else sampling
