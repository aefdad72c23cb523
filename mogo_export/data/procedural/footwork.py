"""Footwork for the mimed actions (mimed.py): a few walking steps with the arms left to the family, both legs from
keyed channels with the feet flat on the floor, and one keyed step of one leg.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .curves import Keys, envelope
from .gaits import WALK, gait
from .pose import FPS, OTHER, SIDES, Pose, flat_foot


# the walk with the arms left to the family: no swing, no elbow bend, no lean (the families lean themselves)
HELD_ARMS = replace(WALK, arm_swing=0.0, elbow=(0.0, 0.0), lean=0.0)
# pushing: short flat-footed shuffling steps (a full heel raise would lift the leaning body onto its toes)
SHUFFLE = replace(HELD_ARMS, foot=[(p, 0.5 * v) for p, v in WALK.foot])


def walk_steps(pose: Pose, start: float, steps: int, cadence: float, stride: float, direction: float = 1.0,
          style=HELD_ARMS) -> np.ndarray:
    """Lay `steps` walking steps from `start` onto `pose` (feet side by side before and after, as in
    locomotion._take_steps); returns the stride envelope."""
    t = pose.t
    stop = min(start + steps / cadence, t[-1] - 0.1)
    amp = stride * envelope(t, start, stop, 0.7 / cadence)
    lift = envelope(t, start - 0.3, stop + 0.3, 0.3)
    cycles = 0.5 * steps - 0.12
    rate = np.where((t >= start) & (t < stop), cycles / (stop - start), 0.0)
    phase = (0.12 if direction > 0 else 0.0) + direction * np.cumsum(rate) / FPS
    stance = gait(pose, phase, amp, style, np.zeros(pose.T), lift)
    pose.support = np.stack([stance["left"], stance["right"]], axis=1)
    return amp


def keyed_legs(pose: Pose, k: Keys, tt: np.ndarray, pitch: np.ndarray) -> None:
    """Both legs from per-side keyed channels hip_<side> (thigh angle to the vertical, > 0 forward), knee_<side>,
    abd_<side>, heel_<side> (heel raise); the foot stays flat on the floor, whatever the trunk's pitch. A
    channel up_<side> > 0 lifts that foot off the floor (it carries no weight)."""
    for side in SIDES:
        flex = k(f"hip_{side}", tt) + pitch
        knee = k(f"knee_{side}", tt)
        pose.leg(side, flex=flex, knee=knee, abd=k(f"abd_{side}", tt),
                 dorsi=flat_foot(pitch, flex, knee, lift=k(f"heel_{side}", tt)))
        if f"up_{side}" in k.pts:
            pose.support[:, 0 if side == "left" else 1] = k(f"up_{side}", tt) < 0.02


def key_step(k: Keys, t: float, side: str, dur: float, frm: float, to: float, other_frm: float, other_to: float,
          knee: float = 45.0) -> float:
    """Key one step of the `side` leg (thigh from `frm` to `to` degrees, knee lifted on the way) while the
    other leg's thigh goes from other_frm to other_to over its planted foot; returns the end time."""
    o = OTHER[side]
    k.add(t, **{f"hip_{side}": frm, f"knee_{side}": 0, f"up_{side}": 0, f"hip_{o}": other_frm, f"knee_{o}": 0})
    k.add(t + 0.08, **{f"up_{side}": 1})
    # the knee bends first, the thigh following so the foot rises straight up off the floor before it
    # travels, while the other leg waits to carry the body over
    k.add(t + 0.25 * dur, **{f"hip_{side}": frm + 0.35 * knee, f"knee_{side}": 0.7 * knee, f"hip_{o}": other_frm})
    k.add(t + 0.5 * dur, **{f"hip_{side}": 0.5 * (frm + to) + 0.3 * knee, f"knee_{side}": knee})
    # and comes straight down onto its spot at the end
    k.add(t + 0.8 * dur, **{f"hip_{side}": to + 0.15 * knee, f"knee_{side}": 0.3 * knee})
    k.add(t + 0.92 * dur, **{f"up_{side}": 1})
    k.add(t + dur, **{f"hip_{side}": to, f"knee_{side}": 0, f"up_{side}": 0, f"hip_{o}": other_to, f"knee_{o}": 0})
    return t + dur
