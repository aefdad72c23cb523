"""Getting down toward the floor and staying there, or rising again: crouching low (and rising again), kneeling down
on one knee or both, and sitting down on the ground.

Each is a family as action.py describes, `(rng, budget) -> Action`, its key poses solved with floorwork.py so that
what should touch the floor together (a knee and the toes behind it, the seat and the heels) comes down level.
FAMILIES lists this module's families in their fixed order (families.py appends it to the registry, followed by
falls.py's); WORDS holds every caption word the two modules use that the shared lexicon (captions.py) lacks;
LAST_ONLY names the families that do not end standing (kneel_down, sit_on_ground).
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget, sample_speed
from .captions import adverb, how_often
from .curves import Keys, ease
from .floorwork import fit_pose, floor_points, hold_within, legs_at
from .pose import OTHER, SIDES, Pose, seconds_to_frames


# --- crouch -----------------------------------------------------------------------------------------------


def crouch(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    speed = sample_speed(rng)
    heels_up = bool(rng.random() < 0.6)
    touch = str(rng.choice(["none", "left", "right"], p=[0.4, 0.3, 0.3]))
    looks = int(rng.integers(1, 4))
    down = {"slow": 1.3, "normal": 0.85, "fast": 0.5}[speed] * rng.uniform(0.9, 1.1)
    up = {"slow": 1.4, "normal": 1.0, "fast": 0.7}[speed] * rng.uniform(0.9, 1.1)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.6)
    per_look = rng.uniform(0.7, 1.0)
    hold = hold_within(budget, looks * per_look + rng.uniform(0.3, 0.8), lead_in + down + up + lead_out, 0.8)
    looks = int(max(1, min(looks, np.floor((hold - 0.2) / per_look))))
    # the low crouch: thighs past level, knees bent 135-140 degrees, trunk leaning over the knees
    thigh, shank, lift = (rng.uniform(104, 110), 32.0, 34.0) if heels_up else (rng.uniform(92, 98), 40.0, 0.0)
    pitch = rng.uniform(28, 36)
    k = Keys(d=0)
    t0, t1 = lead_in, lead_in + down
    t2 = t1 + hold
    k.add(t0, d=0).add(t1, "stop", d=1).add(t2, d=1).add(t2 + up, d=0)
    pose = Pose(seconds_to_frames(t2 + up + lead_out))
    tt = pose.t
    d = k("d", tt)
    p = d * pitch
    pose.root(pitch=p)
    for side in SIDES:
        legs_at(pose, side, d * thigh, d * shank, p, lift=d * lift, abd=d * 16)
    reach = d * (touch != "none")  # reaching a hand to the floor folds the trunk further, toward that side
    pose.spine(bend=2 + d * 12 + reach * 18, lean=reach * 8 * SIDES[touch if touch != "none" else "left"]["sign"])
    # looking around while down: the head turns (and the shoulders follow a little) one way, then the other
    first = float(rng.choice([-1.0, 1.0]))
    look = Keys(a=0)
    for i in range(looks):
        c = t1 + 0.2 + i * per_look
        look.add(c, a=0).add(c + 0.45 * per_look, a=first * (-1) ** i).add(c + per_look, a=0)
    a = look("a", tt) * d
    pose.head(nod=-d * 22, turn=a * rng.uniform(45, 65))
    pose.spine(twist=a * 12)
    for side in SIDES:
        if side == touch:  # reaches down and forward: the fingertips touch the floor in front of the feet
            pose.arm(side, flex=d * (pitch + 45), abd=4 + d * 6, elbow=12 - d * 10)
        else:  # forearm resting across the thigh
            pose.arm(side, flex=d * (pitch + 20), abd=4 + d * 8, across=d * 10, elbow=12 + d * 48 + reach * 25)
    times = how_often(looks)
    low = "on {pos} toes" if heels_up else "with {pos} heels down"
    phrases = [f"crouches down low{adverb(speed)}, looks around and stands back up",
               f"drops into a low crouch {low} and looks around",
               f"crouches{adverb(speed)} and glances around {times} before standing up",
               "gets down into a crouch, holds it and stands up again"]
    if touch != "none":
        phrases.append(f"crouches low and touches the floor with {{pos}} {touch} hand")
    else:
        phrases.append("hunkers down low for a moment and then rises")
    params = dict(speed=speed, heels_up=heels_up, looks=looks, hold=round(hold, 2))
    if touch != "none":
        params["side"] = touch
    return Action("crouch", pose, phrases, params)


# --- kneel_down ---------------------------------------------------------------------------------------------

_LEG = ("thigh", "shank", "lift")


def _kneel_layers(pose: Pose, c: dict, side: str) -> None:
    """The kneel's layers from channel values c (arrays or numbers): the `side` leg ("b": it goes back and
    down onto its knee) and the other ("f": in front, or down beside it)."""
    pitch = c["pitch"]
    pose.root(pitch=pitch)
    for leg, who in ((side, "b"), (OTHER[side], "f")):
        legs_at(pose, leg, c[who + "thigh"], c[who + "shank"], pitch, lift=c[who + "lift"], abd=c["abd"])
    pose.spine(bend=c["bend"])
    pose.head(nod=c["nod"])


def kneel_down(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    side = str(rng.choice(["left", "right"]))
    both = bool(rng.random() < 0.5)
    speed = str(rng.choice(["slow", "normal"]))
    step, lower = rng.uniform(0.5, 0.7), (1.4 if speed == "slow" else 0.9) * rng.uniform(0.9, 1.1)
    second = rng.uniform(0.8, 1.1) if both else 0.0
    lead_in = rng.uniform(0.3, 0.6)
    stay = hold_within(budget, rng.uniform(1.0, 3.0), lead_in + step + lower + second, 0.6)
    other = OTHER[side]
    bk, bt, ft = f"{side}_knee", f"{side}_toe", f"{other}_toe"

    def build(p, c):
        _kneel_layers(p, c, side)
    stand = dict(pitch=0, bend=2, nod=0, abd=0, bthigh=0, bshank=0, blift=0, fthigh=0, fshank=0, flift=0)
    # key poses, each solved so that what is on the floor is level and what is pinned stays where it landed.
    # The held kneel: the down knee under the hip, toes tucked under; the front shin near upright
    half = fit_pose({**stand, "pitch": rng.uniform(2, 6), "nod": 6, "abd": 5, "bthigh": -2, "bshank": 100,
                 "blift": 75, "fthigh": 88, "fshank": 18}, build, ("bshank", "fthigh"),
                lambda q: [q[bk][1] - q[ft][1], q[bt][1] - q[ft][1]])
    q = floor_points(lambda p: build(p, half))
    gap = q[bt][2] - q[ft][2]                                       # back toes behind the front foot
    # the kneeling leg swings back as the front knee bends, and its toes land where they will stay ...
    s_key = fit_pose({**stand, "fthigh": 62, "fshank": 14, "pitch": 4, "abd": 3, "bthigh": -30, "bshank": 60,
                  "blift": 55}, build, ("bthigh", "bshank"), lambda q: [q[bt][1] - q[ft][1], q[bt][2] - q[ft][2] - gap])
    # ... then the knee sinks to the floor, the toes pivoting under it
    m_key = fit_pose({**stand, "fthigh": 78, "fshank": 16, "pitch": 4, "abd": 4, "nod": 3, "bthigh": -15,
                  "bshank": 80, "blift": 65}, build, ("bthigh", "bshank"),
                 lambda q: [q[bt][1] - q[ft][1], q[bt][2] - q[ft][2] - gap])
    # both knees: the front foot lifts and its knee comes down beside the other, toes tucked too
    end = half if not both else fit_pose({**half, "fthigh": half["bthigh"], "fshank": half["bshank"], "flift": 75},
                                     build, ("fthigh", "fshank"),
                                     lambda q: [q[f"{other}_knee"][1] - q[bk][1], q[ft][1] - q[bk][1]])
    k = Keys(**stand)
    t = lead_in
    k.add(t, **stand)
    # the foot comes up under the body first (toes clear of the floor at once), then reaches back
    k.add(t + 0.3 * step, bthigh=8, bshank=40, blift=-5, fthigh=18, fshank=8, pitch=2)
    k.add(t + 0.65 * step, bthigh=-12, bshank=65, blift=25, fthigh=38, fshank=11, pitch=3)
    k.add(t + step, **s_key)
    lifted = (t + 0.1, t + step - 0.05)
    t += step
    k.add(t + 0.5 * lower, **m_key)
    t += lower
    k.add(t, "stop", **half)
    if both:
        k.add(t + 0.35 * second, fthigh=half["fthigh"] + 4, fshank=35, flift=20)
        k.add(t + 0.7 * second, fthigh=40, fshank=98, flift=60)
        k.add(t + second, **end)
        forward_lifted = (t + 0.1, t + 0.9 * second)
        t += second
    pose = Pose(seconds_to_frames(t + stay))
    tt = pose.t
    c = {n: k(n, tt) for n in stand}
    breathe = np.sin(2 * np.pi * (tt - t) / rng.uniform(3.0, 4.5)) * ease((tt - t) / 0.5)
    c["bend"] = c["bend"] + 1.0 * breathe
    _kneel_layers(pose, c, side)
    b, f = (0, 1) if side == "left" else (1, 0)
    pose.support[:, b] = ~((tt > lifted[0]) & (tt < lifted[1]))
    if both:
        pose.support[:, f] = ~((tt > forward_lifted[0]) & (tt < forward_lifted[1]))
    pose.rest_on([f"{side}_knee"] + ([f"{OTHER[side]}_knee"] if both else []))
    # arms: the front hand comes to rest on the front knee (one knee), or both hands on the thighs
    down = ease((tt - lead_in - step) / lower)
    if both:
        for arm in SIDES:
            pose.arm(arm, flex=4 + down * 28, abd=4 + down * 6, elbow=12 + down * 40)
    else:
        pose.arm(other, flex=3 + down * 55, abd=4 + down * 4, across=down * 8, elbow=12 + down * 45)
        pose.arm(side, flex=3 + down * 8, abd=4 + down * 6, elbow=12 + down * 10)
    how = "on both knees" if both else f"on {{pos}} {side} knee"
    phrases = [f"kneels down {how}", f"gets down {how}{adverb(speed)} and stays there",
               f"steps back with the {side} leg and kneels {'on both knees' if both else 'on one knee'}",
               f"lowers {{pos}} {side} knee to the floor" + (" and then the other one" if both else ""),
               f"goes down {how} and stays kneeling"]
    return Action("kneel_down", pose, phrases, dict(side=side, both=both, speed=speed, stay=round(stay, 2)))


# --- sit_on_ground ----------------------------------------------------------------------------------------


def _seat_layers(pose: Pose, c: dict) -> None:
    """Both legs alike by world angles (thigh; `dir`: the shank's direction, degrees forward of straight
    down, so 90 is a shin level with the floor), the trunk pitched `pitch`, the arms by `arm` / `elbow`."""
    pitch = c["pitch"]
    pose.root(pitch=pitch)
    for side in SIDES:
        legs_at(pose, side, c["thigh"], -np.asarray(c["dir"]), pitch, lift=c["lift"], abd=c["abd"], dorsi=c["toes"])
    pose.spine(bend=c["bend"])
    pose.head(nod=c["nod"])
    for side in SIDES:  # arm_d: the left arm's flexion above the right's (the arms differ by a centimetre)
        pose.arm(side, flex=np.asarray(c["arm"]) + SIDES[side]["sign"] * 0.5 * np.asarray(c["arm_d"]),
                 abd=c["arm_abd"], elbow=c["elbow"])


_SEAT = dict(pitch=0, thigh=0, dir=0, lift=0, abd=0, toes=0, bend=2, nod=0, arm=3, arm_d=0, arm_abd=4, elbow=12)


def _seated(c: dict, channel: str, lo_part: str = "pelvis") -> dict:
    """c with `channel` solved so the heels come down level with `lo_part` (the seat, or the back)."""
    return fit_pose(c, _seat_layers, (channel,), lambda q: [_sole(q) - q[lo_part][1]])


def _sole(q: dict) -> float:
    """The lowest heel or toe of either foot (the legs differ by a centimetre)."""
    return min(q[f"{s}_{p}"][1] for s in SIDES for p in ("heel", "toe"))


def _sit_keys(rng) -> tuple[dict, dict]:
    """The way down to the floor: a squat over the feet, then the seat comes down behind them, knees up."""
    squat = {**_SEAT, "pitch": rng.uniform(30, 38), "thigh": 85, "dir": -35, "arm": 45, "elbow": 25, "abd": 6}
    seat = _seated({**_SEAT, "pitch": rng.uniform(5, 12), "thigh": 132, "dir": 40, "arm": 30, "arm_abd": 12,
                    "elbow": 30, "abd": 8, "nod": 4}, "dir")
    return squat, seat


def sit_on_ground(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    legs = str(rng.choice(["straight", "bent"]))
    speed = str(rng.choice(["slow", "normal"]))
    down = (1.3 if speed == "slow" else 0.9) * rng.uniform(0.9, 1.1)
    sit, settle = rng.uniform(0.6, 0.8), rng.uniform(0.8, 1.1)
    lead_in = rng.uniform(0.3, 0.6)
    stay = hold_within(budget, rng.uniform(1.0, 3.0), lead_in + down + sit + settle, 0.6)
    squat, seat = _sit_keys(rng)
    if legs == "straight":  # legs stretched out in front, leaning back on both hands behind the hips
        end = _seated({**_SEAT, "pitch": rng.uniform(-22, -12), "thigh": 98, "dir": 88, "toes": -8,
                       "arm": -40, "arm_abd": 14, "elbow": 6, "nod": 10}, "dir")  # knees a little bent
        end = fit_pose(end, _seat_layers, ("arm", "arm_d"),
                   lambda q: [q["left_hand"][1] - q["pelvis"][1], q["right_hand"][1] - q["pelvis"][1]])
        # the feet lift as the legs stretch out (so they do not drag), the hands swing back with bent elbows
        mid = {**end, "thigh": 122, "dir": 78, "toes": 0, "pitch": 0.5 * (end["pitch"] + seat["pitch"]),
               "arm": -5, "arm_d": 0, "arm_abd": 14, "elbow": 75}
        # ... the legs reach out above the floor and set the heels down, the hands come down behind the hips
        late = {**end, "thigh": end["thigh"] + 6, "arm": end["arm"] - 4, "elbow": 45}
        rest = ["left_hand", "right_hand"]
    else:  # knees drawn up, both arms wrapped around the shins
        q = floor_points(lambda p: _seat_layers(p, seat))
        gap = q["left_heel"][2] - q["pelvis"][2]                  # the feet stay where the seat came down
        end = fit_pose({**seat, "pitch": rng.uniform(12, 20), "thigh": 138, "dir": 35, "arm": 50, "arm_abd": 6,
                    "elbow": 35, "nod": 10}, _seat_layers, ("thigh", "dir"),
                   lambda q: [_sole(q) - q["pelvis"][1],
                              q["left_heel"][2] - q["pelvis"][2] - gap])
        mid = {n: 0.5 * (seat[n] + end[n]) for n in _SEAT}
        late = {n: 0.8 * end[n] + 0.2 * seat[n] for n in _SEAT}
        rest = []
    k = Keys(**_SEAT)
    t = lead_in
    k.add(t, **_SEAT)
    k.add(t + down, **squat)
    t += down
    k.add(t + sit, "stop", **seat)
    t += sit
    k.add(t + 0.5 * settle, **mid)
    k.add(t + 0.8 * settle, **late)
    k.add(t + settle, **end)
    lifting = (t + 0.05, t + settle - 0.1) if legs == "straight" else None
    t += settle
    pose = Pose(seconds_to_frames(t + stay))
    tt = pose.t
    c = {n: k(n, tt) for n in _SEAT}
    # breathing: the head sways (leaning on the hands, a bending spine would drag them or the seat)
    c["nod"] = c["nod"] + 2.0 * np.sin(2 * np.pi * (tt - t) / rng.uniform(3.0, 4.5)) * ease((tt - t) / 0.5)
    _seat_layers(pose, c)
    if lifting:
        pose.support[(tt > lifting[0]) & (tt < lifting[1])] = False
    pose.rest_on("pelvis")
    # the hands are a support only once they are down (coming down, they are not yet where they will rest)
    pose.rest_on(rest, np.where(tt >= t - 0.05, 1.0, 0.0) if legs == "straight" else 1.0)
    how = {"straight": "with {pos} legs stretched out in front", "bent": "and hugs {pos} knees"}[legs]
    phrases = [f"sits down on the floor {how}", f"lowers {{pos}} body{adverb(speed)} and sits on the ground",
               f"gets down and sits on the ground {how}",
               "sits on the floor and stays there" if legs == "bent" else "sits on the floor leaning back on both hands",
               f"sits down{adverb(speed)} on the ground and stays seated"]
    return Action("sit_on_ground", pose, phrases, dict(legs=legs, speed=speed, stay=round(stay, 2)))




FAMILIES: tuple = (crouch, kneel_down, sit_on_ground)
WORDS: dict = {
    "ADV": "again there hard flat",
    "ADP": "for",
    "NOUN": {"crouch": "crouch", "floor": "floor", "ground": "ground", "heels": "heel", "knee": "knee",
             "legs": "leg", "moment": "moment", "pain": "pain", "toes": "toe"},
    "VERB": {"crouches": "crouch", "drops": "drop", "gets": "get", "glances": "glance", "goes": "go",
             "hugs": "hug", "hunkers": "hunker", "kneeling": "kneel", "kneels": "kneel", "leaning": "lean",
             "stretched": "stretch", "touches": "touch", "collapses": "collapse", "clutches": "clutch",
             "clutching": "clutch", "falls": "fall", "sinks": "sink", "hurts": "hurt", "hobbles": "hobble",
             "holding": "hold", "loses": "lose", "lies": "lie", "rests": "rest"},
    "NOUN_OR_VERB": {"fall": "fall"},
}
LAST_ONLY: tuple[str, ...] = ("kneel_down", "sit_on_ground")

