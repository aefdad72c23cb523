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

Causal, its state the pins and offsets: a stream decoded in chunks of any size gets the same joints. float64
arithmetic on the float32 joints, then float32 again, and only + - * / sqrt (each correctly rounded): the same bits in
every runtime (js/src/control/plant.js), whether a leg is computed alone on Python floats (`apply`: a lone stream's
frame) or as a lane of numpy arrays (`apply_many`: a crowd's legs at once). What it buys is measured in
benchmarks/control.py ("feet").
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
        if len({len(leg) for leg in legs}) != 1:
            raise ValueError(f"legs of one length are planted together, got {legs}")
        self.legs = legs
        # the legs' joints, and each leg as positions among them: only those rows are read and written
        self._joints = sorted({j for leg in legs for j in leg})
        self._legs = [tuple(self._joints.index(j) for j in leg) for leg in legs]
        # each leg's state: whether its toe is planted, and [pin x, z (0 unplanted), the foot's shift x, z on the
        # last frame] one leg after another (a crowd gathers its streams' with one conversion)
        self.pinned: list[bool] = [False] * len(legs)
        self.values: list[float] = [0.0] * (4 * len(legs))

    def apply(self, joints: np.ndarray, moved) -> np.ndarray:
        """Frames (n, J, 3) float32, in order after the last ones applied -> the same with planted feet. `moved`:
        whether the steering moved them (one bool, or one per frame); a frame it did not move plants nothing new,
        and an offset left from before fades as a lifted foot's does (a stream never steered: its frames as they
        are)."""
        moved = [moved] * len(joints) if isinstance(moved, bool) else list(moved)
        v = self.values
        if not any(moved) and not any(self.pinned) and not any(v[2::4]) and not any(v[3::4]):
            return joints
        out = joints.copy()
        frames = out[:, self._joints].tolist()      # float64 values of the float32 joints
        for rows, m in zip(frames, moved):
            for i, leg in enumerate(self._legs):
                hip, knee, ankle = rows[leg[0]], rows[leg[1]], rows[leg[2]]
                dx, dz, shifted, bones, down, pin, offset = _plant(_FLOATS, hip, knee, ankle, rows[leg[-1]], m,
                                                                   self.pinned[i], v[4 * i:4 * i + 2],
                                                                   v[4 * i + 2:4 * i + 4])
                self.pinned[i] = down
                v[4 * i:4 * i + 4] = (*pin, *offset) if down else (0.0, 0.0, *offset)
                if shifted:
                    for j in leg[2:]:           # the foot, ankle to toe
                        rows[j][0] += dx
                        rows[j][2] += dz
                    rows[leg[1]] = list(_knee(_FLOATS, hip, knee, ankle, *bones))
        out[:, self._joints] = frames               # float32 again
        return out

    @staticmethod
    def apply_many(plants: list["FootPlant"], joints: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """`apply` for many streams at once (a crowd's), the same numbers: joints (B, n, J, 3) float32, stream b's
        next n frames, `moved` (B, n) bool -> the same with planted feet. Each leg of each stream is a lane of
        numpy's elementwise float64 arithmetic, the frames in order: a lane's numbers do not depend on the others'."""
        B, n = joints.shape[:2]
        if B == 1:          # a lone stream: Python floats (numpy's cost per call is ~10x the arithmetic of 2 lanes)
            return plants[0].apply(joints[0], np.asarray(moved, bool)[0].tolist())[None]
        legs = plants[0].legs
        if any(p.legs != legs for p in plants):
            raise ValueError("apply_many plants the feet of streams of one skeleton")
        L, K = len(legs), len(legs[0])
        # lane b * L + i: leg i of stream b
        pinned = np.array([p.pinned for p in plants]).reshape(B * L)
        values = np.array([p.values for p in plants], np.float64).reshape(B * L, 4).T
        pins, offsets = values[:2], values[2:]
        moved = np.repeat(np.asarray(moved, bool), L, axis=0)                       # (B * L, n)
        if not moved.any() and not pinned.any() and not offsets.any():
            return joints
        index = np.array(legs)                                                       # (L, K)
        # (n, K, 3, lanes): each coordinate of a joint over the lanes is one contiguous row
        x = np.ascontiguousarray(joints[:, :, index].astype(np.float64).transpose(1, 3, 4, 0, 2))
        x = x.reshape(n, K, 3, B * L)
        for f in range(n):
            leg = x[f]
            dx, dz, shifted, bones, pinned, pins, offsets = _plant(
                _LANES, leg[0], leg[1], leg[2], leg[K - 1], moved[:, f], pinned, pins, offsets)
            leg[2:, 0] = np.where(shifted, leg[2:, 0] + dx, leg[2:, 0])          # the foot, ankle to toe
            leg[2:, 2] = np.where(shifted, leg[2:, 2] + dz, leg[2:, 2])
            leg[1] = np.where(shifted, np.stack(_knee(_LANES, leg[0], leg[1], leg[2], *bones)), leg[1])
        out = joints.copy()
        out[:, :, index] = x.reshape(n, K, 3, B, L).transpose(3, 0, 4, 1, 2)        # float32 again
        values = np.stack([*(np.where(pinned, q, 0.0) for q in pins), *offsets], axis=1).reshape(B, 4 * L)
        for p, on, v in zip(plants, pinned.reshape(B, L).tolist(), values.tolist()):
            p.pinned, p.values = on, v
        return out

    def state(self) -> tuple[list[bool], list[float]]:
        """(pinned per leg, [pin x, z, offset x, z] per leg): all a stream's later joints depend on."""
        return list(self.pinned), list(self.values)

    def load(self, pinned, floats) -> None:
        """`state()`'s values back."""
        self.pinned = [bool(on) for on in pinned[:len(self.legs)]]
        self.values = [float(v) if self.pinned[i // 4] or i % 4 >= 2 else 0.0        # an unplanted leg's pin: 0
                       for i, v in enumerate(floats[:4 * len(self.legs)])]


STATE_FLOATS = 8       # state()'s floats for two legs


class _FLOATS:
    """Python floats: one leg of one frame (a lone stream's: numpy's cost per call is ~10x the arithmetic's)."""
    sqrt = staticmethod(math.sqrt)

    @staticmethod
    def where(condition, a, b):
        return a if condition else b


class _LANES:
    """numpy arrays: one frame of many legs (a crowd's), each a lane."""
    sqrt = staticmethod(np.sqrt)
    where = staticmethod(np.where)


def _plant(xp, hip, knee, ankle, toe, moved, pinned, pin, offset):
    """The rule above, for one frame of a leg: `xp` computes on Python floats (_FLOATS) or on lanes (_LANES); each
    point is (x, y, z), `pin` and `offset` (x, z) of the leg's state. Both sides of a choice are computed, the lane
    taking its own (divisions guarded, so a side not taken raises nothing). -> (dx, dz) the foot's shift, whether it
    shifts, the thigh's and shin's lengths (l1, l2: `_knee` places the knee of a shifted foot), and the state after
    the frame: (down, pin, offset)."""
    where, sqrt = xp.where, xp.sqrt
    (hx, hy, hz), (kx, ky, kz), (ax, ay, az), (tx, ty, tz) = hip, knee, ankle, toe
    down = moved & (ty < PLANT_HEIGHT)
    # touched down: the pin is where the toe shows now, with the offset it has; lifted, the offset fades
    px, pz = where(pinned, pin[0], tx + offset[0]), where(pinned, pin[1], tz + offset[1])
    dx, dz = where(down, px - tx, offset[0] * RELEASE), where(down, pz - tz, offset[1] * RELEASE)
    ux, uy, uz, vx, vy, vz = kx - hx, ky - hy, kz - hz, ax - kx, ay - ky, az - kz    # thigh, shin
    l1, l2 = sqrt(ux * ux + uy * uy + uz * uz), sqrt(vx * vx + vy * vy + vz * vz)
    reach = REACH * (l1 + l2)
    bx, by, bz = ax - hx, ay - hy, az - hz
    ex, ez = bx + dx, bz + dz
    # out of reach: the offset shortened along itself, |b + s d| = reach, 0 <= s < 1 (s = 0 where the motion itself
    # is out of reach: its own foot, unplanted); the pin moves with it
    far = ex * ex + by * by + ez * ez > reach * reach
    a = dx * dx + dz * dz
    b = 2.0 * (bx * dx + bz * dz)
    c = bx * bx + by * by + bz * bz - reach * reach
    root = b * b - 4.0 * a * c
    s = where(c >= 0.0, 0.0, (-b + sqrt(where(root < 0.0, 0.0, root))) / where(a == 0.0, 1.0, 2.0 * a))
    dx, dz = where(far, dx * s, dx), where(far, dz * s, dz)
    px, pz = where(far, tx + dx, px), where(far, tz + dz, pz)
    shifted = (dx != 0.0) | (dz != 0.0)
    return dx, dz, shifted, (l1, l2), down, (px, pz), (dx, dz)


def _knee(xp, hip, knee, ankle, l1, l2):
    """The knee of a leg from `hip` to `ankle` with thigh l1 and shin l2, bent the way the motion's `knee` is (a leg
    whose ankle is on its hip: the motion's knee); `xp` as _plant's."""
    where, sqrt = xp.where, xp.sqrt
    vx, vy, vz = ankle[0] - hip[0], ankle[1] - hip[1], ankle[2] - hip[2]
    d = sqrt(vx * vx + vy * vy + vz * vz)
    on_hip = d == 0.0
    d = where(on_hip, 1.0, d)
    ux, uy, uz = vx / d, vy / d, vz / d
    along = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d)           # the knee's distance along hip -> ankle
    side = l1 * l1 - along * along                            # and away from that line
    side = sqrt(where(side < 0.0, 0.0, side))
    kx, ky, kz = knee[0] - hip[0], knee[1] - hip[1], knee[2] - hip[2]
    dot = kx * ux + ky * uy + kz * uz
    px, py, pz = kx - dot * ux, ky - dot * uy, kz - dot * uz  # the motion's bend, across the line
    n = sqrt(px * px + py * py + pz * pz)
    straight = n == 0.0                                       # a straight leg: no bend to keep
    side, n = where(straight, 0.0, side), where(straight, 1.0, n)
    return (where(on_hip, knee[0], hip[0] + along * ux + side * (px / n)),
            where(on_hip, knee[1], hip[1] + along * uy + side * (py / n)),
            where(on_hip, knee[2], hip[2] + along * uz + side * (pz / n)))
