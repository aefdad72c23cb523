"""Gestures performed standing on the spot: pointing (left, right, straight ahead), saluting, shrugging,
nodding, shaking the head, beckoning, cheering, facepalming, looking around and stretching.

Each is a family as action.py describes, `(rng, budget) -> Action`: keyframed joint curves (curves.Keys)
layered on the relaxed standing pose, the feet never leave the floor. FAMILIES lists this module's families
in their fixed order (families.py appends it to the registry); WORDS holds every caption word they use that
the shared lexicon (captions.py) lacks; LAST_ONLY is empty: every gesture ends standing.

The arm poses were found by searching joint angles for wrist and elbow targets around the skeleton's head
(joint 15, about 9 cm above the neck and 6 cm in front of it): a saluting wrist rests ~18 cm beside and in
front of it, a face-covering one ~13 cm in front of it, never inside (tests/export/test_families_gestures.py).
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget
from .captions import NUMBER_WORDS, how_often
from .curves import Keys, ease
from .pose import OTHER, SIDES, Pose, flat_foot, seconds_to_frames


def _fit(budget: TimeBudget, reps: int, per: float, fixed: float, hold: float, lo: float = 0.5) -> tuple[int, float]:
    """Repetitions of (per + hold) seconds that fit after `fixed`, and the hold shortened (to no less than lo)
    so that even one repetition fits a short budget."""
    reps = budget.fit(reps, per + hold, fixed)
    room = (budget.seconds - 0.05 - fixed) / reps - per
    return reps, float(max(lo, min(hold, room)))


def _cycles(start: float, up: float, hold: float, down: float, rest: float, reps: int,
            up_mode: str = "") -> tuple[Keys, float]:
    """Channel "a": `reps` times 0 -> 1 in `up` s, held `hold` s, -> 0 in `down` s, `rest` s between them.
    Returns the keys and the time the last one is back at 0."""
    k = Keys(a=0)
    t = start
    for i in range(reps):
        t += rest if i else 0.0
        k.add(t, a=0)
        k.add(t + up, up_mode, a=1)
        k.add(t + up + hold, a=1)
        t += up + hold + down
        k.add(t, a=0)
    return k, t


def _pointing_phrases(side: str, toward: str, reps: int) -> list[str]:
    times = f" {how_often(reps)}" if reps > 1 else ""
    if toward == "forward":
        return [f"points straight ahead with {{pos}} {side} arm{times}",
                f"points forward with {{pos}} {side} hand{times}",
                f"extends {{pos}} {side} arm straight out in front and points",
                f"points at something ahead with {{pos}} {side} index finger",
                f"holds {{pos}} {side} arm out at shoulder height pointing forward{times}"]
    return [f"points to the {toward} with {{pos}} {side} arm{times}",
            f"points {toward}{times}",
            f"extends {{pos}} {side} arm out to the side and points",
            f"looks and points to {{pos}} {toward}{times}",
            f"points at something on {{pos}} {toward} with {{pos}} {side} hand"]


def _point(rng, side: str, toward: str, budget: TimeBudget) -> Action:
    """Raise the straight arm to shoulder height toward the left, the right or straight ahead, hold, lower."""
    reps = int(rng.choice([1, 1, 2, 3]))
    up, down, rest = rng.uniform(0.35, 0.6), rng.uniform(0.4, 0.7), rng.uniform(0.3, 0.6)
    hold = rng.uniform(1.0, 2.5)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    reps, hold = _fit(budget, reps, up + down + rest, lead_in + lead_out - rest, hold, lo=1.0)
    k, end = _cycles(lead_in, up, hold, down, rest, reps)
    pose = Pose(seconds_to_frames(end + lead_out))
    a = k("a", pose.t)
    sign = SIDES[side]["sign"]  # +1 left: abduction and turns to the left are positive
    pose.relaxed()
    if toward == "forward":
        flex = rng.uniform(82, 95)
        pose.arm(side, flex=a * flex, abd=-a * 3, across=a * 3, elbow=-a * 10)
        pose.spine(twist=-sign * a * 6)  # the pointing shoulder comes forward
        pose.head(nod=-a * 3)
    else:
        abd, flex = rng.uniform(82, 95), rng.uniform(5, 18)
        pose.arm(side, abd=a * abd, flex=a * flex, elbow=-a * 10)
        pose.spine(twist=sign * a * rng.uniform(6, 12), lean=-sign * a * 2)
        pose.head(turn=sign * a * rng.uniform(35, 55))  # the head turns toward where the arm points
    family = "point_forward" if toward == "forward" else f"point_{side}"
    return Action(family, pose, _pointing_phrases(side, toward, reps),
                  dict(side=side, reps=reps, hold=round(hold, 2)))


def point_left(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _point(rng, "left", "left", budget)


def point_right(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _point(rng, "right", "right", budget)


def point_forward(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    side = str(rng.choice(["left", "right"]))
    return _point(rng, side, "forward", budget)


def salute(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Stand to attention, bring the right hand to the brow with the elbow out sideways, hold, snap it down."""
    reps = int(rng.choice([1, 1, 1, 2]))
    up, snap, rest = rng.uniform(0.4, 0.55), rng.uniform(0.35, 0.45), rng.uniform(0.4, 0.8)
    hold = rng.uniform(1.0, 2.5)
    lead_in, lead_out = rng.uniform(0.4, 0.8), rng.uniform(0.4, 0.8)
    reps, hold = _fit(budget, reps, up + snap + rest, lead_in + lead_out - rest, hold, lo=0.8)
    k, end = _cycles(lead_in, up, hold, snap, rest, reps)
    pose = Pose(seconds_to_frames(end + lead_out))
    t = pose.t
    a = k("a", t)
    attention = ease((t - lead_in + 0.3) / 0.4) * ease((end + 0.3 - t) / 0.4)
    pose.relaxed()
    pose.spine(bend=-2 * attention)  # straight back
    pose.head(nod=-3 * attention)
    pose.arm("left", abd=-3 * attention, elbow=-9 * attention)  # the other arm straight down at the side
    # wrist at the right brow: elbow ~25 cm out to the side at shoulder height, forearm angled up and in
    pose.arm("right", flex=a * 10, abd=a * 95, twist=a * 60, elbow=a * 120, across=a * 20)
    times = how_often(reps)
    phrases = ["salutes" + (f" {times}" if reps > 1 else ""), "gives a military salute with {pos} right hand",
               "raises {pos} right hand to {pos} brow in a salute" + (f" {times}" if reps > 1 else ""),
               "stands at attention and salutes" + (f" {times}" if reps > 1 else ""),
               "snaps {pos} right hand up to {pos} forehead, holds the salute and snaps it down"]
    return Action("salute", pose, phrases, dict(reps=reps, hold=round(hold, 2)))


def shrug(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Shoulders up, elbows bent with the forearms out to the sides (palms up), head tilted; then down."""
    reps = int(rng.choice([1, 1, 2, 3]))
    up, down, rest = rng.uniform(0.25, 0.4), rng.uniform(0.35, 0.5), rng.uniform(0.2, 0.4)
    hold = rng.uniform(0.4, 0.9)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    reps, hold = _fit(budget, reps, up + down + rest, lead_in + lead_out - rest, hold, lo=0.3)
    k, end = _cycles(lead_in, up, hold, down, rest, reps)
    pose = Pose(seconds_to_frames(end + lead_out))
    s = k("a", pose.t)
    tilt = float(rng.choice([-1.0, 1.0])) * rng.uniform(8, 15)
    pose.relaxed()
    for side in SIDES:
        pose.arm(side, shrug=s * 20, abd=s * 10, twist=s * 45, elbow=s * 80)
    pose.spine(bend=-s * 2)
    pose.head(tilt=s * tilt, nod=s * 4)
    times = how_often(reps)
    phrases = [f"shrugs {{pos}} shoulders {times}" if reps > 1 else "shrugs {pos} shoulders",
               f"shrugs {times} with {{pos}} palms turned up",
               "raises {pos} shoulders and spreads {pos} hands with the palms up" + (f" {times}" if reps > 1 else ""),
               "shrugs as if to say who knows",
               f"lifts both shoulders in a shrug {times}"]
    return Action("shrug", pose, phrases, dict(reps=reps, hold=round(hold, 2)))


def _head_cycles(rng, budget: TimeBudget, lo: int, hi: int, freq: float, up: float, down: float):
    """Keys of a head oscillation: `count` cycles at `freq` Hz, each to +down then -up (degrees)."""
    count = int(rng.integers(lo, hi + 1))
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    count = budget.fit(count, 1.0 / freq, lead_in + lead_out + 0.1, lo=2)
    k = Keys(h=0)
    k.add(lead_in, h=0)
    for i in range(count):
        c = lead_in + i / freq
        k.add(c + 0.25 / freq, h=down)
        k.add(c + 0.75 / freq, h=-up)
    end = lead_in + count / freq + 0.1
    k.add(end, h=0)
    return k, count, end + lead_out


def nod(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Big clear yes-nods: the head pitches ~22 deg down and ~15 up about twice a second."""
    freq, amp = rng.uniform(1.7, 2.4), rng.uniform(20, 25)
    k, nods, seconds = _head_cycles(rng, budget, 2, 6, freq, 0.7 * amp, amp)
    pose = Pose(seconds_to_frames(seconds))
    h = k("h", pose.t)
    pose.relaxed()
    pose.head(nod=h)
    pose.spine(bend=0.12 * h)  # the upper back follows the head a little
    times = how_often(nods)
    phrases = [f"nods {{pos}} head {times}", f"nods yes {times}", f"nods {times} in agreement",
               f"nods {{pos}} head up and down {times}", f"gives {NUMBER_WORDS[nods]} big nods"]
    return Action("nod", pose, phrases, dict(reps=nods, freq=round(float(freq), 2)))


def shake_head(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Shaking the head no: the head yaws ~35 deg to each side two to three times a second."""
    freq, amp = rng.uniform(2.0, 3.0), rng.uniform(30, 40)
    first = float(rng.choice([-1.0, 1.0]))
    k, shakes, seconds = _head_cycles(rng, budget, 2, 6, freq, first * amp, first * amp)
    pose = Pose(seconds_to_frames(seconds))
    h = k("h", pose.t)
    pose.relaxed()
    pose.head(turn=h)
    pose.spine(twist=0.08 * h)
    times = how_often(shakes)
    phrases = [f"shakes {{pos}} head {times}", f"shakes {{pos}} head no {times}",
               f"shakes {{pos}} head from side to side {times}", f"says no by shaking {{pos}} head {times}",
               f"shakes {{pos}} head {times} in disagreement"]
    return Action("shake_head", pose, phrases, dict(reps=shakes, freq=round(float(freq), 2)))


def beckon(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """One hand held forward palm up, the forearm curling up toward the body and out again: "come here"."""
    side = str(rng.choice(["left", "right"]))
    curls = int(rng.integers(2, 6))
    freq = rng.uniform(1.1, 1.7)
    up, down = rng.uniform(0.4, 0.6), rng.uniform(0.4, 0.6)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    curls = budget.fit(curls, 1.0 / freq, lead_in + lead_out + up + down, lo=2)
    start = lead_in + up
    stop = start + curls / freq
    c = Keys(c=0)
    c.add(start, c=0)
    for i in range(curls):
        c.add(start + (i + 0.45) / freq, c=1)
        c.add(start + (i + 1) / freq, c=0)
    pose = Pose(seconds_to_frames(stop + down + lead_out))
    t = pose.t
    on = ease((t - lead_in) / up) * ease((stop + down - t) / down)
    curl = c("c", t)
    pose.relaxed()
    pose.arm(side, flex=on * 45, abd=on * 15, across=on * 10, elbow=on * (20 + 90 * curl))
    pose.head(nod=-on * 3)
    pose.spine(bend=-on * 2)
    times = how_often(curls)
    phrases = [f"beckons with {{pos}} {side} hand", f"beckons someone closer {times} with the {side} hand",
               f"motions someone to come here with {{pos}} {side} hand",
               f"holds {{pos}} {side} hand out palm up and curls it toward {{pos}} body {times}",
               f"gestures come here {times} with {{pos}} {side} arm"]
    return Action("beckon", pose, phrases, dict(side=side, reps=curls, freq=round(float(freq), 2)))


def cheer(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Both fists pumped above the head, the knees bouncing with each pump."""
    pumps = int(rng.integers(2, 7))
    freq = rng.uniform(1.5, 2.2)
    up, down = rng.uniform(0.35, 0.55), rng.uniform(0.4, 0.6)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    pumps = budget.fit(pumps, 1.0 / freq, lead_in + lead_out + up + down, lo=2)
    start = lead_in + up
    stop = start + pumps / freq
    k = Keys(p=0)
    k.add(start, p=0)
    for i in range(pumps):
        k.add(start + (i + 0.4) / freq, p=1)  # fists thrust up
        k.add(start + (i + 1) / freq, p=0)
    pose = Pose(seconds_to_frames(stop + down + lead_out))
    t = pose.t
    on = ease((t - lead_in) / up) * ease((stop + down - t) / down)
    p = k("p", t)
    dip = on * (1 - p) * rng.uniform(0.6, 1.0)  # the knees give between pumps
    pose.relaxed()
    for side in SIDES:
        pose.arm(side, abd=on * (115 + 25 * p), twist=on * 75, elbow=on * (85 - 75 * p), across=on * 10 * p)
        flex, knee = 14 * dip, 30 * dip
        pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(0.0, flex, knee))
    pose.head(nod=-on * 10)
    times = how_often(pumps)
    phrases = ["cheers with both fists in the air", f"pumps both fists above {{pos}} head {times}",
               f"cheers and pumps {{pos}} fists {times}", "celebrates with {pos} fists raised over {pos} head",
               f"cheers excitedly, bouncing and pumping {{pos}} fists {times}"]
    return Action("cheer", pose, phrases, dict(reps=pumps, freq=round(float(freq), 2)))


def facepalm(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """One hand brought up over the face and held there, the head bowed into it; then lowered."""
    side = str(rng.choice(["left", "right"]))
    up, down = rng.uniform(0.5, 0.8), rng.uniform(0.5, 0.8)
    hold = rng.uniform(1.2, 2.5)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    _, hold = _fit(budget, 1, up + down, lead_in + lead_out, hold, lo=0.8)
    k, end = _cycles(lead_in, up, hold, down, 0.0, 1)
    pose = Pose(seconds_to_frames(end + lead_out))
    a = k("a", pose.t)
    bow = rng.uniform(15, 25)
    pose.relaxed()
    # the wrist ~13 cm in front of the head joint, below the chin; the palm covers the eyes
    pose.arm(side, flex=a * 60, abd=a * 30, elbow=a * 100, across=a * 20)
    pose.spine(bend=a * 6)
    pose.head(nod=a * bow)
    phrases = [f"facepalms with {{pos}} {side} hand", f"covers {{pos}} face with {{pos}} {side} hand",
               f"puts {{pos}} {side} hand over {{pos}} face and lowers {{pos}} head",
               f"buries {{pos}} face in {{pos}} {side} hand", f"brings {{pos}} {side} palm to {{pos}} face in frustration"]
    return Action("facepalm", pose, phrases, dict(side=side, hold=round(hold, 2)))


def look_around(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Feet planted, the head and upper body twist to one side, hold, sweep to the other, back to the front."""
    first = str(rng.choice(["left", "right"]))
    sweeps = int(rng.choice([1, 1, 2]))
    turn, cross, back = rng.uniform(0.6, 0.9), rng.uniform(0.9, 1.3), rng.uniform(0.6, 0.9)
    hold = rng.uniform(0.4, 0.9)
    lead_in, lead_out = rng.uniform(0.2, 0.5), rng.uniform(0.2, 0.5)
    # lead in, turn to the first side, then per sweep (hold, across) twice, less the last across; hold, back
    sweeps, hold = _fit(budget, sweeps, 2 * cross, lead_in + lead_out + turn + back - cross, 2 * hold, lo=0.6)
    hold /= 2
    sign = SIDES[first]["sign"]
    k = Keys(y=0)
    t = lead_in
    k.add(t, y=0)
    t += turn
    k.add(t, y=sign)
    for i in range(2 * sweeps - 1):
        t += hold
        k.add(t, y=sign)
        sign = -sign
        t += cross
        k.add(t, y=sign)
    t += hold
    k.add(t, y=sign)
    t += back
    k.add(t, y=0)
    pose = Pose(seconds_to_frames(t + lead_out))
    y = k("y", pose.t)
    yaw = rng.uniform(60, 80)  # head and upper body together
    pose.relaxed()
    pose.spine(twist=0.5 * yaw * y)
    pose.head(turn=0.5 * yaw * y)
    for side in SIDES:  # the arms hang and swing a little with the shoulders
        pose.arm(side, abd=3 * np.abs(y))
    other = OTHER[first]
    times = f" {how_often(sweeps)}" if sweeps > 1 else ""
    phrases = [f"looks around, first to the {first} and then to the {other}{times}",
               f"scans the area to {{pos}} {first} and {other}{times}",
               f"twists {{pos}} head and upper body to look {first} and {other}{times}",
               f"glances over {{pos}} {first} shoulder and then {{pos}} {other} shoulder",
               f"looks all around {{pos}} surroundings, twisting {first} and {other} with {{pos}} feet planted"]
    return Action("look_around", pose, phrases, dict(first=first, reps=sweeps, yaw=round(float(yaw), 1)))


def stretch(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """kind "overhead": hands interlaced above the head, pushed up; "side": the same, bending left and right;
    "back": both arms stretched back and out, chest open."""
    kind = str(rng.choice(["overhead", "side", "back"]))
    up, down = rng.uniform(0.8, 1.2), rng.uniform(0.8, 1.2)
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)
    pose_t = Keys(b=0)
    first = str(rng.choice(["left", "right"]))
    if kind == "side":
        reps = int(rng.choice([1, 1, 2]))
        bend, hold = rng.uniform(0.8, 1.1), rng.uniform(0.5, 1.0)
        reps = budget.fit(reps, 4 * bend + 2 * hold, lead_in + lead_out + up + down)
        # one bend to each side must fit a short budget: everything but the leads is sped up to fit
        total = lead_in + lead_out + up + down + reps * (4 * bend + 2 * hold)
        speed = max(1.0, (total - lead_in - lead_out) / (budget.seconds - 0.05 - lead_in - lead_out))
        up, down, bend, hold = up / speed, down / speed, bend / speed, hold / speed
        t = lead_in + up
        pose_t.add(t, b=0)
        sign = SIDES[first]["sign"]
        for _ in range(reps):
            for s in (sign, -sign):
                t += bend
                pose_t.add(t, b=s)
                t += hold
                pose_t.add(t, b=s)
                t += bend
                pose_t.add(t, b=0)
        k, end = _cycles(lead_in, up, t - lead_in - up, down, 0.0, 1)
    else:
        reps = int(rng.choice([1, 1, 2]))
        hold, rest = rng.uniform(1.2, 2.5), rng.uniform(0.3, 0.6)
        reps, hold = _fit(budget, reps, up + down + rest, lead_in + lead_out - rest, hold, lo=0.8)
        k, end = _cycles(lead_in, up, hold, down, rest, reps)
    pose = Pose(seconds_to_frames(end + lead_out))
    t = pose.t
    a = k("a", t)
    pose.relaxed()
    if kind == "back":
        for side in SIDES:
            pose.arm(side, flex=-a * 40, abd=a * 20, elbow=-a * 10, across=-a * 10)
        pose.spine(bend=-a * 8)
        pose.head(nod=-a * 12)
    else:
        for side in SIDES:  # the wrists meet above the head, fingers interlaced
            pose.arm(side, flex=a * 170, abd=a * 10, twist=-a * 30, elbow=-a * 8)
        lean = pose_t("b", t) * rng.uniform(20, 28)
        pose.spine(bend=-a * 5, lean=lean)
        pose.head(nod=-a * 8, tilt=0.3 * lean)
    times = f" {how_often(reps)}" if reps > 1 else ""
    other = OTHER[first]
    if kind == "overhead":
        phrases = [f"stretches {{pos}} arms up over {{pos}} head{times}",
                   f"stretches upward with {{pos}} hands clasped above {{pos}} head{times}",
                   "interlaces {pos} fingers and stretches both arms overhead",
                   f"stretches {{pos}} arms overhead with the fingers interlaced{times}"]
    elif kind == "side":
        phrases = [f"stretches {{pos}} arms overhead and bends to the {first} and to the {other}{times}",
                   f"leans from side to side with {{pos}} arms raised overhead to stretch{times}",
                   f"bends sideways to the {first} and then the {other} with {{pos}} hands clasped overhead",
                   f"stretches {{pos}} sides, bending {first} and {other}{times}"]
    else:
        phrases = [f"stretches {{pos}} arms back and opens {{pos}} chest{times}",
                   f"stretches both arms out backward{times}",
                   "leans back slightly and stretches {pos} arms back",
                   f"opens {{pos}} chest by stretching {{pos}} arms back{times}"]
    return Action("stretch", pose, phrases, dict(kind=kind, first=first, reps=reps))


FAMILIES: tuple = (point_left, point_right, point_forward, salute, shrug, nod, shake_head, beckon, cheer, facepalm,
                   look_around, stretch)
WORDS: dict = {
    "ADJ": "big military",
    "ADV": "excitedly overhead upward here closer sideways",
    "ADP": "as if by from toward",
    "PRON": "something someone who",
    "INTJ": "yes no",
    "NOUN": {"agreement": "agreement", "area": "area", "attention": "attention", "brow": "brow",
             "disagreement": "disagreement", "face": "face", "finger": "finger", "fingers": "finger",
             "forehead": "forehead", "frustration": "frustration", "index": "index", "air": "air",
             "palm": "palm", "palms": "palm", "salute": "salute", "shoulders": "shoulder", "shrug": "shrug",
             "sides": "side", "surroundings": "surroundings", "feet": "foot"},
    "VERB": {"beckons": "beckon", "bends": "bend", "bouncing": "bounce", "brings": "bring", "buries": "bury",
             "celebrates": "celebrate", "cheers": "cheer", "clasped": "clasp", "covers": "cover", "curls": "curl",
             "come": "come", "extends": "extend", "facepalms": "facepalm", "gestures": "gesture",
             "gives": "give", "glances": "glance", "interlaced": "interlace", "interlaces": "interlace",
             "knows": "know", "leans": "lean", "look": "look", "motions": "motion",
             "opens": "open", "planted": "plant", "pointing": "point", "points": "point", "pumping": "pump",
             "pumps": "pump", "raised": "raise", "say": "say", "says": "say", "scans": "scan", "shakes": "shake",
             "shaking": "shake", "shrugs": "shrug", "snaps": "snap", "spreads": "spread", "stretches": "stretch",
             "stretch": "stretch", "stretching": "stretch", "turned": "turn", "twisting": "twist", "twists": "twist",
             "bending": "bend", "salutes": "salute"},
    "NOUN_OR_VERB": {"nods": "nod"},  # "nods his head", "gives three big nods"
}
LAST_ONLY: tuple[str, ...] = ()
