"""Planted feet for a steered character: a toe on the floor stays where it was put down while the steering moves the
body under it (the root warp's turn and shift, control/warp.py; a game's capsule), and the leg reaches it, as a
game's foot IK does.

The steering moves a whole frame rigidly, so a planted toe would slide with the body: up to ~2 cm a frame by the
warp, as far as the capsule and the motion differ under a game-owned root. Frame by frame, for each leg (hip, knee,
ankle, toe: `legs_of`):

- a toe below PLANT_HEIGHT is on the floor: from the frame it touched down, its (x, z) is pinned, and the foot (ankle
  and toe) is shifted by the offset d = pin - toe, y untouched;
- a lifted foot keeps RELEASE of its offset a frame, so it swings back onto the motion's own path in the air;
- the ankle stays within REACH of the leg's length from the hip: a longer offset is shortened along itself until it
  fits (the pin moves with it: the foot slides only as far as the leg cannot stretch);
- the knee is placed by two-bone IK: in the plane of hip, new ankle and the motion's own knee, thigh and shin keeping
  this frame's lengths.

Causal, its state the pins and offsets: a stream decoded in chunks of any size gets the same joints. Scalar float64
arithmetic on the float32 joints, then float32 again, and only + - * / sqrt (each correctly rounded): the same bits in
every runtime (js/src/control/plant.js). What it buys is measured in benchmarks/control.py ("feet").
"""
from __future__ import annotations

import math

import numpy as np

PLANT_HEIGHT = 0.05    # m: a toe below this is on the floor (as the skating measure counts contact)
RELEASE = 0.7          # of a lifted foot's offset kept a frame: back on the motion's path within ~10 frames
REACH = 0.995          # of the leg's length (thigh + shin): the farthest the ankle goes from the hip


def legs_of(skeleton) -> tuple[tuple[int, ...], ...]:
    """Each leg (left, right) as (hip, knee, ankle, ..., toe): the chain from the root's child down to the toe of
    the foot contact joints, the foot being every joint from the third on (HumanML3D: hip, knee, ankle, toe; KIT's
    foot has a joint between ankle and toe)."""
    legs = []
    for toe in (skeleton.foot_left[1], skeleton.foot_right[1]):
        chain = [toe]
        while skeleton.parents[chain[-1]] != skeleton.root:
            chain.append(skeleton.parents[chain[-1]])
        if len(chain) < 4:
            raise ValueError(f"skeleton {skeleton.name!r}: a leg of hip, knee, ankle and toe is needed to plant feet")
        legs.append(tuple(reversed(chain)))
    return tuple(legs)


class FootPlant:
    def __init__(self, legs: tuple[tuple[int, ...], ...]):
        self.legs = legs
        # the legs' joints, and each leg as positions among them: only those rows are read and written
        self._joints = sorted({j for leg in legs for j in leg})
        self._legs = [tuple(self._joints.index(j) for j in leg) for leg in legs]
        self.pins: list[tuple[float, float] | None] = [None] * len(legs)     # a planted toe's (x, z)
        self.offsets: list[tuple[float, float]] = [(0.0, 0.0)] * len(legs)  # the foot's shift on the last frame

    def apply(self, joints: np.ndarray, moved) -> np.ndarray:
        """Frames (n, J, 3) float32, in order after the last ones applied -> the same with planted feet. `moved`:
        whether the steering moved them (one bool, or one per frame); a frame it did not move plants nothing new,
        and an offset left from before fades as a lifted foot's does (a stream never steered: its frames as they
        are)."""
        moved = [moved] * len(joints) if isinstance(moved, bool) else list(moved)
        if not any(moved) and not any(self.pins) and not any(dx or dz for dx, dz in self.offsets):
            return joints
        out = joints.copy()
        frames = out[:, self._joints].tolist()      # float64 values of the float32 joints
        for rows, m in zip(frames, moved):
            for i, leg in enumerate(self._legs):
                self._leg(i, leg, rows, m)
        out[:, self._joints] = frames               # float32 again
        return out

    def _leg(self, i: int, leg: tuple[int, ...], rows: list[list[float]], moved: bool) -> None:
        hip, knee, ankle, toe = rows[leg[0]], rows[leg[1]], rows[leg[2]], rows[leg[-1]]
        pin = self.pins[i]
        if moved and toe[1] < PLANT_HEIGHT:
            if pin is None:               # touched down: where it shows now, with the offset it has
                pin = (toe[0] + self.offsets[i][0], toe[2] + self.offsets[i][1])
            dx, dz = pin[0] - toe[0], pin[1] - toe[2]
        else:
            pin = None
            dx, dz = self.offsets[i][0] * RELEASE, self.offsets[i][1] * RELEASE
        hx, hy, hz = hip
        kx, ky, kz = knee
        ax, ay, az = ankle
        l1 = math.sqrt((kx - hx) * (kx - hx) + (ky - hy) * (ky - hy) + (kz - hz) * (kz - hz))
        l2 = math.sqrt((ax - kx) * (ax - kx) + (ay - ky) * (ay - ky) + (az - kz) * (az - kz))
        reach = REACH * (l1 + l2)
        bx, by, bz = ax - hx, ay - hy, az - hz
        ex, ez = bx + dx, bz + dz
        if ex * ex + by * by + ez * ez > reach * reach:
            # shorten the offset along itself: |b + s d| = reach, 0 <= s < 1 (s = 0 where the motion itself is
            # out of reach: its own foot, unplanted)
            a = dx * dx + dz * dz
            b = 2.0 * (bx * dx + bz * dz)
            c = bx * bx + by * by + bz * bz - reach * reach
            s = 0.0 if c >= 0.0 else (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
            dx, dz = dx * s, dz * s
            if pin is not None:
                pin = (toe[0] + dx, toe[2] + dz)
        self.pins[i], self.offsets[i] = pin, (dx, dz)
        if dx == 0.0 and dz == 0.0:
            return
        for j in leg[2:]:                 # the foot, ankle to toe
            rows[j][0], rows[j][2] = rows[j][0] + dx, rows[j][2] + dz
        knee[:] = _knee(hip, knee, ankle, l1, l2)

    def state(self) -> tuple[list[bool], list[float]]:
        """(pinned per leg, [pin x, z, offset x, z] per leg): all a stream's later joints depend on."""
        floats = []
        for pin, offset in zip(self.pins, self.offsets):
            floats += [*(pin or (0.0, 0.0)), *offset]
        return [pin is not None for pin in self.pins], floats

    def load(self, pinned, floats) -> None:
        """`state()`'s values back."""
        for i in range(len(self.legs)):
            x, z, dx, dz = (float(v) for v in floats[4 * i:4 * i + 4])
            self.pins[i] = (x, z) if pinned[i] else None
            self.offsets[i] = (dx, dz)


STATE_FLOATS = 8       # state()'s floats for two legs


def _knee(hip, knee, ankle, l1: float, l2: float) -> list[float]:
    """The knee of a leg from `hip` to `ankle` with thigh l1 and shin l2, bent the way the motion's `knee` is."""
    vx, vy, vz = ankle[0] - hip[0], ankle[1] - hip[1], ankle[2] - hip[2]
    d = math.sqrt(vx * vx + vy * vy + vz * vz)
    if d == 0.0:
        return knee
    ux, uy, uz = vx / d, vy / d, vz / d
    along = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d)           # the knee's distance along hip -> ankle
    side = math.sqrt(max(l1 * l1 - along * along, 0.0))      # and away from that line
    kx, ky, kz = knee[0] - hip[0], knee[1] - hip[1], knee[2] - hip[2]
    dot = kx * ux + ky * uy + kz * uz
    px, py, pz = kx - dot * ux, ky - dot * uy, kz - dot * uz  # the motion's bend, across the line
    n = math.sqrt(px * px + py * py + pz * pz)
    if n == 0.0:                  # a straight leg: no bend to keep
        side, n = 0.0, 1.0
    return [hip[0] + along * ux + side * (px / n), hip[1] + along * uy + side * (py / n),
            hip[2] + along * uz + side * (pz / n)]
