"""A bounded correction of where a steered character's motion stands on the floor: a rigid turn and shift of the
whole motion (about the vertical axis), eased in over each token's frames, that closes what is left between where
the model walked and where the game asked.

The model reads the game's request (the control vector) and picks its tokens to follow it, but its codes keep the
root's path only approximately (a turn of 90 degrees decodes as 60-100), so a character left to the model alone
drifts off a path. The correction rotates the motion at most MAX_TURN and shifts it at most MAX_SHIFT per frame:
a planted toe about 0.15 m from the root moves under 1.2 cm a frame by the turn, 1 cm by the shift, against the
2.5 cm a frame at which the skating measure (mogo_eval.streaming) counts a toe as sliding. What it costs in foot
contact is measured (benchmarks/control.py, "feet").

A point p (x, z) of the model's motion stands at M(phi) p + t, M(a) = [[cos a, sin a], [-sin a, cos a]] (turning
facing (sin yaw, cos yaw) into yaw + a, as control/vector.py has yaw).
"""
from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

from .plant import FootPlant

MAX_TURN = math.radians(4.5)    # per frame: 90 degrees a second
MAX_SHIFT = 0.01                # m per frame: 0.2 m/s
GAIN = 0.5                      # of the error corrected over one token (then read again: a closed loop)

# Scalar arithmetic throughout (no matrix products, no hypot): a BLAS product may fuse a multiply-add and hypot is
# not correctly rounded everywhere, and the pose read through the warp feeds the control vector, whose tokens the
# JavaScript runtime must reproduce bit for bit.


def wrap(a: float) -> float:
    """An angle into [-pi, pi], by whole turns (subtraction only: the same bits in every runtime)."""
    while a > math.pi:
        a -= math.tau
    while a < -math.pi:
        a += math.tau
    return a


def turned(a: float, x, z, xp=math):
    """(x, z) turned by a: M(a) (x, z); `xp` math (Python floats) or numpy (arrays: a crowd's lanes, the same bits)."""
    c, s = xp.cos(a), xp.sin(a)
    return c * x + s * z, -s * x + c * z


def _eased(xp, phi, tx, tz, turn, sx, sz, px, pz, f):
    """An ease's warp (phi, tx, tz) a fraction f of the way in: the one rule, on floats (`Ease.at`) or lanes
    (`RootWarp.warps_many`)."""
    a = turn * f
    x, z = turned(a, tx - px, tz - pz, xp)
    return phi + a, x + px + sx * f, z + pz + sz * f


class Ease(NamedTuple):
    """From frame `start` on: the warp (phi, tx, tz), then a turn about (px, pz) and a shift eased in over
    `frames`."""
    start: int
    phi: float
    tx: float
    tz: float
    turn: float
    sx: float
    sz: float
    px: float
    pz: float
    frames: int

    def at(self, k: int) -> tuple[float, float, float]:
        """The warp (phi, tx, tz) k frames into the ease (k >= frames: all of it)."""
        f = min(k, self.frames) / self.frames if self.frames else 0.0
        return _eased(math, self.phi, self.tx, self.tz, self.turn, self.sx, self.sz, self.px, self.pz, f)


PLANS_KEPT = 64    # a token-stream writer (wire/tap.py) reads the plans every token; more unread is an error there


class RootWarp:
    def __init__(self, legs: tuple[tuple[int, ...], ...] | None = None):
        """`legs`: each leg's joints, hip to toe (plant.legs_of): the feet the warp moves are planted again
        (control/plant.py); None: the whole frame moves, feet and all."""
        self.plant = FootPlant(legs) if legs else None
        self.eases: deque[Ease] = deque([Ease(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0)], maxlen=3)
        self.active = False                       # no correction yet: frames pass through untouched
        # `plan`'s arguments as given, newest last, and how many there were: a client that replays them places
        # frames where this warp does (the token stream's WARP records)
        self.plans: deque[tuple[int, int, float, float, float, float, float]] = deque(maxlen=PLANS_KEPT)
        self.planned = 0

    def _warp(self, frame: int) -> tuple[float, float, float]:
        ease = self._ease(frame)
        if ease is None:
            first = self.eases[0]
            return first.phi, first.tx, first.tz      # older than every ease kept: a frame shown that late
        return ease.at(frame - ease.start + 1)

    def _ease(self, frame: int) -> Ease | None:
        """The ease `frame` is in (its warp: `.at(frame - .start + 1)`); None: older than every ease kept."""
        for ease in reversed(self.eases):
            if frame >= ease.start:
                return ease
        return None

    @staticmethod
    def warps_many(warps: list["RootWarp"], frames: list[range]) -> np.ndarray:
        """The warp (phi, tx, tz) of the frames frames[b] (consecutive) of warps[b], for many at once (a crowd's):
        (frames in all, 3) float64, the same numbers as `_warp` one by one (the ease's rule on lanes)."""
        if len(warps) == 1:     # a lone stream: Python floats (numpy's calls cost more than a few frames' arithmetic)
            return np.array([warps[0]._warp(f) for f in frames[0]]).reshape(-1, 3)
        eases, first, counts, late = [], [], [], []
        for w, numbers in zip(warps, frames):
            newest = w.eases[-1]
            if numbers and numbers[0] >= newest.start:      # the common case: every frame in the newest ease
                eases.append(newest)
                first.append(numbers[0] - newest.start + 1)
                counts.append(len(numbers))
                continue
            for frame in numbers:
                ease = w._ease(frame)
                if ease is None:
                    late.append((sum(counts), w.eases[0]))
                    ease = w.eases[0]
                eases.append(ease)
                first.append(frame - ease.start + 1)
                counts.append(1)
        e = np.repeat(np.array(eases, np.float64).reshape(-1, len(Ease._fields)), counts, axis=0).T
        # k: each frame's place in its ease, first[i], first[i] + 1, ... for each run of frames
        k = np.arange(len(e[0]), dtype=np.float64) + np.repeat(np.array(first) - (np.cumsum(counts) - counts),
                                                                 counts)
        n = e[9]
        f = np.where(n > 0, np.minimum(k, n) / np.where(n > 0, n, 1.0), 0.0)
        out = np.stack(_eased(np, *e[1:9], f), axis=1)
        for row, oldest in late:
            out[row] = oldest.phi, oldest.tx, oldest.tz
        return out

    def pose(self, model_pose: np.ndarray, frame: int) -> np.ndarray:
        """The pose (x, z, yaw) of the model's motion at `frame` -> where it stands (the eases planned so far; a
        frame past them where the last one ends)."""
        x, z, yaw = (float(v) for v in model_pose)
        if self.active:
            phi, tx, tz = self._warp(frame)
            x, z = turned(phi, x, z)
            x, z, yaw = x + tx, z + tz, yaw + phi
        return np.array([x, z, yaw])

    @staticmethod
    def poses_many(warps: list["RootWarp"], model_poses: np.ndarray, frames: list[int]) -> np.ndarray:
        """`pose` for many streams at once (a crowd's), the same numbers: poses (B, 3), stream b's at frame
        frames[b] -> (B, 3) float64, where each stands."""
        out = np.array(model_poses, np.float64)
        active = [b for b, w in enumerate(warps) if w.active]
        if active:
            phi, tx, tz = RootWarp.warps_many([warps[b] for b in active], [range(frames[b], frames[b] + 1)
                                                                           for b in active]).T
            x, z = turned(phi, out[active, 0], out[active, 1], np)
            out[active] = np.stack([x + tx, z + tz, out[active, 2] + phi], axis=1)
        return out

    def plan(self, start: int, frames: int, pose: np.ndarray, turn: float, shift) -> None:
        """From frame `start`: ease in a turn of GAIN * `turn` rad about `pose` (x, z, where it stands) and a shift
        of GAIN * `shift` (x, z) over `frames` frames, bounded by MAX_TURN and MAX_SHIFT a frame."""
        self.plans.append((start, frames, float(pose[0]), float(pose[1]), float(turn), float(shift[0]),
                           float(shift[1])))
        self.planned += 1
        turn = min(max(GAIN * turn, -MAX_TURN * frames), MAX_TURN * frames)
        sx, sz = GAIN * float(shift[0]), GAIN * float(shift[1])
        norm = math.sqrt(sx * sx + sz * sz)
        if norm > MAX_SHIFT * frames:
            scale = MAX_SHIFT * frames / norm
            sx, sz = sx * scale, sz * scale
        phi, tx, tz = self._warp(start - 1)
        self.eases.append(Ease(start, phi, tx, tz, turn, sx, sz, float(pose[0]), float(pose[1]), frames))
        self.active = self.active or turn != 0.0 or norm > 0.0

    def joints(self, index: int, joints: np.ndarray) -> np.ndarray:
        """Frames (n, J, 3) numbered index.. (each once, in order) -> where they stand, feet planted."""
        return RootWarp.joints_many([self], [index], np.asarray(joints)[None])[0]

    @staticmethod
    def joints_many(warps: list["RootWarp"], index: list[int], joints: np.ndarray) -> np.ndarray:
        """`joints` for many streams at once (a crowd's), the same numbers: frames (B, n, J, 3), stream b's numbered
        index[b].. -> where they stand, feet planted."""
        B, n = joints.shape[:2]
        active = [b for b, w in enumerate(warps) if w.active]
        # a frame the warp leaves where it was (before the first correction: the eases' zero warp) is not moved
        moved = np.zeros((B, n), bool)
        out = joints
        if active and n:
            # (phi, tx, tz) of each frame of each active stream
            warp = RootWarp.warps_many([warps[b] for b in active],
                                       [range(index[b], index[b] + n) for b in active]).reshape(-1, n, 3, 1)
            phi, tx, tz = warp[:, :, 0], warp[:, :, 1], warp[:, :, 2]
            c, s = np.cos(phi), np.sin(phi)
            every = len(active) == B
            turned = (joints if every else joints[active]).astype(np.float64)
            x, z = turned[..., 0], turned[..., 2]
            # turned(phi, x, z) frame by frame, the same products and sums
            turned[..., 0], turned[..., 2] = c * x + s * z + tx, -s * x + c * z + tz
            if every:
                out, moved = turned.astype(joints.dtype), warp[..., 0].any(axis=2)
            else:
                out = joints.copy()
                out[active], moved[active] = turned, warp[..., 0].any(axis=2)
        if warps[0].plant is None:
            return out
        return FootPlant.apply_many([w.plant for w in warps], out, moved)
