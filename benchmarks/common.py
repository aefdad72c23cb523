"""What every benchmark case shares: the prompt and motion length, statistics, memory readings, and a profile of
one generation by the loop's own stage clock (mogo_runtime.clock)."""
from __future__ import annotations

import resource
import statistics
import time

PROMPT = "a person walks forward and then jumps"
MOTION_FRAMES = 196              # the 9.8 s motion at 20 fps
SOAK_LIMIT = 1.1                 # last interval / first, for both RSS and time per token (soaks)
STAGES = ("text", "step", "sample", "decode", "joints")   # the loop's stages (mogo_runtime.clock.StageClock)


def stats(xs: list[float]) -> dict:
    """median, min, max, quartiles of a list of seconds (or any numbers)."""
    xs = sorted(float(x) for x in xs)
    n = len(xs)
    if n == 0:
        return {"n": 0}
    q = statistics.quantiles(xs, n=4, method="inclusive") if n >= 2 else [xs[0]] * 3
    return {"n": n, "median": statistics.median(xs), "min": xs[0], "max": xs[-1], "q1": q[0], "q3": q[2],
            "values": xs}


def peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024       # Linux: kilobytes


def current_rss_bytes(field: str = "VmRSS") -> int | None:
    """VmRSS (now) or VmHWM (peak) from /proc: getrusage's peak lags behind the current value at times."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def read_manifest(bundle: str):
    """The bundle's typed manifest, without hashing files or opening graphs (the cold case measures those)."""
    from mogo_runtime.bundle import read_manifest

    return read_manifest(bundle)


def motion_tokens(dims, frames: int = MOTION_FRAMES) -> int:
    """Tokens of a `frames`-frame motion (what MotionGenerator.tokens_for(frames / fps) gives), capped at max."""
    return max(1, min(dims.max_tokens, int(round(frames / dims.downsample))))


def guided(manifest) -> bool:
    return manifest.sampling_defaults.guided


def profiled(run) -> dict:
    """`run(clock)`, one generation handed a StageClock: its wall time, the seconds and calls of each of the loop's
    stages, and what the loop spent outside them ("loop_other")."""
    from mogo_runtime.clock import StageClock

    clock = StageClock()
    t = time.perf_counter()
    run(clock)
    wall = time.perf_counter() - t
    parts = {stage: clock.seconds.get(stage, 0.0) for stage in STAGES}
    parts["loop_other"] = wall - sum(parts.values())
    return {"wall": wall, "parts": parts, "calls": dict(clock.calls)}
