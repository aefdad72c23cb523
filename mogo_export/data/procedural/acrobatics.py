"""Acrobatics the kinematics can express: a backflip.

Each is a family as action.py describes, `(rng, budget) -> Action`. FAMILIES lists this module's families in
their fixed order (families.py appends it to the registry, after exercise.py's); WORDS holds every caption word
they use that the shared lexicon (captions.py) and the modules before it lack; LAST_ONLY names the families that
do not end standing (none here).

- backflip: crouch, swing the arms, take off, rotate backward 360 deg in the air with the knees tucked (the
  root pitch goes through -360, then is wrapped back to 0: the same rotation), land on the feet; reps 1.
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget
from .curves import Keys, ease
from .pose import FPS, GRAVITY, SIDES, Pose, flat_foot, seconds_to_frames


def backflip(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    height = rng.uniform(0.6, 0.72)          # the pelvis's rise over its take-off height, m
    flight = float(np.sqrt(8.0 * height / GRAVITY))
    back = rng.uniform(0.0, 0.35)            # lands a little behind its take-off spot, m
    crouch, push, land, recover = rng.uniform(0.45, 0.6), 0.35, 0.3, rng.uniform(0.5, 0.8)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    # a short budget (late in a long sequence) trims the standing after and before, then the recovery
    spare = budget.seconds - 0.05 - (crouch + push + flight + land)
    lead_out = min(lead_out, max(0.15, spare - lead_in - recover))
    lead_in = min(lead_in, max(0.1, spare - lead_out - recover))
    recover = min(recover, max(0.4, spare - lead_in - lead_out))
    k = Keys(thigh=0, shank=0, lean=0, arm=0, elbow=12, heel=0, nod=0, spin=0)
    t = lead_in
    k.add(t, thigh=0, shank=0, lean=0, arm=0, elbow=12, heel=0, nod=0, spin=0)
    t += crouch
    k.add(t, thigh=62, shank=30, lean=30, arm=-40, elbow=20, heel=0, nod=5)
    k.add(t + 0.5 * push, arm=45, elbow=15)                             # the arms swing through
    t += push
    k.add(t, "stop", thigh=-6, shank=6, heel=30)                       # take-off: legs straight, on the toes
    k.add(t, lean=-22, arm=145, elbow=10, nod=-10, spin=0)
    off = t
    # the knees tuck to the chest (the hands reaching for the shins), the head looks back for the floor
    k.add(t + 0.4 * flight, thigh=95, shank=30, arm=95, elbow=45, nod=-25, heel=-5, spin=0.34)
    k.add(t + 0.62 * flight, thigh=100, shank=28, arm=80, elbow=50, nod=-20, spin=0.66)
    k.add(t + 0.82 * flight, spin=0.9)
    t += flight
    # opening out slows the turn: the legs reach for the floor, the arms go forward for balance
    k.add(t, "start", thigh=22, shank=-4, heel=6)
    k.add(t, lean=22, arm=70, elbow=20, nod=5, spin=1)
    t += land
    k.add(t, thigh=60, shank=28, lean=32, arm=55, elbow=25, heel=0, nod=0)
    t += recover
    k.add(t, thigh=0, shank=0, lean=0, arm=0, elbow=12, heel=0, nod=0)
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    thigh, shank, lean, spin = k("thigh", tt), k("shank", tt), k("lean", tt), k("spin", tt)
    # a full backward turn: -360 deg of pitch over the flight, then wrapped back to 0 (the same rotation) so a
    # following action does not blend through a turn
    pitch = lean - 360.0 * np.where(spin >= 1.0 - 1e-12, 0.0, spin)
    flex, knee = thigh + lean, thigh + shank
    pose.root(pitch=pitch)
    pose.spine(bend=0.3 * lean)
    for s in SIDES:
        pose.leg(s, flex=flex, knee=knee, abd=4 + 6 * ease(thigh / 95),
                 dorsi=flat_foot(lean, flex, knee, lift=k("heel", tt)))
        pose.arm(s, flex=k("arm", tt), abd=10, elbow=k("elbow", tt))
    pose.head(nod=k("nod", tt))
    air = (tt > off) & (tt < off + flight)
    pose.flight |= air
    pose.leap |= air
    pose.air_speed[air] = -back * FPS / max(air.sum(), 1)
    phrases = ["does a backflip", "flips backward and lands on {pos} feet", "does a back somersault",
               "swings {pos} arms up and flips over backward", "does a backflip, tucking {pos} knees in the air"]
    return Action("backflip", pose, phrases, dict(height=round(float(height), 2), back=round(float(back), 2)))


FAMILIES: tuple = (backflip,)
WORDS: dict = {
    "NOUN": {"air": "air", "backflip": "backflip", "feet": "foot", "somersault": "somersault"},
    "VERB": {"flips": "flip", "lands": "land", "tucking": "tuck"},
}
LAST_ONLY: tuple[str, ...] = ()
