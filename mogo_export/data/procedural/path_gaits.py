"""How a body walks a path (for paths.py): the gait, cadence and stride that give a speed (`Pace`, measured per gait),
speed profiles, the stretches a path is made of and the heading track along them, and `_locomote`, which plants the
feet ahead along that heading so the root follows from them (grounding.solve_ground).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable, NamedTuple

import numpy as np

from .curves import Keys, ease
from .gaits import RUN, WALK, GaitStyle, gait, lock_foot_yaw
from .pose import FPS, SIDES, Pose, seconds_to_frames

TURN_EVENT = 30.0       # degrees: a stretch that turns less is captioned as straight ahead


class Pace(NamedTuple):
    """How a person reaches a speed with one gait: a cadence that rises with speed (steps/s = a + b * v,
    times a per-segment factor), and the stride amplitude whose step length makes up the rest."""
    style: GaitStyle
    speeds: tuple[float, float]     # m/s, drawn uniformly
    cadence: tuple[float, float]    # (a, b)
    cadence_range: tuple[float, float]
    amps: tuple[float, ...]         # stride amplitudes (gait's amp) ...
    steps: tuple[float, ...]        # ... and the step length (m) each gave, measured on straight walks
    max_turn: float                 # deg/s of the tightest curve
    accel: float                    # m/s^2 at most, speeding up from standing and slowing to a stop
    swing_scale: float = 1.0
    direction: float = 1.0
    lift: float = 1.0               # scales the knees' and feet's cycles


# Step lengths measured with locomotion._take_steps at full stride (they do not depend on cadence). The
# bounds are where the grounding stays smooth: a walk's first step shorter than amp 0.8 lands before its
# heel reaches the floor and the root jerks (pelvis 100+ m/s^2, also in _take_steps); walks past 1.65
# and runs past cadence 3.1 shake the pelvis past 50 and 100 m/s^2.
WALK_PACE = Pace(WALK, (0.6, 1.8), (1.1, 0.75), (1.2, 2.45), (0.8, 1.0, 1.2, 1.4, 1.6, 1.65),
                 (0.455, 0.542, 0.621, 0.685, 0.739, 0.752), 120.0, 1.5)
RUN_PACE = Pace(RUN, (1.8, 4.0), (2.3, 0.2), (2.4, 3.1), (0.7, 0.8, 1.0, 1.2, 1.4, 1.6),
                (0.59, 0.681, 0.857, 1.028, 1.188, 1.347), 65.0, 3.0)
# Walking backward is the walk played in reverse, but with the knee bent early in the backward swing
# (late in the forward one): the walk's knee lifts the foot only as it reaches back, so it dragged below
# the pinning height, its pins held it 20-40 cm from where the legs put it, and it stood 5 cm off at the
# end (the next segment's first step then flipped the knee). Its toe lands at phase 0.70 (the stance
# mask's end), and the steps are shorter (0.25-0.33 m).
BACKPEDAL = replace(WALK, stance=0.70, knee=[(0.0, 3), (0.13, 15), (0.38, 4), (0.55, 12), (0.65, 30), (0.75, 50),
                                             (0.85, 55), (0.93, 25)])
BACK_LIFT = 0.2  # the phase (forward) under which a foot stepping back is lifting, no longer carrying weight
BACK_PACE = Pace(BACKPEDAL, (0.3, 0.6), (0.9, 1.0), (1.0, 2.0), (0.4, 0.6, 0.8, 1.0), (0.247, 0.281, 0.303, 0.312),
                 0.0, 1.0, swing_scale=0.6, direction=-1.0)
# a planted foot keeps its yaw, so the pelvis twists against it by what the body turns in half a stance
# (the other half before mid-stance, see _plant_ahead): turning rates are capped per step to keep that
# twist under ~40 degrees
MAX_DEG_PER_STEP = 55.0
CORNER_ACCEL = 4.5      # m/s^2 sideways, at most, round a corner


def _speed_profile(rng, pace: Pace, change: bool) -> tuple[Callable, float, float]:
    """Speed (m/s) as a function of the walking time's fraction u: steady, or easing from one speed to
    another over part of it (speeding up or slowing down)."""
    lo, hi = pace.speeds
    v0 = rng.uniform(lo, hi)
    if not change:
        wobble = rng.uniform(-0.04, 0.04)  # a person's steady pace still drifts a little
        return (lambda u: v0 * (1 + wobble * np.sin(np.pi * u))), v0, v0
    v1 = rng.uniform(lo, hi)
    while abs(v1 - v0) < 0.25 * (hi - lo):
        v1 = rng.uniform(lo, hi)
    u0 = rng.uniform(0.1, 0.45)
    u1 = rng.uniform(u0 + 0.25, 0.9)
    return (lambda u: v0 + (v1 - v0) * ease((u - u0) / (u1 - u0))), v0, v1


def _pieces(rng, pace: Pace, seconds: float) -> list[tuple[str, float, float]]:
    """The stretches a walking path is made of, each at least 1.5 s: (kind, seconds, turn rate deg/s, or
    the angle of a corner)."""
    n = int(rng.integers(1, min(3, max(1, int(seconds // 1.5))) + 1))
    lengths = 1.5 + (seconds - 1.5 * n) * rng.dirichlet(np.ones(n))
    out = []
    is_run = pace is RUN_PACE
    for length in lengths:
        kind = str(rng.choice(["straight", "gentle", "tight", "corner"], p=[0.32, 0.3, 0.23, 0.15]))
        side = float(rng.choice([-1.0, 1.0]))
        if kind == "straight":  # a person's straight line still wanders a little
            rate = rng.uniform(-2.0, 2.0)
        elif kind == "gentle":  # at least TURN_EVENT over the stretch, so it is not captioned straight
            rate = side * max(rng.uniform(10.0, 35.0 if is_run else 45.0), 1.3 * TURN_EVENT / length)
        elif kind == "tight":
            rate = side * rng.uniform(35.0 if is_run else 45.0, pace.max_turn)
        else:
            rate = side * rng.uniform(45.0, 100.0 if is_run else 135.0)
        out.append((kind, float(length), float(rate)))
    return out


def _heading(rng, t, start, pieces, cadence, speed, steer) -> np.ndarray:
    """Heading (deg) along the walk: a smooth curvature profile through the pieces' turn rates, and
    corners (a quick change of 45-135 degrees over 0.5-1 s, longer where the speed asks for it) in corner
    pieces. Turning is scaled by `steer` and corners kept where it is 1."""
    k = Keys(w=0.0)
    corners = []
    full = t[steer > 0.999]
    a = start
    for kind, length, rate in pieces:
        b = a + length
        edge = min(0.4, 0.25 * length)
        # a corner's sideways acceleration (peaking at 1.5 v * angle / dur) stays under CORNER_ACCEL:
        # taken faster, the pelvis jerked past 50 m/s^2 at 1.8 m/s
        v = float(np.interp(a + 0.5 * length, t, speed))
        dur = float(np.clip(max(rng.uniform(0.5, 1.0), abs(rate) / 150.0,
                                1.5 * v * np.radians(abs(rate)) / CORNER_ACCEL), 0.5, 1.5))
        lo, hi = max(a, full[0]), min(b, full[-1]) - dur
        if kind == "corner" and hi < lo:  # no room in a short walk: a tight curve instead
            kind, rate = "tight", rate / length
        w = 0.0 if kind == "corner" else rate
        k.add(a + edge, w=w).add(b - edge, w=w)
        if kind == "corner":
            corners.append((0.5 * (lo + hi), dur, rate))
        a = b
    w = k("w", t) * steer
    cap = MAX_DEG_PER_STEP * cadence
    w = np.clip(w, -cap, cap)
    heading = np.cumsum(w) / FPS
    for tc, dur, angle in corners:
        heading = heading + angle * ease((t - tc) / dur)
    return heading


def _plant_ahead(pose: Pose, heading: np.ndarray, stance: dict, rate: np.ndarray, style: GaitStyle) -> None:
    """Set each foot down already turned by what the body turns in its first half-stance: gait() plants it
    along the heading at touch-down, so on a curve the pelvis twisted against the planted foot by the
    whole stance's turn (70+ degrees at 120 deg/s); now it is half of that either side of mid-stance.
    The foot still keeps its yaw while planted."""
    half = np.clip(0.5 * style.stance / np.maximum(rate, 1e-3), 0.0, 0.5)  # s: half a stance
    ahead = np.interp(pose.t + half, pose.t, heading)
    for side in ("left", "right"):
        hip = SIDES[side]["hip"]
        pose.angles[:, hip, 1] += lock_foot_yaw(ahead, stance[side]) - lock_foot_yaw(heading, stance[side])


def _locomote(rng, pace: Pace, seconds: float, speed: Callable, pieces=None, hips: float = 0.0,
              feet: float = 0.0, settle: float = 0.35) -> tuple[Pose, dict, dict]:
    """Stand, step along a path for `seconds` at speed(u) m/s, stand (as locomotion._take_steps, with the
    cadence, stride and heading varying along the way). Without `pieces` the heading stays, but `hips`
    (deg) turns the pelvis that far while stepping (the shoulders staying) and `feet` the feet further,
    both over the first `settle` cycles. -> (pose, parameters, tracks)."""
    lead_in, lead_out = rng.uniform(0.4, 0.9), rng.uniform(0.4, 0.9)
    T = seconds_to_frames(lead_in + seconds + lead_out)
    pose = Pose(T)
    t = pose.t
    start, stop = lead_in, min(lead_in + seconds, t[-1] - 0.1)
    walking = (t >= start) & (t < stop)
    # a person does not reach 4 m/s (or stop from it) in two strides: from standing the speed starts at
    # the gait's slowest and rises at most `accel` (the first stride still grows from nothing, below)
    slowest = pace.speeds[0] + pace.accel * np.minimum(np.maximum(t - start, 0), np.maximum(stop - t, 0))
    v = np.minimum(speed(np.clip((t - start) / (stop - start), 0.0, 1.0)), slowest)
    # the cadence a speed asks for, then the stride that makes up the speed at that cadence (bounded
    # strides: the cadence then gives way instead)
    cadence = np.clip((pace.cadence[0] + pace.cadence[1] * v) * rng.uniform(0.92, 1.08), *pace.cadence_range)
    stride = np.interp(v / cadence, pace.steps, pace.amps)
    cadence = v / np.interp(stride, pace.amps, pace.steps)
    # whole steps: the phase starts just past a heel strike and ends on one, as in _take_steps
    steps = max(4 if pace.style is RUN else 2, int(round(cadence[walking].sum() / FPS)))
    cycles = 0.5 * steps - 0.12
    rate = np.where(walking, cadence, 0.0)
    rate *= cycles / (rate.sum() / FPS)
    i0, i1 = np.flatnonzero(walking)[[0, -1]]
    done = np.cumsum(rate) / FPS
    # the first and last strides grow and shrink over 0.35 cycles (0.7 / cadence s in _take_steps): counted
    # in cycles, not seconds, so a cadence rising on the first step does not land it short of its heel
    # (the root then jumped 20 cm in a frame)
    moving = ease(done / 0.35) * ease((cycles - done) / 0.35)
    # the body turns only on feet that step, and stops turning over half a cycle before the last step:
    # both feet are then set down along the final heading (a stance left with one foot turned against the
    # other was swivelled on the floor by the fade into the next segment)
    steer = ease(done / settle) * ease((cycles - 0.6 - done) / 0.35)
    amp = stride * moving
    lift = ease((t - start + 0.3) / 0.3) * ease((stop + 0.3 - t) / 0.3)
    d = pace.direction
    phase = (0.12 if d > 0 else 0.0) + d * done
    # the feet are planted along the heading, so a pelvis turned less than the feet is the heading less
    # that difference, taken back up at the hips (both legs turn with the feet)
    heading = _heading(rng, t, start, pieces, 2 * rate, v, steer) if pieces else (hips + feet) * steer
    pose.root(yaw=-feet * steer)
    pose.spine(bend=2.0, twist=-hips * steer)
    # arms swing with the hips; at a run's longest strides and fastest cadence the forearms would turn
    # 60+ degrees a frame, so they keep the swing of stride 1.2
    arms = pace.swing_scale * (np.minimum(1.0, 1.2 / stride) if pace.style is RUN else 1.0)
    stance = gait(pose, phase, amp, pace.style, heading, pace.lift * lift, arms)
    _plant_ahead(pose, heading, stance, rate, pace.style)
    for side in SIDES:
        pose.leg(side, yaw=feet * steer)
    pose.support = np.stack([stance["left"], stance["right"]], axis=1)
    if d < 0:  # stepping back, a foot rolls onto its heel to lift: it no longer carries the body
        for k, off in enumerate((0.0, 0.5)):
            pose.support[:, k] &= (np.mod(phase + off, 1.0) > BACK_LIFT) | (amp < 0.05)
    if pace.style is RUN:
        pose.flight = ~(stance["left"] | stance["right"]) & (amp > 0.6 * stride)
    full = np.flatnonzero(steer > 0.99)  # where it keeps its pace and (on a path) follows its curves
    info = dict(steps=steps, cadence=round(float(2 * rate[walking].mean()), 3), walk=(int(i0), int(i1) + 1),
                steady=(int(full[0]), int(full[-1]) + 1) if len(full) else (int(i0), int(i0)))
    return pose, info, dict(heading=heading, steer=steer)
