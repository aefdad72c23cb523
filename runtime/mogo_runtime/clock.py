"""Where the generation loop's time goes: wall time per named stage, summed over calls, for a profile.

    clock = StageClock()
    gen.generate("a person walks forward", seconds=10, clock=clock)
    clock.seconds      # {"text": ..., "step": ..., "sample": ..., "decode": ..., "joints": ...}
"""
from __future__ import annotations

import time
from contextlib import contextmanager, nullcontext


class StageClock:
    """Stages: text (prompt encoding), step (the step graph), sample (the step policy), decode (lookup and
    decoder graphs), joints (features to joints: root integration and foot lock)."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}

    @contextmanager
    def __call__(self, stage: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - start
            self.calls[stage] = self.calls.get(stage, 0) + 1


def NO_CLOCK(stage: str):   # noqa: N802 - a stand-in for a StageClock that measures nothing
    return nullcontext()
