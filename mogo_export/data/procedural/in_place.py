"""The action families performed on the spot: waving, kicking, squatting, sitting down, punching, clapping,
raising both arms, standing idle and bowing.

Each is a family as action.py describes, `(rng, budget) -> Action`: keyframed joint curves (curves.Keys)
repeated as often as the budget allows, with verb phrases naming exactly the sampled parameters. The
families that move over the floor are in locomotion.py.
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget
from .captions import NUMBER_WORDS, adverb, how_often
from .curves import Keys, ease
from .pose import MIN_SECONDS, OTHER, SIDES, Pose, flat_foot, seconds_to_frames


def hold_cycles(channel: str, start: float, rise: float, hold: float, rest: float, reps: int) -> tuple[Keys, float]:
    """Keys of `reps` cycles on one channel: rise 0 -> 1, hold, fall back in `rise`, rest; -> (keys, end time)."""
    k = Keys(**{channel: 0})
    t = start
    for _ in range(reps):
        k.add(t, **{channel: 0})
        k.add(t + rise, **{channel: 1})
        k.add(t + rise + hold, **{channel: 1})
        t += 2 * rise + hold
        k.add(t, **{channel: 0})
        t += rest
    return k, t


def _wave(rng, side: str, budget: TimeBudget) -> Action:
    waves = int(rng.integers(2, 7))
    high = bool(rng.random() < 0.5)
    freq = rng.uniform(1.3, 2.4)
    raise_t, lower_t = rng.uniform(0.4, 0.7), rng.uniform(0.4, 0.7)
    lead_in, lead_out = rng.uniform(0.3, 0.8), rng.uniform(0.3, 0.8)
    waves = budget.fit(waves, 1.0 / freq, lead_in + lead_out + raise_t + lower_t, lo=2)
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
    times = how_often(waves)
    where = "above {pos} head" if high else "at shoulder height"
    phrases = [f"waves with {{pos}} {side} hand", f"raises {{pos}} {side} hand and waves",
               f"waves {{pos}} {side} arm {where}", f"waves hello with the {side} hand",
               f"lifts {{pos}} {side} arm and waves it {times}"]
    return Action(f"wave_{side}_hand", pose, phrases, dict(side=side, waves=waves, high=high))


def wave_right_hand(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _wave(rng, "right", budget)


def wave_left_hand(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _wave(rng, "left", budget)


def _kick(rng, side: str, budget: TimeBudget) -> Action:
    reps = int(rng.choice([1, 1, 2, 3]))
    height = str(rng.choice(["low", "middle", "high"]))
    peak = {"low": 45.0, "middle": 70.0, "high": 95.0}[height] + rng.uniform(-5, 5)
    tempo = rng.uniform(0.85, 1.1)
    windup, strike, retract, land, rest = 0.35 / tempo, 0.3 / tempo, 0.3 / tempo, 0.3 / tempo, rng.uniform(0.2, 0.5)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    reps = budget.fit(reps, windup + strike + retract + land + rest, lead_in + lead_out)
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
    times = how_often(reps)
    how = {"low": "low", "middle": "at waist height", "high": "high"}[height]
    phrases = [f"kicks with {{pos}} {side} leg", f"kicks {{pos}} {side} foot forward {times}",
               f"kicks {how} with the {side} leg" + (f" {times}" if reps > 1 else ""),
               f"kicks forward {times} using {{pos}} {side} leg", f"swings {{pos}} {side} leg forward in a kick"]
    return Action(f"kick_{side}", pose, phrases, dict(side=side, reps=reps, height=height))


def kick_right(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _kick(rng, "right", budget)


def kick_left(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _kick(rng, "left", budget)


def squat(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.integers(1, 6))
    deep = bool(rng.random() < 0.5)
    speed = str(rng.choice(["slow", "normal"]))
    down = (1.3 if speed == "slow" else 0.8) * rng.uniform(0.9, 1.1)
    hold = rng.uniform(0.1, 0.5)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    reps = budget.fit(reps, 2 * down + 2 * hold, lead_in + lead_out)
    thigh, shank, pitch = (90.0, 35.0, 40.0) if deep else (50.0, 20.0, 22.0)
    k, t = hold_cycles("d", lead_in, down, hold, hold, reps)
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
    times = how_often(reps)
    kind = "deep squats" if deep else "half squats"
    phrases = [f"squats down {times}" if reps > 1 else "squats down and stands back up",
               f"does {NUMBER_WORDS[reps]} {kind}" if reps > 1 else f"does a {kind[:-1]}",
               f"bends {{pos}} knees and squats {times}{adverb(speed)}",
               f"squats{adverb(speed)} with {{pos}} arms held out in front",
               f"lowers into a squat and rises {times}"]
    return Action("squat", pose, phrases, dict(reps=reps, deep=deep, speed=speed))


def sit_down(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    speed = str(rng.choice(["slow", "normal"]))
    descend = (1.8 if speed == "slow" else 1.2) * rng.uniform(0.9, 1.1)
    lead_in, seated = rng.uniform(0.4, 1.0), rng.uniform(1.0, 2.5)
    seated = max(0.5, min(seated, budget.seconds - 0.05 - lead_in - descend - 0.5))
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
    phrases = [f"sits down{adverb(speed)}", "sits down on a chair", "lowers {pos} body into a seated position",
               f"sits down{adverb(speed)} and stays seated", "takes a seat"]
    return Action("sit_down", pose, phrases, dict(speed=speed))


def punch(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    mode = str(rng.choice(["right", "left", "both"]))
    reps = int(rng.integers(1, 7)) if mode != "both" else int(rng.choice([2, 4, 6]))
    tempo = rng.uniform(0.8, 1.3)
    out, back, rest = 0.16 / tempo, 0.22 / tempo, rng.uniform(0.1, 0.4)
    guard_t, lead_in, lead_out = 0.5, rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)
    reps = budget.fit(reps, out + back + rest, lead_in + lead_out + 2 * guard_t, lo=2 if mode == "both" else 1)
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
    times = how_often(reps)
    if mode == "both":
        phrases = ["punches with both fists", f"throws {NUMBER_WORDS[reps]} punches alternating hands",
                   "boxes with both arms", f"punches forward {times} with left and right hands"]
    else:
        phrases = [f"punches with {{pos}} {mode} hand", f"punches forward {times} with the {mode} fist",
                   f"throws {NUMBER_WORDS[reps]} {mode} punches" if reps > 1 else f"throws a {mode} punch",
                   f"jabs {times} with {{pos}} {mode} arm"]
    return Action("punch", pose, phrases, dict(side=mode, reps=reps))


def clap(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    claps = int(rng.integers(3, 11))
    freq = rng.uniform(1.5, 3.0)
    lead_in, lead_out, raise_t = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7), 0.5
    claps = budget.fit(claps, 1.0 / freq, lead_in + lead_out + 2 * raise_t, lo=2)
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
    times = how_often(claps) if claps <= 10 else "many times"
    phrases = [f"claps {{pos}} hands {times}", f"claps {fast or 'in front of {pos} chest'}",
               f"brings {{pos}} hands together and claps {times}", f"claps {NUMBER_WORDS[claps]} times",
               "applauds with both hands"]
    return Action("clap", pose, phrases, dict(claps=claps, freq=round(float(freq), 2)))


def raise_both_arms(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.choice([1, 1, 2, 3]))
    way = str(rng.choice(["forward", "sideways"]))
    high = bool(rng.random() < 0.6)
    up, hold = rng.uniform(0.6, 1.1), rng.uniform(0.3, 1.0)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    reps = budget.fit(reps, 2 * up + hold + 0.2, lead_in + lead_out)
    k, t = hold_cycles("a", lead_in, up, hold, 0.2, reps)
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
    times = how_often(reps)
    where = "above {pos} head" if high else ("in front of {pos} body" if way == "forward" else "out to the sides")
    phrases = [f"raises both arms {where}", f"lifts both arms {way} and lowers them {times}"
               if reps > 1 else f"lifts both arms {way} and lowers them",
               f"raises {{pos}} arms {'up high' if high else 'to shoulder height'} {times}",
               f"puts both hands up {times}" if high else f"holds both arms out {way}"]
    return Action("raise_both_arms", pose, phrases, dict(reps=reps, way=way, high=high))


def stand_idle(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    seconds = rng.uniform(MIN_SECONDS, max(MIN_SECONDS, min(6.0, budget.seconds - 0.05)))
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


def bow(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.choice([1, 1, 2]))
    deep = bool(rng.random() < 0.5)
    depth = rng.uniform(55, 75) if deep else rng.uniform(20, 35)
    down, hold = rng.uniform(0.6, 1.0), rng.uniform(0.3, 1.0)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    reps = budget.fit(reps, 2 * down + hold + 0.3, lead_in + lead_out)
    k, t = hold_cycles("b", lead_in, down, hold, 0.3, reps)
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
    times = how_often(reps)
    adj = "deeply" if deep else "slightly"
    phrases = [f"bows {adj}", f"bows {times}", f"bends forward at the waist and bows {times}",
               f"takes a {'deep' if deep else 'small'} bow" if reps == 1 else f"bows {adj} {times}",
               f"bows {{pos}} head and upper body {times}"]
    return Action("bow", pose, phrases, dict(reps=reps, deep=deep))
