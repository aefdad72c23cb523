"""What an action family returns (`Action`) and the time it may take (`TimeBudget`).

A family is a function `(rng, budget) -> Action`: it samples its parameters (speed, amplitude, side,
repetitions, duration) from the generator it is given, and fits its repetitions into the budget so a clip
is never cut in the middle of what its captions describe. The budget is an explicit, immutable value
because it differs between calls: a single action may use up to MAX_SECONDS, the first action of a
two-action sequence must leave room for the second (clips.py), an action of a long sequence gets what is
left of its 60 s (sequences.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .pose import MAX_SECONDS, Pose


@dataclass
class Action:
    family: str
    pose: Pose
    phrases: list[str]                  # third-person verb phrases, "{pos}" stands for his/her/their
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class TimeBudget:
    """Seconds an action may last (at most MAX_SECONDS; short actions still last MIN_SECONDS)."""
    seconds: float = MAX_SECONDS

    @classmethod
    def at_most(cls, seconds: float) -> "TimeBudget":
        """A budget of `seconds`, capped at MAX_SECONDS."""
        return cls(float(min(seconds, MAX_SECONDS)))

    def fit(self, count: int, per: float, fixed: float, lo: int = 1) -> int:
        """Largest count <= `count` (and >= lo) whose duration fixed + count * per fits the budget."""
        return int(max(lo, min(count, np.floor((self.seconds - 0.05 - fixed) / per))))


FULL_BUDGET = TimeBudget()

Family = Callable[[np.random.Generator, TimeBudget], Action]


def sample_speed(rng) -> str:
    """The pace most families sample: slow, normal or fast (each family sets its own cadence per pace)."""
    return str(rng.choice(["slow", "normal", "fast"], p=[0.3, 0.4, 0.3]))
