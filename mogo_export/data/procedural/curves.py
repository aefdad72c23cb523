"""Keyframe curves the action families animate with: smooth interpolation through keys (`curve`, `Keys`),
periodic curves for gait cycles (`cyclic`), and easing (`ease`, `envelope`).

Pure functions of numpy arrays, kept apart from the poses so the interpolation rules (no overshoot past a
key, "stop" / "start" keys for take-off and landing) are stated in one place.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np


def _hermite(t: np.ndarray, times: np.ndarray, values: np.ndarray, slope_out: np.ndarray,
             slope_in: np.ndarray | None = None) -> np.ndarray:
    """Cubic Hermite through the keys; segment k leaves key k with slope_out[k], reaches k+1 with slope_in[k+1]."""
    slope_in = slope_out if slope_in is None else slope_in
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    h = times[k + 1] - times[k]
    s = np.clip((t - times[k]) / h, 0.0, 1.0)
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * values[k] + h10 * h * slope_out[k] + h01 * values[k + 1] + h11 * h * slope_in[k + 1]


def _slopes(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    # Catmull-Rom slopes, zeroed at local extrema so a curve never overshoots its keys (no knee past 0).
    m = np.zeros_like(values)
    d = np.diff(values) / np.diff(times)
    inner = (d[:-1] * d[1:]) > 0
    m[1:-1] = np.where(inner, (values[2:] - values[:-2]) / (times[2:] - times[:-2]), 0.0)
    return m


def curve(t: np.ndarray, keys: list[tuple]) -> np.ndarray:
    """Smooth interpolation through (time, value[, mode]) keys, constant before the first and after the last.

    mode "stop": the motion reaches the key at full speed (a quadratic ease-in) and stops there, as legs
    do at take-off; "start": it leaves the key at full speed, as legs that touch the floor and give way.
    """
    keys = sorted(keys, key=lambda k: k[0])
    times = np.array([k[0] for k in keys], dtype=np.float64)
    if len(keys) == 1:
        return np.full_like(t, keys[0][1], dtype=np.float64)
    times, idx = np.unique(times, return_index=True)  # a later key at the same time is dropped
    keys = [keys[i] for i in idx]
    values = np.array([k[1] for k in keys], dtype=np.float64)
    slope_out = _slopes(times, values)
    slope_in = slope_out.copy()
    d = np.diff(values) / np.diff(times)
    for i, key in enumerate(keys):
        mode = key[2] if len(key) > 2 else ""
        if mode == "stop" and i > 0:
            slope_in[i], slope_out[i] = 2 * d[i - 1], 0.0
        elif mode == "start" and i < len(keys) - 1:
            slope_in[i], slope_out[i] = 0.0, 2 * d[i]
    return _hermite(np.clip(t, times[0], times[-1]), times, values, slope_out, slope_in)


def cyclic(phase: np.ndarray, keys: list[tuple[float, float]]) -> np.ndarray:
    """Periodic smooth curve through (phase in [0, 1), value) keys, evaluated at any real phase."""
    keys = sorted(keys)
    ph = np.array([k[0] for k in keys])
    v = np.array([k[1] for k in keys])
    # wrap two keys on each side so the slopes at the seam see their periodic neighbours
    times = np.concatenate([ph[-2:] - 1, ph, ph[:2] + 1])
    values = np.concatenate([v[-2:], v, v[:2]])
    slopes = _slopes(times, values)
    return _hermite(np.mod(phase, 1.0), times, values, slopes)


def ease(x) -> np.ndarray:
    """Smoothstep of x clipped to [0, 1]: 0 -> 0, 1 -> 1, zero slope at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


class Keys:
    """Keyframed channels: `add(t, knee=40, hip=20)` keys values at time t; `k("knee", t)` interpolates."""

    def __init__(self, **start):
        self.pts: dict[str, list[tuple]] = defaultdict(list)
        if start:
            self.add(0.0, **start)

    def add(self, t: float, mode: str = "", **values: float) -> "Keys":
        """Key `values` at time t; mode "stop" / "start" as in `curve`."""
        for name, v in values.items():
            self.pts[name].append((float(t), float(v), mode))
        return self

    def __call__(self, name: str, t: np.ndarray, default: float = 0.0) -> np.ndarray:
        if name not in self.pts:
            return np.full(t.shape, default)
        return curve(t, self.pts[name])



def envelope(t: np.ndarray, start: float, stop: float, ramp: float) -> np.ndarray:
    """0 before `start`, eased up to 1 over `ramp` seconds, back down to 0 at `stop`."""
    return ease((t - start) / ramp) * ease((stop - t) / ramp)

