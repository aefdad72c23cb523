"""Interactions mimed without props: picking something up off the floor, throwing overhand and underhand,
pushing and pulling something heavy, carrying a box, reaching up to a shelf, climbing a ladder in place and
opening a door.

Each is a family as action.py describes, `(rng, budget) -> Action`: keyframed joint curves (curves.Keys), with
the walking ones stepping through the gait engine with their arms held still (footwork.py). FAMILIES lists this
module's families in their fixed order (families.py appends it to the registry); WORDS holds every caption word
they use that the shared lexicon (captions.py) lacks; LAST_ONLY names the families that do not end standing
(none: all of them end on their feet).
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget
from .captions import NUMBER_WORDS, adverb, how_often
from .curves import Keys, ease
from .footwork import SHUFFLE, key_step, keyed_legs, walk_steps
from .gaits import WALK
from .pose import OTHER, SIDES, Pose, flat_foot, seconds_to_frames

# --- pick_up -------------------------------------------------------------------------------------------------

def pick_up(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    how = str(rng.choice(["waist", "knees"]))
    speed = str(rng.choice(["slow", "normal"], p=[0.35, 0.65]))
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.5)
    down, grab, hold = rng.uniform(0.9, 1.15), rng.uniform(0.35, 0.55), rng.uniform(0.6, 1.1)
    if speed == "slow" and lead_in + lead_out + 2.8 * down + grab + hold > budget.seconds - 0.05:
        speed = "normal"
    down *= 1.4 if speed == "slow" else 1.0
    up = 1.1 * down
    hold = max(0.3, min(hold, budget.seconds - 0.05 - lead_in - lead_out - down - grab - up))
    # bottom pose: the thighs' and the shins' angles to the vertical, the trunk's pitch (root, spine) and
    # the arms' angle to the vertical (forward of straight down)
    if how == "waist":  # legs nearly straight, the hips back, the trunk folded past horizontal
        low = dict(thigh=52, shank=18, pitch=72, bend=40, arm=8, abd=10)
    else:  # a deep crouch, the trunk leaning over the knees, the arms reaching past them
        low = dict(thigh=95, shank=32, pitch=48, bend=20, arm=24, abd=16)
    k = Keys(thigh=0, shank=0, pitch=0, bend=0, arm=0, abd=0, elbow=12, close=0, carry=0, nod=0)
    t = lead_in
    k.add(t, thigh=0, shank=0, pitch=0, bend=0, arm=0, abd=0, elbow=12, close=0, carry=0, nod=0)
    k.add(t + 0.55 * down, **{c: 0.6 * v for c, v in low.items()}, elbow=18, nod=-5)
    t += down
    k.add(t, **low, elbow=8, close=0.3, nod=-15)
    k.add(t + grab, **low, elbow=8, close=1, nod=-15)  # the hands come together on the thing: grab it
    t += grab
    k.add(t + 0.45 * up, **{c: 0.45 * v for c, v in low.items()}, elbow=45, close=1, carry=0.5, nod=-8)
    t += up
    k.add(t, thigh=0, shank=0, pitch=0, bend=-3, arm=0, abd=0, elbow=0, close=1, carry=1, nod=-6)
    t += hold
    k.add(t, carry=1, close=1, bend=-3, nod=-6)
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    thigh, shank, pitch, bend = k("thigh", tt), k("shank", tt), k("pitch", tt), k("bend", tt)
    carry, close = k("carry", tt), k("close", tt)
    trunk = pitch + bend
    pose.root(pitch=pitch)
    pose.spine(bend=2 + bend)
    flex, knee = thigh + pitch, thigh + shank
    for side in SIDES:
        pose.leg(side, flex=flex, abd=k("abd", tt), knee=knee, dorsi=flat_foot(pitch, flex, knee))
        # down: the arms hang `arm` degrees forward of straight down, closing in on the thing at the bottom;
        # up: the forearms held level in front of the waist, holding it
        pose.arm(side, flex=(1 - carry) * (trunk + k("arm", tt)) + carry * 12,
                 abd=4 + (1 - carry) * (3 - 5 * close), across=(1 - carry) * 6 * close + carry * 6,
                 elbow=k("elbow", tt) + carry * 80)
    pose.head(nod=k("nod", tt))
    adv = adverb(speed)
    if how == "waist":
        phrases = [f"bends over at the waist and picks something up off the floor{adv}",
                   "bends down, picks up an object from the ground and stands back up",
                   f"leans down{adv} to pick up a box and holds it at {{pos}} waist",
                   "folds forward at the waist and lifts something off the floor",
                   f"picks up something from the floor{adv} by bending at the waist"]
    else:
        phrases = [f"bends {{pos}} knees deeply{adv} and picks something up off the floor",
                   "bends {pos} knees, picks up an object from the ground and stands back up",
                   f"gets down low{adv} to pick up a box and holds it at {{pos}} waist",
                   "lowers {pos} hips and lifts something off the floor",
                   f"picks up something from the floor{adv} bending {{pos}} knees"]
    return Action("pick_up", pose, phrases, dict(how=how, speed=speed))


# --- throws --------------------------------------------------------------------------------------------------

def _throw(rng, budget: TimeBudget, over: bool) -> Action:
    side = str(rng.choice(["right", "left"]))
    other = OTHER[side]
    sgn = SIDES[side]["sign"]  # +1 left: twist > 0 turns the shoulders to the left
    reps = int(rng.choice([1, 1, 2, 3]))
    tempo = rng.uniform(0.9, 1.1)
    stride = rng.uniform(14.0, 19.0)  # thigh angle of the step: 0.4-0.55 m between the feet
    windup, step, whip, follow, close = 0.55 / tempo, 0.3 / tempo, 0.3 / tempo, 0.45 / tempo, 0.6 / tempo
    rest = rng.uniform(0.3, 0.6)
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.4, 0.7)
    per = windup + step + whip + follow + close + rest
    reps = budget.fit(reps, per, lead_in + lead_out - rest)
    zero = dict(flex=0, abd=0, twist=0, elbow=12, across=0, oflex=0, oelbow=12, spin=0, bend=0,
                lean=0, pitch=0, crouch=0)
    k = Keys(**zero, **{f"hip_{s}": 0 for s in SIDES}, **{f"knee_{s}": 0 for s in SIDES})
    t = lead_in
    for i in range(reps):
        k.add(t, **zero)
        if over:  # the arm up and back, elbow bent, the hand behind the head; the shoulders turned away
            cock = dict(flex=-5, abd=92, twist=80, elbow=95, across=-10, oflex=60, oelbow=40, spin=-40,
                        bend=-6, lean=6, pitch=0, crouch=0)
        else:  # the arm swings down and back past the hip; the knees bend
            cock = dict(flex=-50, abd=8, twist=0, elbow=10, across=0, oflex=25, oelbow=30, spin=-20, bend=10,
                        lean=0, pitch=6, crouch=12)
        k.add(t + windup, **cock)
        # the opposite foot steps forward while the arm is cocked (shoulders still turned away)
        t = key_step(k, t + windup, other, step, 0, stride, 0, -stride)
        k.add(t, **cock)
        if over:  # over the shoulder: the elbow leads, the forearm whips through, the trunk turns and bends
            k.add(t + 0.5 * whip, flex=40, abd=82, twist=45, elbow=75, across=0, spin=0, bend=5, lean=0)
            k.add(t + whip, flex=100, abd=30, twist=0, elbow=20, across=5, oflex=25, oelbow=60, spin=30, bend=18)
            t += whip
            k.add(t + follow, flex=35, abd=5, twist=0, elbow=20, across=35, oflex=5, oelbow=30, spin=35, bend=24,
                  pitch=6)
        else:  # forward and up, letting go at hip height, the hand following through to chest height
            k.add(t + 0.6 * whip, flex=10, abd=6, elbow=8, oflex=10, spin=0, bend=8, pitch=4, crouch=8)
            k.add(t + whip, flex=45, abd=5, elbow=8, across=5, oflex=5, spin=12, bend=4, pitch=2, crouch=4)
            t += whip
            k.add(t + follow, flex=70, abd=5, elbow=12, across=8, oflex=0, oelbow=20, spin=15, bend=2, pitch=0,
                  crouch=0)
        t += follow
        # the back foot comes up beside the front one, the arms settle
        t = key_step(k, t, side, close, -stride, 0, stride, 0)
        k.add(t, **zero)
        if i < reps - 1:
            t += rest
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    pitch = k("pitch", tt)
    crouch = k("crouch", tt)
    pose.root(pitch=pitch)
    keyed_legs(pose, k, tt, pitch)
    for s in SIDES:  # the knees soften with the crouch, on top of the steps
        pose.leg(s, flex=crouch, knee=2 * crouch, dorsi=flat_foot(0, crouch, 2 * crouch))
    pose.spine(bend=2 + k("bend", tt), twist=-sgn * k("spin", tt), lean=sgn * k("lean", tt))
    pose.arm(side, flex=k("flex", tt), abd=7 + k("abd", tt), twist=k("twist", tt), elbow=k("elbow", tt),
             across=k("across", tt))
    pose.arm(other, flex=k("oflex", tt), abd=7, elbow=k("oelbow", tt))
    pose.head(turn=sgn * 0.6 * k("spin", tt))  # the eyes stay on the target
    times = how_often(reps)
    n = NUMBER_WORDS[reps]
    if over:
        balls = f"{n} balls" if reps > 1 else "a ball"
        phrases = [f"throws {balls} overhand with the {side} hand",
                   f"winds up and throws overhand with {{pos}} {side} arm {times}",
                   f"pitches a ball with {{pos}} {side} arm, stepping forward {times}",
                   f"throws something overhand {times} using {{pos}} {side} hand",
                   f"cocks {{pos}} {side} arm back over {{pos}} shoulder and throws {times}"]
        name = "throw_overhand"
    else:
        balls = f"{n} balls" if reps > 1 else "a ball"
        phrases = [f"tosses {balls} underhand with the {side} hand",
                   f"swings {{pos}} {side} arm back and tosses something underhand {times}",
                   f"throws underhand with {{pos}} {side} arm {times}",
                   f"bowls a ball with {{pos}} {side} hand {times}",
                   f"swings {{pos}} {side} arm down and forward and lets go {times}"]
        name = "throw_underhand"
    return Action(name, pose, phrases, dict(side=side, reps=reps))


def throw_overhand(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _throw(rng, budget, over=True)


def throw_underhand(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _throw(rng, budget, over=False)


# --- pushing, pulling, carrying ------------------------------------------------------------------------------

def _lean(pose: Pose, tt: np.ndarray, trunk: np.ndarray, legs: np.ndarray, knee: np.ndarray) -> None:
    """Lean the whole body: the root pitched `trunk` degrees, the thighs `legs` degrees forward of the
    vertical (< 0: the feet behind the hips), the knees bent, the feet flat (on top of any gait)."""
    pose.root(pitch=trunk)
    for side in SIDES:
        flex = legs + trunk
        pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(trunk, flex, knee))


def push(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    steps = int(rng.integers(2, 9))
    speed = str(rng.choice(["slow", "normal"], p=[0.4, 0.6]))
    cadence = {"slow": 1.1, "normal": 1.45}[speed] * rng.uniform(0.92, 1.08)
    stride = rng.uniform(0.7, 0.9)
    set_t, lead_in, lead_out = rng.uniform(0.6, 0.8), rng.uniform(0.3, 0.6), rng.uniform(0.4, 0.7)
    steps = budget.fit(steps, 1.0 / cadence, lead_in + 2 * set_t + lead_out + 0.2, lo=2)
    start = lead_in + set_t + 0.1
    end = start + steps / cadence
    pose = Pose(seconds_to_frames(end + 0.1 + set_t + lead_out))
    tt = pose.t
    on = ease((tt - lead_in) / set_t) * ease((end + 0.1 + set_t - tt) / set_t)
    amp = walk_steps(pose, start, steps, cadence, stride, style=SHUFFLE)
    drive = amp / stride
    pose.spine(bend=2 + 4 * on)
    # the body leans 20-25 degrees forward into the thing from the hips
    trunk = on * (16 + 4 * drive)
    # in a slight crouch, the feet under the hips (thighs tilted back, as a sprinter's, would set the front
    # foot down lower than the back one and the body would drop onto it)
    _lean(pose, tt, trunk=trunk, legs=on * 8, knee=on * 16)
    trunk = trunk + 4 * on  # and the spine's bend
    for side in SIDES:  # both arms out at chest height (75 degrees forward of hanging down), the palms on the
        # thing; an arm's flexion is measured from the trunk, which leans forward
        pose.arm(side, flex=on * 75 + trunk, abd=-3 * on, across=on * 4, elbow=12 + on * 14)
    pose.head(nod=-on * 12)
    n = NUMBER_WORDS[steps]
    adv = adverb(speed)
    phrases = [f"pushes something heavy forward{adv}", f"leans forward and pushes with both hands, taking {n} steps",
               f"pushes a heavy object{adv} with both arms out in front",
               f"shoves something heavy {n} steps forward",
               f"pushes against a heavy box and moves it forward {n} steps"]
    return Action("push", pose, phrases, dict(steps=steps, speed=speed))


def pull(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    mode = str(rng.choice(["rope", "backward"]))
    reach_t, grab_t = rng.uniform(0.5, 0.7), rng.uniform(0.4, 0.6)
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.4, 0.7)
    if mode == "rope":
        reps = int(rng.integers(3, 9))
        per = rng.uniform(0.6, 0.85)  # one hand over the other
        reps = budget.fit(reps, per, lead_in + reach_t + grab_t + 0.6 + lead_out, lo=2)
        steps = 0
        work = reps * per
    else:
        steps = int(rng.integers(2, 7))
        cadence = rng.uniform(1.1, 1.4)
        reps = 1
        steps = budget.fit(steps, 1.0 / cadence, lead_in + reach_t + grab_t + 0.8 + lead_out, lo=2)
        work = steps / cadence + 0.2
    start = lead_in + reach_t + grab_t
    end = start + work
    pose = Pose(seconds_to_frames(end + 0.6 + lead_out))
    tt = pose.t
    # reach: the arms go out straight at chest height; lean: the body sits back against the pull
    reach = ease((tt - lead_in) / reach_t) * ease((end + 0.6 - tt) / 0.6)
    lean = ease((tt - lead_in - reach_t) / grab_t) * ease((end + 0.5 - tt) / 0.5)
    pose.spine(bend=2 - 6 * lean)
    _lean(pose, tt, trunk=-14 * lean, legs=22 * lean, knee=34 * lean)
    if mode == "rope":
        # hand over hand: each hand in turn reaches out along the rope and draws it in to the belly
        ph = np.clip((tt - start) / per, 0, reps)
        w = 0.5 - 0.5 * np.cos(np.pi * ph)  # 0 -> 1 over each hand-over: the right hand out, then back
        w = np.where(ph >= reps, np.where(reps % 2 == 1, 1.0, 0.0), w)
        mix = {"right": w, "left": 1 - w}
        fade = ease((tt - start) / 0.3) * ease((end - tt) / 0.3)
        for side in SIDES:
            m = 0.5 + fade * (mix[side] - 0.5)  # 1 reaching out, 0 drawn in
            # 80 degrees forward of hanging down reaching out, 30 drawn in, measured from the leaning trunk
            pose.arm(side, flex=reach * (30 + 42 * m) - 20 * lean, abd=4 + 6 * (1 - m) * reach,
                     across=reach * (8 + 6 * m),
                     elbow=12 + reach * (8 + 70 * (1 - m)))
        pose.spine(twist=8 * fade * (w - 0.5))
    else:
        walk_steps(pose, start + 0.1, steps, cadence, rng.uniform(0.45, 0.6), direction=-1.0)
        for side in SIDES:  # both hands together on the rope in front of the belly
            pose.arm(side, flex=reach * 78 - 38 * lean, across=reach * 12, elbow=12 + reach * (4 + 50 * lean))
    pose.head(nod=4 * lean)
    n = NUMBER_WORDS[reps if mode == "rope" else steps]
    if mode == "rope":
        phrases = ["pulls on a rope hand over hand", f"leans back and pulls a rope in {n} times",
                   f"grabs a rope and pulls it toward {{pos}} body {how_often(reps)}",
                   "reaches forward, grabs something and pulls it hand over hand",
                   f"hauls in a rope with both hands {how_often(reps)}"]
    else:
        phrases = ["grabs something heavy and pulls it, backing up",
                   f"leans back and drags something, taking {n} steps back",
                   f"pulls a heavy object toward {{pos}} body and backs up {n} steps",
                   "reaches forward, grabs a rope and pulls, stepping backwards",
                   f"hauls something heavy back {n} steps with both hands"]
    return Action("pull", pose, phrases, dict(mode=mode, reps=reps, steps=steps))


def carry(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    steps = int(rng.integers(3, 11))
    speed = str(rng.choice(["slow", "normal"], p=[0.4, 0.6]))
    cadence = {"slow": 1.3, "normal": 1.7}[speed] * rng.uniform(0.92, 1.08)
    stride = {"slow": 0.85, "normal": 1.1}[speed] * rng.uniform(0.92, 1.08)
    lift_t, lead_in, lead_out = rng.uniform(0.4, 0.6), rng.uniform(0.1, 0.3), rng.uniform(0.3, 0.6)
    steps = budget.fit(steps, 1.0 / cadence, lead_in + 2 * lift_t + lead_out + 0.4, lo=2)
    start = lead_in + lift_t + 0.2
    end = start + steps / cadence
    pose = Pose(seconds_to_frames(end + 0.2 + lift_t + lead_out))
    tt = pose.t
    hold = ease((tt - lead_in) / lift_t)  # the box is held to the end
    walk_steps(pose, start, steps, cadence, stride)
    pose.spine(bend=2 - 4 * hold)  # the upper body leans back a little under the weight
    for side in SIDES:  # upper arms down by the sides, forearms level, hands ~35 cm apart at waist height
        pose.arm(side, flex=hold * 14, abd=-5 * hold, across=hold * 6, elbow=12 + hold * 80)
    n = NUMBER_WORDS[steps]
    adv = adverb(speed)
    phrases = [f"carries a box forward{adv}", f"carries something heavy in front of {{pos}} body for {n} steps",
               f"holds a box at {{pos}} waist and carries it {n} steps forward",
               f"carries a box in both arms{adv}", f"walks forward{adv} carrying a box"]
    return Action("carry", pose, phrases, dict(steps=steps, speed=speed))


# --- reaching up, climbing -----------------------------------------------------------------------------------

def reach_up(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    side = str(rng.choice(["right", "left"]))
    other = OTHER[side]
    sgn = SIDES[side]["sign"]
    reps = int(rng.choice([1, 1, 2]))
    up, hold, down, rest = rng.uniform(0.7, 1.0), rng.uniform(0.5, 1.0), rng.uniform(0.7, 1.0), 0.3
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)
    reps = budget.fit(reps, up + hold + down + rest, lead_in + lead_out - rest)
    k = Keys(a=0, toes=0)
    t = lead_in
    for i in range(reps):
        k.add(t, a=0, toes=0)
        k.add(t + 0.6 * up, a=0.8)
        k.add(t + up, a=1, toes=1)
        t += up
        k.add(t + hold, a=1, toes=1)
        t += hold
        k.add(t + 0.5 * down, toes=0)
        t += down
        k.add(t, a=0, toes=0)
        if i < reps - 1:
            t += rest
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    a, toes = k("a", tt), k("toes", tt)
    pose.relaxed()
    # up on the toes: 30 degrees of heel raise lift the body ~7 cm
    for s in SIDES:
        pose.leg(s, dorsi=flat_foot(0, 0, 0, lift=28 * toes))
    pose.arm(side, flex=a * 174, abd=a * 4, across=-a * 4, elbow=-a * 10, shrug=a * 14)
    pose.arm(other, flex=a * 10, abd=a * 4)
    pose.spine(bend=-a * 5, lean=-sgn * a * 6)  # stretching up and over toward the shelf
    pose.head(nod=-a * 22, turn=sgn * a * 6)
    times = how_often(reps)
    phrases = [f"reaches up high with {{pos}} {side} hand",
               f"goes up on {{pos}} toes and reaches up with the {side} arm {times}",
               f"reaches up to a high shelf with {{pos}} {side} hand {times}",
               f"extends {{pos}} {side} arm up to grab something from a shelf",
               f"rises onto {{pos}} toes reaching up with {{pos}} {side} hand {times}"]
    return Action("reach_up", pose, phrases, dict(side=side, reps=reps))


def climb_ladder(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.integers(4, 11))  # rungs: one hand reaches up and the opposite knee lifts
    speed = str(rng.choice(["slow", "normal"], p=[0.4, 0.6]))
    per = {"slow": 1.0, "normal": 0.75}[speed] * rng.uniform(0.92, 1.08)
    knee_up = rng.uniform(75, 90)
    lead_in, lead_out, raise_t = rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6), 0.5
    reps = budget.fit(reps, per, lead_in + lead_out + 2 * raise_t, lo=2)
    start = lead_in + raise_t
    end = start + reps * per
    pose = Pose(seconds_to_frames(end + raise_t + lead_out))
    tt = pose.t
    on = ease((tt - lead_in) / raise_t) * ease((end + raise_t - tt) / raise_t)
    # rung i (i = 0, 1, ...) over [start + i per, start + (i + 1) per): the right hand reaches up on even
    # rungs, the left on odd ones, and the opposite knee lifts; a hand that is up pulls down through the next
    ph = (tt - start) / per
    r = np.floor(ph)
    f = ph - r
    inside = (ph >= 0) & (ph < reps)
    lift = np.where(inside, np.sin(np.pi * f) ** 2, 0.0)  # the knee: up and back down within the rung
    for side, parity in (("right", 0), ("left", 1)):
        mine = inside & (np.mod(r, 2) == parity)
        last = (ph >= 1) & (ph < reps + 1) & (np.mod(r - 1, 2) == parity)
        # hand height 1 = high on the ladder, 0 = pulled down to the chin: up in its own rung, down in the next
        h = np.where(mine, ease(f / 0.6), np.where(last, 1 - ease(f), 0.0))
        h = 0.35 + 0.65 * h
        pose.arm(side, flex=on * (105 + 65 * h), abd=on * (10 - 4 * h), across=on * 6 * (1 - h),
                 elbow=12 + on * (75 - 75 * h))
        knee_side = OTHER[side]
        kl = np.where(mine, lift, 0.0)
        # the shin stays under the knee while the foot is near the floor (knee twice the hip), so the foot
        # comes straight down where it left
        flex = knee_up * kl
        knee = flex + 45 * (1 - np.exp(-flex / 45))
        pose.leg(knee_side, flex=flex, knee=knee, dorsi=flat_foot(0, flex, knee))
        pose.support[:, 0 if knee_side == "left" else 1] &= kl < 0.02
    pose.spine(bend=2 + 3 * on)
    pose.head(nod=-on * 12)
    n = NUMBER_WORDS[reps]
    adv = adverb(speed)
    phrases = [f"climbs an imaginary ladder in place{adv}", f"mimes climbing a ladder, {n} rungs",
               f"pretends to climb a ladder, reaching up hand over hand {how_often(reps)}",
               f"climbs a ladder on the spot, lifting {{pos}} knees high{adv}",
               f"climbs up {n} rungs of a ladder without moving"]
    return Action("climb_ladder", pose, phrases, dict(reps=reps, speed=speed))


# --- open_door -----------------------------------------------------------------------------------------------

def open_door(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    side = str(rng.choice(["right", "left"]))
    sgn = SIDES[side]["sign"]
    steps = int(rng.integers(2, 5))
    cadence, stride = rng.uniform(1.6, 1.9), rng.uniform(0.85, 1.05)
    reach_t, turn_t, open_t, back_t = rng.uniform(0.5, 0.7), rng.uniform(0.3, 0.4), rng.uniform(0.8, 1.0), 0.5
    lead_in, lead_out = rng.uniform(0.3, 0.5), rng.uniform(0.3, 0.6)
    steps = budget.fit(steps, 1.0 / cadence, lead_in + reach_t + turn_t + open_t + back_t + 0.2 + lead_out, lo=2)
    k = Keys(flex=0, abd=0, across=0, elbow=0, twist=0, spin=0, **{f"hip_{s}": 0 for s in SIDES},
             **{f"abd_{s}": 0 for s in SIDES}, **{f"knee_{s}": 0 for s in SIDES})
    t = lead_in
    k.add(t, flex=0, abd=0, across=0, elbow=0, twist=0)
    t += reach_t
    k.add(t, flex=44, abd=0, across=10, elbow=18, twist=0)  # the hand on the handle, at waist height
    t += turn_t
    k.add(t, flex=44, abd=0, across=10, elbow=22, twist=-35)  # turns the handle
    # the door swings open toward the body: the hand draws back and out to its side while the foot on that
    # side steps back and out of its way
    o0 = t
    k.add(t, **{f"abd_{side}": 0})
    t = key_step(k, t, side, open_t, 0, -14, 0, 6, knee=30)
    k.add(o0 + 0.5 * open_t, **{f"abd_{side}": 5})
    k.add(t, **{f"abd_{side}": 9})
    k.add(t, flex=25, abd=45, across=0, elbow=55, twist=-20, spin=12)
    # lets go; the back foot comes forward beside the other
    k.add(t + 0.5 * back_t, flex=10, abd=15, across=0, elbow=25, twist=0)
    t = key_step(k, t, side, back_t, -14, 0, 6, 0, knee=35)
    k.add(t, flex=0, abd=0, across=0, elbow=0, twist=0, spin=0, **{f"abd_{side}": 0})
    start = t + 0.05
    end = start + steps / cadence
    pose = Pose(seconds_to_frames(end + 0.15 + lead_out))
    tt = pose.t
    keyed_legs(pose, k, tt, np.zeros(pose.T))
    support = pose.support.copy()
    walk_steps(pose, start, steps, cadence, stride, style=WALK)
    pose.support &= support
    pose.relaxed()
    pose.arm(side, flex=k("flex", tt), abd=k("abd", tt), across=k("across", tt), elbow=k("elbow", tt),
             twist=k("twist", tt))
    pose.spine(twist=sgn * k("spin", tt))
    pose.head(nod=8 * ease((tt - lead_in) / reach_t) * ease((start - tt) / 0.5))
    n = NUMBER_WORDS[steps]
    phrases = [f"opens a door with {{pos}} {side} hand and walks through",
               f"reaches for a door handle with the {side} hand, pulls the door open and steps through",
               f"pulls a door open with {{pos}} {side} hand and walks {n} steps through it",
               f"grabs the handle with {{pos}} {side} hand, swings the door open and goes through",
               f"turns a door handle with {{pos}} {side} hand, opens it and walks in"]
    return Action("open_door", pose, phrases, dict(side=side, steps=steps))


FAMILIES: tuple = (pick_up, throw_overhand, throw_underhand, push, pull, carry, reach_up, climb_ladder, open_door)
WORDS: dict = {
    "DET": "an",
    "PRON": "something",
    "ADJ": "heavy imaginary open",
    "ADV": "overhand underhand away",
    "ADP": "against by for from off onto through toward",
    "NOUN": {"ball": "ball", "balls": "ball", "box": "box", "door": "door", "feet": "foot", "floor": "floor",
             "ground": "ground", "handle": "handle", "hips": "hip", "ladder": "ladder", "object": "object",
             "rope": "rope", "rung": "rung", "rungs": "rung", "shelf": "shelf", "spot": "spot", "toes": "toe"},
    "VERB": {"backing": "back", "backs": "back", "bending": "bend", "bowls": "bowl", "carries": "carry",
             "carrying": "carry", "climb": "climb", "cocks": "cock", "climbing": "climb", "climbs": "climb",
             "drags": "drag", "extends": "extend", "folds": "fold", "gets": "get", "go": "go", "goes": "go",
             "grab": "grab", "grabs": "grab",
             "hauls": "haul", "leans": "lean", "lets": "let", "lifting": "lift", "mimes": "mime", "opens": "open",
             "pick": "pick", "picks": "pick", "pitches": "pitch", "pretends": "pretend", "pulls": "pull",
             "pushes": "push", "reaches": "reach", "reaching": "reach", "shoves": "shove", "stepping": "step",
             "taking": "take", "tosses": "toss", "winds": "wind"},
}
LAST_ONLY: tuple[str, ...] = ()
