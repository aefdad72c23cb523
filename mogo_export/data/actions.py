"""The procedural action library: one function per motion family, returning joint-angle tracks and captions.

Every family samples its parameters (speed, amplitude, side, repetitions, duration) from the generator it
is given and returns an `Action`: per-frame local joint angles on the HUMANML3D skeleton, which frames are
airborne, and verb phrases that describe exactly those parameters ("walks forward slowly"). Turning angles
into joint positions with feet planted on the floor is procedural.py's job.

Angle conventions (degrees; the body faces +z, y is up, the person's left is +x):
  flex  > 0 swings a limb forward, knee/elbow > 0 bends them, dorsi > 0 lifts the toes,
  abd   > 0 moves a limb away from the body's midline, yaw > 0 turns left (counter-clockwise from above),
  pitch / bend > 0 leans forward, lean / roll > 0 leans to the body's left.
"""
from __future__ import annotations

from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

FPS = 20.0
NUM_JOINTS = 22
MIN_SECONDS, MAX_SECONDS = 2.05, 10.0    # 41..200 frames, so features (one frame fewer) keep T2M's 40..199
GRAVITY = 9.81

# HumanML3D joint indices
PELVIS, SPINE1, SPINE2, SPINE3, NECK = 0, 3, 6, 9, 12
SIDES = {  # per side: joint indices, and the sign that mirrors abduction / twist across the midline
    "left": dict(hip=1, knee=4, ankle=7, collar=13, shoulder=16, elbow=18, sign=1.0),
    "right": dict(hip=2, knee=5, ankle=8, collar=14, shoulder=17, elbow=19, sign=-1.0),
}
OTHER = {"left": "right", "right": "left"}


# ----------------------------------------------------------------------------------------------- curves

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


# ------------------------------------------------------------------------------------------------ poses

class Pose:
    """Joint-angle tracks of one clip, built by adding layers.

    angles[t, j] = (x, y, z) degrees. Joint j's local rotation is POSTURE[j] @ Rz(z) @ Rx(x) @ Ry(y): the
    twist (y) about the bone first, then flexion (x), then abduction (z). The root (joint 0) instead
    holds (pitch, yaw, roll) and rotates as Ry(yaw) @ Rx(pitch) @ Rz(-roll).
    """

    def __init__(self, num_frames: int):
        self.T = num_frames
        self.t = np.arange(num_frames) / FPS
        self.angles = np.zeros((num_frames, NUM_JOINTS, 3))
        self.flight = np.zeros(num_frames, dtype=bool)  # airborne frames: root follows a ballistic arc
        self.support = np.ones((num_frames, 2), dtype=bool)  # (left, right) feet allowed to carry the body
        self.air_speed = np.zeros(num_frames)           # m/s forward (body frame) while airborne

    def _add(self, j: int, axis: int, value) -> None:
        self.angles[:, j, axis] += np.broadcast_to(np.asarray(value, dtype=np.float64), (self.T,))

    def root(self, pitch=0.0, yaw=0.0, roll=0.0) -> None:
        self._add(PELVIS, 0, pitch)
        self._add(PELVIS, 1, yaw)
        self._add(PELVIS, 2, roll)

    def leg(self, side: str, flex=0.0, abd=0.0, yaw=0.0, knee=0.0, dorsi=0.0) -> None:
        """`yaw` turns the whole leg (foot included) about the vertical: > 0 points the toes left, either side."""
        s = SIDES[side]
        self._add(s["hip"], 0, -np.asarray(flex))
        self._add(s["hip"], 1, yaw)
        self._add(s["hip"], 2, s["sign"] * np.asarray(abd))
        self._add(s["knee"], 0, knee)
        self._add(s["ankle"], 0, -np.asarray(dorsi))

    def arm(self, side: str, flex=0.0, abd=0.0, twist=0.0, elbow=0.0, shrug=0.0, across=0.0) -> None:
        """twist > 0 rotates the upper arm outward, so a bent elbow lifts the forearm when abducted;
        across > 0 swings the whole arm about the (near vertical) collar -> shoulder bone toward the
        midline, the horizontal adduction of clapping and punching."""
        s = SIDES[side]
        self._add(s["collar"], 1, s["sign"] * np.asarray(across))
        self._add(s["collar"], 2, s["sign"] * np.asarray(shrug))
        self._add(s["shoulder"], 0, -np.asarray(flex))
        self._add(s["shoulder"], 1, s["sign"] * np.asarray(twist))
        self._add(s["shoulder"], 2, s["sign"] * np.asarray(abd))
        self._add(s["elbow"], 0, -np.asarray(elbow))

    def spine(self, bend=0.0, lean=0.0, twist=0.0) -> None:
        """Spread over the three spine joints; twist > 0 turns the shoulders to the left."""
        for j, w in ((SPINE1, 0.4), (SPINE2, 0.3), (SPINE3, 0.3)):
            self._add(j, 0, w * np.asarray(bend))
            self._add(j, 1, w * np.asarray(twist))
            self._add(j, 2, -w * np.asarray(lean))

    def head(self, nod=0.0, turn=0.0, tilt=0.0) -> None:
        self._add(NECK, 0, nod)
        self._add(NECK, 1, turn)
        self._add(NECK, 2, -np.asarray(tilt))

    def relaxed(self, arms: bool = True) -> None:
        """The neutral standing layer: arms hang slightly away from the body, elbows soft."""
        if arms:
            for side in SIDES:
                self.arm(side, abd=4.0, elbow=12.0, flex=3.0)
        self.spine(bend=2.0)


def flat_foot(pitch, flex, knee, lift=0.0):
    """Ankle dorsiflexion that keeps the foot at its standing pitch (minus `lift` degrees of heel raise).

    In the sagittal plane the foot's global pitch is the sum of the root, hip, knee and ankle rotations
    about x, so zeroing that sum keeps the sole parallel to the floor.
    """
    return np.asarray(pitch) - np.asarray(flex) + np.asarray(knee) - np.asarray(lift)


# ------------------------------------------------------------------------------------------------ gaits

@dataclass(frozen=True)
class GaitStyle:
    stance: float                       # fraction of the cycle a foot is on the floor
    hip: list                           # cyclic keys per leg, phase 0 = heel strike
    knee: list
    foot: list                          # foot pitch against the floor: > 0 heel up, < 0 toes up
    arm_swing: float                    # shoulder flexion per degree of the opposite hip
    elbow: tuple[float, float]          # (base, extra per degree of forward arm swing)
    lean: float                         # trunk pitch, degrees
    pelvis_yaw: float                   # pelvis rotation per degree of hip difference
    hip_lifts: bool = False             # hips raise the feet (stepping in place): scale them with lift


WALK = GaitStyle(
    stance=0.62,
    hip=[(0.0, 21), (0.12, 18), (0.5, -11), (0.62, -5), (0.75, 17), (0.85, 27)],
    knee=[(0.0, 3), (0.13, 15), (0.38, 4), (0.55, 20), (0.65, 50), (0.73, 62), (0.85, 25), (0.93, 2)],
    foot=[(0.0, -16), (0.07, -2), (0.12, 0), (0.45, 0), (0.52, 5), (0.62, 30), (0.7, 25), (0.8, 0),
          (0.9, -10)],
    arm_swing=0.9, elbow=(14.0, 0.5), lean=3.0, pelvis_yaw=0.15)

RUN = GaitStyle(
    stance=0.36,
    hip=[(0.0, 30), (0.2, 5), (0.36, -14), (0.5, -8), (0.72, 38), (0.88, 40)],
    knee=[(0.0, 18), (0.14, 38), (0.36, 18), (0.55, 90), (0.68, 105), (0.85, 45), (0.96, 20)],
    foot=[(0.0, -5), (0.08, 0), (0.2, 0), (0.3, 15), (0.36, 35), (0.5, 30), (0.7, 5), (0.9, -5)],
    arm_swing=1.1, elbow=(75.0, 0.2), lean=9.0, pelvis_yaw=0.12)

MARCH = GaitStyle(  # stepping in place, used to turn on the spot
    stance=0.55,
    hip=[(0.0, 0), (0.5, 0), (0.62, 18), (0.75, 28), (0.9, 10)],
    knee=[(0.0, 0), (0.5, 0), (0.62, 36), (0.75, 55), (0.9, 20)],
    foot=[(0.0, 0), (0.5, 0)],  # flat: a heel raise would push the toe through the floor
    arm_swing=0.0, elbow=(14.0, 0.0), lean=2.0, pelvis_yaw=0.0, hip_lifts=True)


def lock_foot_yaw(heading: np.ndarray, stance: np.ndarray) -> np.ndarray:
    """World yaw of one foot: frozen while it is on the floor, turning to the heading while it swings.

    Without this a turning pelvis would spin the planted foot about its contact point.
    """
    foot = heading.astype(np.float64).copy()
    T = len(heading)
    edges = np.flatnonzero(np.diff(stance.astype(np.int8))) + 1
    bounds = np.concatenate([[0], edges, [T]])
    held = heading[0]
    for a, b in zip(bounds[:-1], bounds[1:]):
        if stance[a]:
            foot[a:b] = held
        else:
            target = heading[min(b, T - 1)]
            w = ease((np.arange(a, b) - a + 1) / (b - a + 1))
            foot[a:b] = held + (target - held) * w
            held = target
    return foot


def gait(pose: Pose, phase: np.ndarray, amp: np.ndarray, style: GaitStyle, heading: np.ndarray,
         lift: np.ndarray | None = None, swing_scale: float = 1.0) -> dict[str, np.ndarray]:
    """Add a cyclic gait to `pose`. phase: left-leg cycles (the right leg is half a cycle later); amp scales
    the stride (hips, arms), lift (default amp) the knees and feet, so first and last steps can still
    clear the floor.

    Returns each leg's stance mask, for callers that need the contact phases.
    """
    out = {}
    hips = {}
    lift_amp = amp if lift is None else lift
    for side, offset in (("left", 0.0), ("right", 0.5)):
        ph = phase + offset
        hips[side] = (lift_amp if style.hip_lifts else amp) * cyclic(ph, style.hip)
        out[side] = (np.mod(ph, 1.0) < style.stance) | (amp < 0.05)
    pelvis_yaw = -style.pelvis_yaw * (hips["left"] - hips["right"])
    pose.root(yaw=heading + pelvis_yaw, pitch=amp * style.lean)
    pose.spine(twist=-0.8 * pelvis_yaw)
    for side, offset in (("left", 0.0), ("right", 0.5)):
        ph = phase + offset
        knee = lift_amp * cyclic(ph, style.knee)
        flex = hips[side] + amp * style.lean       # keep the legs' swing relative to the floor, not the trunk
        dorsi = flat_foot(amp * style.lean, flex, knee, lift=lift_amp * cyclic(ph, style.foot))
        yaw = lock_foot_yaw(heading, out[side]) - (heading + pelvis_yaw)
        pose.leg(side, flex=flex, knee=knee, dorsi=dorsi, yaw=yaw)
        # arms swing with the opposite leg
        swing = swing_scale * style.arm_swing * hips[OTHER[side]]
        elbow = style.elbow[0] * np.maximum(np.minimum(amp, 1.0), 0.2) + style.elbow[1] * np.maximum(swing, 0)
        pose.arm(side, flex=swing, abd=7.0, elbow=elbow)
    return out


def envelope(t: np.ndarray, start: float, stop: float, ramp: float) -> np.ndarray:
    """0 before `start`, eased up to 1 over `ramp` seconds, back down to 0 at `stop`."""
    return ease((t - start) / ramp) * ease((stop - t) / ramp)


# ----------------------------------------------------------------------------------------------- action

@dataclass
class Action:
    family: str
    pose: Pose
    phrases: list[str]                  # third-person verb phrases, "{pos}" stands for his/her/their
    params: dict = field(default_factory=dict)


_budget = [MAX_SECONDS]  # seconds the next action may last; see time_budget


@contextmanager
def time_budget(seconds: float):
    """Within the block, families fit their repetitions into `seconds` instead of MAX_SECONDS (the first
    part of a two-action sequence leaves room for the second)."""
    old = _budget[0]
    _budget[0] = float(min(seconds, MAX_SECONDS))
    try:
        yield
    finally:
        _budget[0] = old


def seconds_to_frames(seconds: float) -> int:
    """Frames for a timeline of `seconds`, at least MIN_SECONDS (short actions end holding their pose)."""
    return int(round(max(seconds, MIN_SECONDS) * FPS))


SPEED_WORDS = {"slow": "slowly", "normal": "", "fast": "quickly"}
COUNT_WORDS = {1: "once", 2: "twice", 3: "three times", 4: "four times", 5: "five times", 6: "six times",
               7: "seven times", 8: "eight times", 9: "nine times", 10: "ten times"}
NUMBER_WORDS = {1: "one", 2: "two", 3: "three", 4: "four", 5: "five", 6: "six", 7: "seven", 8: "eight",
                9: "nine", 10: "ten", 11: "eleven", 12: "twelve", 13: "thirteen", 14: "fourteen", 15: "fifteen",
                16: "sixteen", 17: "seventeen", 18: "eighteen", 19: "nineteen", 20: "twenty"}


def _speed(rng) -> str:
    return str(rng.choice(["slow", "normal", "fast"], p=[0.3, 0.4, 0.3]))


def _adv(speed: str) -> str:
    return (" " + SPEED_WORDS[speed]) if SPEED_WORDS[speed] else ""


# ---------------------------------------------------------------------------------------------- families
# Each family: (rng) -> Action. Durations stay within MIN_SECONDS..MAX_SECONDS by fitting the number of
# steps or repetitions, so a clip is never cut in the middle of what its captions describe.

def _fit(count: int, per: float, fixed: float, lo: int = 1) -> int:
    """Largest count <= `count` (and >= lo) whose duration fixed + count * per fits the time budget."""
    return int(max(lo, min(count, np.floor((_budget[0] - 0.05 - fixed) / per))))


def _times(n: int) -> str:
    return COUNT_WORDS[n]


def _locomotion(rng, style: GaitStyle, steps: int, cadence: float, stride: float, *, direction: float = 1.0,
                turn_deg: float = 0.0, swing_scale: float = 1.0, min_steps: int = 2):
    """Stand, take `steps` steps at `cadence` steps/s, stand. direction -1 plays the cycle backwards.

    Returns (pose, steps actually taken, stance masks per side, stride envelope).
    """
    lead_in, lead_out = rng.uniform(0.4, 0.9), rng.uniform(0.4, 0.9)
    steps = _fit(steps, 1.0 / cadence, lead_in + lead_out, lo=min_steps)
    walk_time = steps / cadence
    T = seconds_to_frames(lead_in + walk_time + lead_out)
    pose = Pose(T)
    t = pose.t
    start = lead_in
    stop = min(start + walk_time, t[-1] - 0.1)
    amp = stride * envelope(t, start, stop, 0.7 / cadence)
    # knees and feet settle before the first step (the heel of the stepping foot rises) and after the
    # last (the landed foot rolls flat), with the phase held
    lift = envelope(t, start - 0.3, stop + 0.3, 0.3)
    # The phase advances only while walking. Forward, it starts with the left foot just past heel strike
    # (the right foot's first move is a toe-off) and ends on a heel strike, as amplitude reaches 0, so
    # the last foot lands beside the other. Backward is the same played in reverse.
    cycles = 0.5 * steps - 0.12
    rate = np.where((t >= start) & (t < stop), cycles / (stop - start), 0.0)
    phase = (0.12 if direction > 0 else 0.0) + direction * np.cumsum(rate) / FPS
    heading = turn_deg * ease((t - start) / max(stop - start, 1e-3))
    pose.spine(bend=2.0)
    stance = gait(pose, phase, amp, style, heading, lift, swing_scale)
    pose.support = np.stack([stance["left"], stance["right"]], axis=1)
    return pose, steps, stance, amp


def walk_forward(rng) -> Action:
    speed = _speed(rng)
    cadence = {"slow": 1.35, "normal": 1.85, "fast": 2.2}[speed] * rng.uniform(0.92, 1.08)
    stride = {"slow": 0.8, "normal": 1.1, "fast": 1.25}[speed] * rng.uniform(0.9, 1.1)
    pose, steps, _, _ = _locomotion(rng, WALK, int(rng.integers(3, 13)), cadence, stride)
    n = NUMBER_WORDS[steps]
    adj = {"slow": "slow ", "normal": "", "fast": "quick "}[speed]
    phrases = [f"walks forward{_adv(speed)}", f"takes {n} {adj}steps forward",
               f"walks straight ahead{_adv(speed) or ' at a normal pace'}",
               f"{SPEED_WORDS[speed] or 'calmly'} walks forward {n} steps"]
    return Action("walk_forward", pose, phrases, dict(speed=speed, steps=steps))


def walk_backward(rng) -> Action:
    speed = str(rng.choice(["slow", "normal"]))
    cadence = {"slow": 1.2, "normal": 1.6}[speed] * rng.uniform(0.92, 1.08)
    stride = {"slow": 0.6, "normal": 0.8}[speed] * rng.uniform(0.9, 1.1)
    pose, steps, _, _ = _locomotion(rng, WALK, int(rng.integers(2, 9)), cadence, stride, direction=-1.0,
                                    swing_scale=0.6)
    n = NUMBER_WORDS[steps]
    adv = _adv(speed) or " carefully"
    phrases = [f"walks backward{_adv(speed)}", f"takes {n} steps backward", f"steps back {n} times"
               if steps <= 10 else f"steps back {n} steps", f"walks backwards{adv}", f"moves backward {n} steps"]
    return Action("walk_backward", pose, phrases, dict(speed=speed, steps=steps))


def walk_circle(rng) -> Action:
    speed = str(rng.choice(["slow", "normal"]))
    side = str(rng.choice(["left", "right"]))
    cadence = {"slow": 1.5, "normal": 1.85}[speed] * rng.uniform(0.92, 1.08)
    stride = {"slow": 0.8, "normal": 1.0}[speed] * rng.uniform(0.9, 1.1)
    turn = 360.0 if side == "left" else -360.0
    pose, steps, _, _ = _locomotion(rng, WALK, int(rng.integers(10, 17)), cadence, stride, turn_deg=turn,
                                    min_steps=10)
    clock = "counterclockwise" if side == "left" else "clockwise"
    phrases = [f"walks in a circle{_adv(speed)}", f"walks in a full circle to the {side}",
               f"walks around in a {clock} circle", f"walks in a circle turning {side}{_adv(speed)}",
               f"walks {clock} in a circle"]
    return Action("walk_circle", pose, phrases, dict(speed=speed, side=side, steps=steps))


def run(rng) -> Action:
    speed = _speed(rng)
    cadence = {"slow": 2.5, "normal": 2.8, "fast": 3.1}[speed] * rng.uniform(0.95, 1.05)
    stride = {"slow": 0.8, "normal": 1.0, "fast": 1.15}[speed] * rng.uniform(0.92, 1.08)
    pose, steps, stance, amp = _locomotion(rng, RUN, int(rng.integers(4, 17)), cadence, stride, min_steps=4)
    pose.flight = ~(stance["left"] | stance["right"]) & (amp > 0.6 * stride)
    verb = {"slow": "jogs", "normal": "runs", "fast": "runs"}[speed]
    adv = {"slow": " slowly", "normal": "", "fast": " quickly"}[speed]
    phrases = [f"{verb} forward{adv}", f"{verb} straight ahead", f"{verb} forward {NUMBER_WORDS[steps]} steps",
               {"slow": "jogs in a straight line", "normal": "runs in a straight line",
                "fast": "sprints forward"}[speed],
               {"slow": "is jogging forward", "normal": "is running forward", "fast": "runs forward fast"}[speed]]
    return Action("run", pose, phrases, dict(speed=speed, steps=steps))


def _jumps(rng, reps: int, height: float, distance: float, tempo: float) -> tuple[Pose, int]:
    """Crouch, push off with an arm swing, fly a ballistic arc of `height` m, land and absorb; repeat."""
    flight_time = np.sqrt(8.0 * height / GRAVITY)
    crouch, push, land, recover = 0.38 / tempo, 0.22, 0.2, 0.35 / tempo
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    per = crouch + push + flight_time + land + recover
    reps = _fit(reps, per, lead_in + lead_out)
    k = Keys(thigh=0, shank=0, pitch=0, arm=0, heel=0, elbow=12)
    fwd = min(distance, 1.5) / 1.5  # 0 in place .. 1 for a long jump forward
    t = lead_in
    offs = []
    for _ in range(reps):
        k.add(t, thigh=0, shank=0, pitch=0, arm=0, heel=0, elbow=12)
        t += crouch
        k.add(t, thigh=55 + 15 * fwd, shank=28, pitch=25 + 15 * fwd, arm=-35, heel=0, elbow=20)
        t += push
        k.add(t, "stop", thigh=-8 - 8 * fwd, shank=8 + 8 * fwd, pitch=8 + 10 * fwd, heel=35)  # take-off, legs straight
        k.add(t, arm=50, elbow=15)
        offs.append((t, t + flight_time))
        # legs reach down for the floor in the air and are already bending when they touch it, so the
        # landing does not stop the fall within one frame
        k.add(t + 0.5 * flight_time, thigh=8 + 20 * fwd, shank=-8, pitch=6, arm=100 - 30 * fwd, heel=15, elbow=25)
        t += flight_time
        k.add(t, "start", thigh=15 + 25 * fwd, shank=-2, pitch=8 + 8 * fwd, heel=5)  # touch-down
        k.add(t, arm=60, elbow=25)
        t += land
        k.add(t, thigh=50 + 10 * fwd, shank=22, pitch=25 + 10 * fwd, arm=25, heel=0, elbow=25)
        t += recover
    k.add(t, thigh=0, shank=0, pitch=0, arm=0, heel=0, elbow=12)
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    thigh, shank, pitch = k("thigh", tt), k("shank", tt), k("pitch", tt)
    flex, knee = thigh + pitch, thigh + shank
    pose.root(pitch=pitch)
    pose.spine(bend=0.3 * pitch)
    for side in SIDES:
        pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(pitch, flex, knee, lift=k("heel", tt)))
        pose.arm(side, flex=k("arm", tt) - pitch, abd=10, elbow=k("elbow", tt))
    for a, b in offs:
        air = (tt > a) & (tt < b)
        pose.flight |= air
        pose.air_speed[air] = distance / flight_time
    return pose, reps


def jump_in_place(rng) -> Action:
    reps = int(rng.choice([1, 1, 2, 2, 3, 4]))
    high = bool(rng.random() < 0.5)
    height = rng.uniform(0.3, 0.45) if high else rng.uniform(0.12, 0.25)
    pose, reps = _jumps(rng, reps, height, 0.0, rng.uniform(0.85, 1.2))
    adj = "high" if high else "a little"
    times = _times(reps)
    phrases = [f"jumps in place {times}", f"jumps up and down {times}" if reps > 1 else "jumps up once",
               f"jumps {adj} {times}", f"hops {adj} in place" + (f" {times}" if reps > 1 else ""),
               f"bends {{pos}} knees and jumps straight up {times}"]
    return Action("jump_in_place", pose, phrases, dict(reps=reps, high=high))


def jump_forward(rng) -> Action:
    reps = int(rng.choice([1, 1, 2, 3]))
    far = bool(rng.random() < 0.5)
    distance = rng.uniform(0.8, 1.2) if far else rng.uniform(0.35, 0.6)
    pose, reps = _jumps(rng, reps, rng.uniform(0.2, 0.35), distance, rng.uniform(0.85, 1.15))
    times = _times(reps)
    adj = "far" if far else "a short distance"
    phrases = [f"jumps forward {times}", f"jumps {adj} forward" + (f" {times}" if reps > 1 else ""),
               f"leaps forward {times}", f"swings {{pos}} arms and jumps forward {times}",
               f"does {NUMBER_WORDS[reps]} {'long' if far else 'short'} jumps forward" if reps > 1
               else f"does a {'long' if far else 'short'} jump forward"]
    return Action("jump_forward", pose, phrases, dict(reps=reps, far=far))


def _wave(rng, side: str) -> Action:
    waves = int(rng.integers(2, 7))
    high = bool(rng.random() < 0.5)
    freq = rng.uniform(1.3, 2.4)
    raise_t, lower_t = rng.uniform(0.4, 0.7), rng.uniform(0.4, 0.7)
    lead_in, lead_out = rng.uniform(0.3, 0.8), rng.uniform(0.3, 0.8)
    waves = _fit(waves, 1.0 / freq, lead_in + lead_out + raise_t + lower_t, lo=2)
    wave_t = waves / freq
    T = seconds_to_frames(lead_in + raise_t + wave_t + lower_t + lead_out)
    pose = Pose(T)
    t = pose.t
    up = lead_in + raise_t
    down = up + wave_t
    on = ease((t - lead_in) / raise_t) * ease((down + lower_t - t) / lower_t)
    abd = 140.0 if high else 95.0
    elbow0 = 180.0 - abd + 5.0
    osc = ease((t - up + 0.15) / 0.3) * ease((down + 0.15 - t) / 0.3) * np.sin(2 * np.pi * freq * (t - up))
    pose.relaxed()
    pose.arm(side, abd=on * abd, twist=on * 90.0, elbow=on * elbow0 + 28.0 * osc, flex=on * 15.0)
    pose.spine(lean=-on * 3.0 * SIDES[side]["sign"])
    pose.head(turn=on * 5.0 * SIDES[side]["sign"])
    times = _times(waves)
    where = "above {pos} head" if high else "at shoulder height"
    phrases = [f"waves with {{pos}} {side} hand", f"raises {{pos}} {side} hand and waves",
               f"waves {{pos}} {side} arm {where}", f"waves hello with the {side} hand",
               f"lifts {{pos}} {side} arm and waves it {times}"]
    return Action(f"wave_{side}_hand", pose, phrases, dict(side=side, waves=waves, high=high))


def wave_right_hand(rng) -> Action:
    return _wave(rng, "right")


def wave_left_hand(rng) -> Action:
    return _wave(rng, "left")


def _kick(rng, side: str) -> Action:
    reps = int(rng.choice([1, 1, 2, 3]))
    height = str(rng.choice(["low", "middle", "high"]))
    peak = {"low": 45.0, "middle": 70.0, "high": 95.0}[height] + rng.uniform(-5, 5)
    tempo = rng.uniform(0.85, 1.1)
    windup, strike, retract, land, rest = 0.35 / tempo, 0.3 / tempo, 0.3 / tempo, 0.3 / tempo, rng.uniform(0.2, 0.5)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    reps = _fit(reps, windup + strike + retract + land + rest, lead_in + lead_out)
    k = Keys(hip=0, knee=0, dorsi=0, pitch=0, arm=0, up=0)
    t = lead_in
    for _ in range(reps):
        k.add(t, hip=0, knee=0, dorsi=0, pitch=0, arm=0, up=0)
        k.add(t + 0.4 * windup, hip=5, knee=35, dorsi=-5, up=1)  # lift the foot before drawing it back
        t += windup
        k.add(t, hip=-15, knee=70, dorsi=-10, pitch=3, arm=20, up=1)
        # the knee stays bent while the thigh swings through, so the foot clears the floor, then snaps out
        k.add(t + 0.5 * strike, hip=0.55 * peak, knee=75, dorsi=-20, up=1)
        t += strike
        k.add(t, hip=peak, knee=5, dorsi=-25, pitch=-0.2 * peak, arm=-30, up=1)
        t += retract
        k.add(t, hip=40, knee=80, dorsi=-10, pitch=-5, arm=-10, up=1)
        k.add(t + 0.6 * land, hip=6, knee=20, dorsi=-3, up=1)  # above its spot: set the foot straight down
        t += land
        k.add(t, hip=0, knee=0, dorsi=0, pitch=0, arm=0, up=0)
        t += rest
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    pitch = k("pitch", tt)
    pose.root(pitch=pitch)
    pose.relaxed()
    other = OTHER[side]
    flex, knee = k("hip", tt) + pitch, k("knee", tt)
    pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(pitch, flex, knee) + k("dorsi", tt))
    sflex, sknee = pitch + 0.1 * k("knee", tt), 0.15 * k("knee", tt)
    pose.leg(other, flex=sflex, knee=sknee, dorsi=flat_foot(pitch, sflex, sknee))
    pose.support[:, 0 if side == "left" else 1] = k("up", tt) < 0.02  # the kicking foot is off the floor
    pose.arm(side, flex=k("arm", tt))
    pose.arm(other, flex=-k("arm", tt), abd=0.2 * np.abs(k("arm", tt)))
    times = _times(reps)
    how = {"low": "low", "middle": "at waist height", "high": "high"}[height]
    phrases = [f"kicks with {{pos}} {side} leg", f"kicks {{pos}} {side} foot forward {times}",
               f"kicks {how} with the {side} leg" + (f" {times}" if reps > 1 else ""),
               f"kicks forward {times} using {{pos}} {side} leg", f"swings {{pos}} {side} leg forward in a kick"]
    return Action(f"kick_{side}", pose, phrases, dict(side=side, reps=reps, height=height))


def kick_right(rng) -> Action:
    return _kick(rng, "right")


def kick_left(rng) -> Action:
    return _kick(rng, "left")


def squat(rng) -> Action:
    reps = int(rng.integers(1, 6))
    deep = bool(rng.random() < 0.5)
    speed = str(rng.choice(["slow", "normal"]))
    down = (1.3 if speed == "slow" else 0.8) * rng.uniform(0.9, 1.1)
    hold = rng.uniform(0.1, 0.5)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    reps = _fit(reps, 2 * down + 2 * hold, lead_in + lead_out)
    thigh, shank, pitch = (90.0, 35.0, 40.0) if deep else (50.0, 20.0, 22.0)
    k = Keys(d=0)
    t = lead_in
    for _ in range(reps):
        k.add(t, d=0)
        k.add(t + down, d=1)
        k.add(t + down + hold, d=1)
        t += 2 * down + hold
        k.add(t, d=0)
        t += hold
    pose = Pose(seconds_to_frames(t + lead_out))
    d = k("d", pose.t)
    p = d * pitch
    flex, knee = d * thigh + p, d * (thigh + shank)
    pose.root(pitch=p)
    for side in SIDES:
        pose.leg(side, flex=flex, abd=d * 8, knee=knee, dorsi=flat_foot(p, flex, knee))
        pose.arm(side, flex=d * (90.0 if deep else 70.0), abd=7, elbow=12 + d * 10)
    pose.spine(bend=2 - d * 5)
    pose.head(nod=-d * 10)
    times = _times(reps)
    kind = "deep squats" if deep else "half squats"
    phrases = [f"squats down {times}" if reps > 1 else "squats down and stands back up",
               f"does {NUMBER_WORDS[reps]} {kind}" if reps > 1 else f"does a {kind[:-1]}",
               f"bends {{pos}} knees and squats {times}{_adv(speed)}",
               f"squats{_adv(speed)} with {{pos}} arms held out in front",
               f"lowers into a squat and rises {times}"]
    return Action("squat", pose, phrases, dict(reps=reps, deep=deep, speed=speed))


def _turn(rng, side: str) -> Action:
    angle = float(rng.choice([90.0, 180.0, 360.0], p=[0.4, 0.4, 0.2]))
    cadence = rng.uniform(1.6, 2.2)
    # about 30 degrees a step: a planted foot then twists at most ~35 degrees against the pelvis
    steps = int(np.ceil(angle / 30.0)) + int(rng.integers(0, 2))
    steps += steps % 2  # an even number, so the feet end side by side
    pose, steps, _, _ = _locomotion(rng, MARCH, steps, cadence, 1.0,
                                    turn_deg=angle if side == "left" else -angle, min_steps=steps)
    if angle == 90.0:
        phrases = [f"turns to the {side}", f"turns {side} ninety degrees", f"makes a quarter turn to the {side}",
                   f"steps in place and turns {side}"]
    elif angle == 180.0:
        phrases = [f"turns around to the {side}", f"turns {side} and faces the other way",
                   f"turns around over {{pos}} {side} shoulder", f"turns {side} one hundred eighty degrees"]
    else:
        phrases = [f"turns in a full circle to the {side}", f"spins around to the {side} in place",
                   f"turns all the way around to the {side}", f"turns {side} three hundred sixty degrees"]
    return Action(f"turn_{side}", pose, phrases, dict(side=side, angle=int(angle), steps=steps))


def turn_left(rng) -> Action:
    return _turn(rng, "left")


def turn_right(rng) -> Action:
    return _turn(rng, "right")


def sit_down(rng) -> Action:
    speed = str(rng.choice(["slow", "normal"]))
    descend = (1.8 if speed == "slow" else 1.2) * rng.uniform(0.9, 1.1)
    lead_in, seated = rng.uniform(0.4, 1.0), rng.uniform(1.0, 2.5)
    seated = max(0.5, min(seated, _budget[0] - 0.05 - lead_in - descend - 0.5))
    k = Keys(thigh=0, shank=0, pitch=0, hands=0)
    t0 = lead_in
    k.add(t0, thigh=0, shank=0, pitch=0, hands=0)
    k.add(t0 + 0.55 * descend, thigh=55, shank=22, pitch=32, hands=0.5)
    k.add(t0 + descend, thigh=88, shank=8, pitch=20, hands=1)
    k.add(t0 + descend + 0.5, thigh=88, shank=4, pitch=8, hands=1)
    pose = Pose(seconds_to_frames(t0 + descend + 0.5 + seated))
    tt = pose.t
    thigh, shank, pitch, hands = k("thigh", tt), k("shank", tt), k("pitch", tt), k("hands", tt)
    flex, knee = thigh + pitch, thigh + shank
    pose.root(pitch=pitch)
    pose.relaxed()
    for side in SIDES:
        pose.leg(side, flex=flex, abd=4 * hands, knee=knee, dorsi=flat_foot(pitch, flex, knee))
        pose.arm(side, flex=hands * 38, elbow=hands * 50)
    pose.head(nod=-0.3 * pitch)
    phrases = [f"sits down{_adv(speed)}", "sits down on a chair", f"lowers {{pos}} body into a seated position",
               f"sits down{_adv(speed)} and stays seated", "takes a seat"]
    return Action("sit_down", pose, phrases, dict(speed=speed))


def punch(rng) -> Action:
    mode = str(rng.choice(["right", "left", "both"]))
    reps = int(rng.integers(1, 7)) if mode != "both" else int(rng.choice([2, 4, 6]))
    tempo = rng.uniform(0.8, 1.3)
    out, back, rest = 0.16 / tempo, 0.22 / tempo, rng.uniform(0.1, 0.4)
    guard_t, lead_in, lead_out = 0.5, rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)
    reps = _fit(reps, out + back + rest, lead_in + lead_out + 2 * guard_t, lo=2 if mode == "both" else 1)
    k = Keys(r=0, l=0)
    t = lead_in + guard_t
    for i in range(reps):
        side = mode if mode != "both" else ("right" if i % 2 == 0 else "left")
        ch = side[0]
        k.add(t, **{ch: 0})
        k.add(t + out, **{ch: 1})
        k.add(t + out + back, **{ch: 0})
        t += out + back + rest
    end = t + guard_t
    pose = Pose(seconds_to_frames(end + lead_out))
    tt = pose.t
    guard = ease((tt - lead_in) / guard_t) * ease((end - tt) / guard_t)
    pitch = 5 * guard
    pose.root(pitch=pitch)
    flex, knee = 12 * guard + pitch, 18 * guard
    pose.spine(bend=2, twist=18 * (k("r", tt) - k("l", tt)))
    for side in SIDES:
        p = k(side[0], tt)
        pose.leg(side, flex=flex, knee=knee, abd=6 * guard, dorsi=flat_foot(pitch, flex, knee))
        g = guard * (1 - p)
        pose.arm(side, flex=g * 40 + p * 85, abd=4 + g * 10 - p * 4, across=g * 18 + p * 12, elbow=12 + g * 108 - p * 7)
    times = _times(reps)
    if mode == "both":
        phrases = ["punches with both fists", f"throws {NUMBER_WORDS[reps]} punches alternating hands",
                   "boxes with both arms", f"punches forward {times} with left and right hands"]
    else:
        phrases = [f"punches with {{pos}} {mode} hand", f"punches forward {times} with the {mode} fist",
                   f"throws {NUMBER_WORDS[reps]} {mode} punches" if reps > 1 else f"throws a {mode} punch",
                   f"jabs {times} with {{pos}} {mode} arm"]
    return Action("punch", pose, phrases, dict(side=mode, reps=reps))


def clap(rng) -> Action:
    claps = int(rng.integers(3, 11))
    freq = rng.uniform(1.5, 3.0)
    lead_in, lead_out, raise_t = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7), 0.5
    claps = _fit(claps, 1.0 / freq, lead_in + lead_out + 2 * raise_t, lo=2)
    T = seconds_to_frames(lead_in + lead_out + 2 * raise_t + claps / freq)
    pose = Pose(T)
    tt = pose.t
    start, stop = lead_in + raise_t, lead_in + raise_t + claps / freq
    on = ease((tt - lead_in) / raise_t) * ease((stop + raise_t - tt) / raise_t)
    # 0 = hands apart, 1 = hands together: a clap every 1/freq s, held apart before and after
    c = 0.5 - 0.5 * np.cos(2 * np.pi * freq * np.clip(tt - start + 0.5 / freq, 0, claps / freq))
    c = np.where((tt > start - 0.5 / freq) & (tt < stop - 0.5 / freq), c, 0.0)
    pose.relaxed()
    for side in SIDES:
        # wrists ~35 cm apart when open, ~5 cm (palms touching) at the clap, in front of the chest
        pose.arm(side, flex=on * 45, abd=on * (14 - 2 * c), across=on * (3 + 23 * c), elbow=on * (72 + 6 * c))
    fast = "quickly" if freq > 2.3 else ("slowly" if freq < 1.8 else "")
    times = _times(claps) if claps <= 10 else "many times"
    phrases = [f"claps {{pos}} hands {times}", f"claps {fast or 'in front of {pos} chest'}",
               f"brings {{pos}} hands together and claps {times}", f"claps {NUMBER_WORDS[claps]} times",
               "applauds with both hands"]
    return Action("clap", pose, phrases, dict(claps=claps, freq=round(float(freq), 2)))


def _sidestep(rng, side: str) -> Action:
    pairs = int(rng.integers(2, 6))
    period = rng.uniform(0.7, 1.1)
    width = rng.uniform(0.25, 0.45)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    pairs = _fit(pairs, period, lead_in + lead_out, lo=1)
    T = seconds_to_frames(lead_in + pairs * period + lead_out)
    pose = Pose(T)
    tt = pose.t
    ph = np.clip((tt - lead_in) / period, 0, pairs)  # step pairs done so far
    frac = ph - np.floor(ph)
    frac[ph >= pairs] = 0.0
    alpha = np.degrees(np.arcsin(0.5 * width / 0.85))
    # each pair: the lead leg swings out while the trail leg pivots (first half), then the lead leg
    # carries the body while the trail leg swings in to close (second half)
    spread = alpha * np.where(frac < 0.5, ease(frac / 0.5), ease((1 - frac) / 0.5))
    bump_lead = np.where(frac < 0.5, np.sin(np.pi * frac / 0.5), 0.0) ** 1.5
    bump_trail = np.where(frac >= 0.5, np.sin(np.pi * (frac - 0.5) / 0.5), 0.0) ** 1.5
    pose.relaxed()
    lead, trail = side, OTHER[side]
    for leg, bump in ((lead, bump_lead), (trail, bump_trail)):
        flex, knee = 25 * bump, 50 * bump
        pose.leg(leg, flex=flex, knee=knee, abd=spread, dorsi=flat_foot(0, flex, knee))
    pose.spine(lean=-2 * np.sin(2 * np.pi * ph) * SIDES[side]["sign"])
    pose.arm("left", abd=0.3 * spread)
    pose.arm("right", abd=0.3 * spread)
    n = NUMBER_WORDS[pairs]
    phrases = [f"sidesteps to the {side}", f"steps sideways to {{pos}} {side}",
               f"shuffles {n} steps to the {side}", f"moves sideways to the {side} {_times(pairs)}",
               f"takes {n} side steps to the {side}"]
    return Action(f"sidestep_{side}", pose, phrases, dict(side=side, steps=pairs))


def sidestep_left(rng) -> Action:
    return _sidestep(rng, "left")


def sidestep_right(rng) -> Action:
    return _sidestep(rng, "right")


def raise_both_arms(rng) -> Action:
    reps = int(rng.choice([1, 1, 2, 3]))
    way = str(rng.choice(["forward", "sideways"]))
    high = bool(rng.random() < 0.6)
    up, hold = rng.uniform(0.6, 1.1), rng.uniform(0.3, 1.0)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    reps = _fit(reps, 2 * up + hold + 0.2, lead_in + lead_out)
    k = Keys(a=0)
    t = lead_in
    for _ in range(reps):
        k.add(t, a=0)
        k.add(t + up, a=1)
        k.add(t + up + hold, a=1)
        t += 2 * up + hold
        k.add(t, a=0)
        t += 0.2
    pose = Pose(seconds_to_frames(t + lead_out))
    a = k("a", pose.t)
    angle = 168.0 if high else 90.0
    pose.relaxed()
    for side in SIDES:
        if way == "forward":
            pose.arm(side, flex=a * angle, elbow=-a * 8)
        else:
            pose.arm(side, abd=a * angle, elbow=-a * 8)
    pose.head(nod=-a * (8 if high else 0))
    times = _times(reps)
    where = "above {pos} head" if high else ("in front of {pos} body" if way == "forward" else "out to the sides")
    phrases = [f"raises both arms {where}", f"lifts both arms {way} and lowers them {times}"
               if reps > 1 else f"lifts both arms {way} and lowers them",
               f"raises {{pos}} arms {'up high' if high else 'to shoulder height'} {times}",
               f"puts both hands up {times}" if high else f"holds both arms out {way}"]
    return Action("raise_both_arms", pose, phrases, dict(reps=reps, way=way, high=high))


def stand_idle(rng) -> Action:
    seconds = rng.uniform(MIN_SECONDS, max(MIN_SECONDS, min(6.0, _budget[0] - 0.05)))
    pose = Pose(seconds_to_frames(seconds))
    t = pose.t
    pose.relaxed()
    pose.spine(bend=1.2 * np.sin(2 * np.pi * t / rng.uniform(3.5, 5.0)))
    k = Keys(turn=0, nod=0)
    for tk in np.arange(rng.uniform(0.5, 1.5), seconds, rng.uniform(1.2, 2.5)):
        k.add(tk, turn=rng.uniform(-15, 15), nod=rng.uniform(-5, 8))
    pose.head(turn=k("turn", t), nod=k("nod", t))
    for side in SIDES:
        pose.arm(side, flex=2.0 * np.sin(2 * np.pi * t / 4.0 + (0 if side == "left" else 1.0)))
    phrases = ["stands still", "stands in place and does nothing", "is standing idle",
               "stands still and looks around", "stands without moving much"]
    return Action("stand_idle", pose, phrases, dict(seconds=round(float(seconds), 2)))


def bow(rng) -> Action:
    reps = int(rng.choice([1, 1, 2]))
    deep = bool(rng.random() < 0.5)
    depth = rng.uniform(55, 75) if deep else rng.uniform(20, 35)
    down, hold = rng.uniform(0.6, 1.0), rng.uniform(0.3, 1.0)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    reps = _fit(reps, 2 * down + hold + 0.3, lead_in + lead_out)
    k = Keys(b=0)
    t = lead_in
    for _ in range(reps):
        k.add(t, b=0)
        k.add(t + down, b=1)
        k.add(t + down + hold, b=1)
        t += 2 * down + hold
        k.add(t, b=0)
        t += 0.3
    pose = Pose(seconds_to_frames(t + lead_out))
    b = k("b", pose.t)
    pitch = b * depth * 0.75
    bend = b * depth * 0.25
    flex = pitch + b * 6  # the hips move back as the trunk folds forward
    pose.root(pitch=pitch)
    pose.spine(bend=2 + bend)
    for side in SIDES:
        pose.leg(side, flex=flex, knee=b * 4, dorsi=flat_foot(pitch, flex, b * 4))
        pose.arm(side, flex=0.85 * (pitch + bend), abd=7, elbow=12)
    pose.head(nod=b * 10)
    times = _times(reps)
    adj = "deeply" if deep else "slightly"
    phrases = [f"bows {adj}", f"bows {times}", f"bends forward at the waist and bows {times}",
               f"takes a {'deep' if deep else 'small'} bow" if reps == 1 else f"bows {adj} {times}",
               f"bows {{pos}} head and upper body {times}"]
    return Action("bow", pose, phrases, dict(reps=reps, deep=deep))


FAMILIES: dict[str, Callable] = {f.__name__: f for f in (
    walk_forward, walk_backward, walk_circle, run, jump_in_place, jump_forward, wave_right_hand,
    wave_left_hand, kick_right, kick_left, squat, turn_left, turn_right, sit_down, punch, clap,
    sidestep_left, sidestep_right, raise_both_arms, stand_idle, bow)}
