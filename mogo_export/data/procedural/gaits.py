"""Cyclic gaits: the walk, run and march (stepping in place) cycles as keyed joint curves (`GaitStyle`),
and `gait`, which lays one onto a Pose along a phase track, with arms swinging against the legs and
planted feet that keep their yaw while the body turns.

The locomotion families (locomotion.py) decide when and how fast to step; this module only knows what
one cycle of each gait looks like.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .curves import cyclic, ease
from .pose import OTHER, Pose, flat_foot


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
