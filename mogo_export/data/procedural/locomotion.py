"""The action families that move the body over the floor: walking (forward, backward, in a circle), running,
jumping (in place, forward), turning on the spot and sidestepping.

Each is a family as action.py describes, `(rng, budget) -> Action`. They share `_take_steps` (stand,
step with a gait from gaits.py, stand) and `_jumps` (crouch, ballistic flight, landing), which is why
they live together; the families that stay on the spot are in in_place.py.
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget, sample_speed
from .captions import NUMBER_WORDS, SPEED_WORDS, adverb, how_often
from .curves import Keys, ease, envelope
from .gaits import MARCH, RUN, WALK, GaitStyle, gait
from .pose import FPS, GRAVITY, OTHER, SIDES, Pose, flat_foot, seconds_to_frames


def _take_steps(rng, budget: TimeBudget, style: GaitStyle, steps: int, cadence: float, stride: float, *,
                direction: float = 1.0, turn_deg: float = 0.0, swing_scale: float = 1.0, min_steps: int = 2):
    """Stand, take `steps` steps at `cadence` steps/s, stand. direction -1 plays the cycle backwards.

    Returns (pose, steps actually taken, stance masks per side, stride envelope).
    """
    lead_in, lead_out = rng.uniform(0.4, 0.9), rng.uniform(0.4, 0.9)
    steps = budget.fit(steps, 1.0 / cadence, lead_in + lead_out, lo=min_steps)
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


def walk_forward(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    speed = sample_speed(rng)
    cadence = {"slow": 1.35, "normal": 1.85, "fast": 2.2}[speed] * rng.uniform(0.92, 1.08)
    stride = {"slow": 0.8, "normal": 1.1, "fast": 1.25}[speed] * rng.uniform(0.9, 1.1)
    pose, steps, _, _ = _take_steps(rng, budget, WALK, int(rng.integers(3, 13)), cadence, stride)
    n = NUMBER_WORDS[steps]
    adj = {"slow": "slow ", "normal": "", "fast": "quick "}[speed]
    phrases = [f"walks forward{adverb(speed)}", f"takes {n} {adj}steps forward",
               f"walks straight ahead{adverb(speed) or ' at a normal pace'}",
               f"{SPEED_WORDS[speed] or 'calmly'} walks forward {n} steps"]
    return Action("walk_forward", pose, phrases, dict(speed=speed, steps=steps))


def walk_backward(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    speed = str(rng.choice(["slow", "normal"]))
    cadence = {"slow": 1.2, "normal": 1.6}[speed] * rng.uniform(0.92, 1.08)
    stride = {"slow": 0.6, "normal": 0.8}[speed] * rng.uniform(0.9, 1.1)
    pose, steps, _, _ = _take_steps(rng, budget, WALK, int(rng.integers(2, 9)), cadence, stride, direction=-1.0,
                                    swing_scale=0.6)
    n = NUMBER_WORDS[steps]
    adv = adverb(speed) or " carefully"
    phrases = [f"walks backward{adverb(speed)}", f"takes {n} steps backward", f"steps back {n} times"
               if steps <= 10 else f"steps back {n} steps", f"walks backwards{adv}", f"moves backward {n} steps"]
    return Action("walk_backward", pose, phrases, dict(speed=speed, steps=steps))


def walk_circle(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    speed = str(rng.choice(["slow", "normal"]))
    side = str(rng.choice(["left", "right"]))
    cadence = {"slow": 1.5, "normal": 1.85}[speed] * rng.uniform(0.92, 1.08)
    stride = {"slow": 0.8, "normal": 1.0}[speed] * rng.uniform(0.9, 1.1)
    turn = 360.0 if side == "left" else -360.0
    pose, steps, _, _ = _take_steps(rng, budget, WALK, int(rng.integers(10, 17)), cadence, stride, turn_deg=turn,
                                    min_steps=10)
    clock = "counterclockwise" if side == "left" else "clockwise"
    phrases = [f"walks in a circle{adverb(speed)}", f"walks in a full circle to the {side}",
               f"walks around in a {clock} circle", f"walks in a circle turning {side}{adverb(speed)}",
               f"walks {clock} in a circle"]
    return Action("walk_circle", pose, phrases, dict(speed=speed, side=side, steps=steps))


def run(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    speed = sample_speed(rng)
    cadence = {"slow": 2.5, "normal": 2.8, "fast": 3.1}[speed] * rng.uniform(0.95, 1.05)
    stride = {"slow": 0.8, "normal": 1.0, "fast": 1.15}[speed] * rng.uniform(0.92, 1.08)
    pose, steps, stance, amp = _take_steps(rng, budget, RUN, int(rng.integers(4, 17)), cadence, stride, min_steps=4)
    pose.flight = ~(stance["left"] | stance["right"]) & (amp > 0.6 * stride)
    verb = {"slow": "jogs", "normal": "runs", "fast": "runs"}[speed]
    adv = {"slow": " slowly", "normal": "", "fast": " quickly"}[speed]
    phrases = [f"{verb} forward{adv}", f"{verb} straight ahead", f"{verb} forward {NUMBER_WORDS[steps]} steps",
               {"slow": "jogs in a straight line", "normal": "runs in a straight line",
                "fast": "sprints forward"}[speed],
               {"slow": "is jogging forward", "normal": "is running forward", "fast": "runs forward fast"}[speed]]
    return Action("run", pose, phrases, dict(speed=speed, steps=steps))


def _jumps(rng, budget: TimeBudget, reps: int, height: float, distance: float, tempo: float) -> tuple[Pose, int]:
    """Crouch, push off with an arm swing, fly a ballistic arc of `height` m, land and absorb; repeat."""
    flight_time = np.sqrt(8.0 * height / GRAVITY)
    crouch, push, land, recover = 0.38 / tempo, 0.22, 0.2, 0.35 / tempo
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    per = crouch + push + flight_time + land + recover
    reps = budget.fit(reps, per, lead_in + lead_out)
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
        pose.leap |= air
        pose.air_speed[air] = distance * FPS / max(air.sum(), 1)  # `distance` over the airborne frames
    return pose, reps


def jump_in_place(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.choice([1, 1, 2, 2, 3, 4]))
    high = bool(rng.random() < 0.5)
    height = rng.uniform(0.3, 0.45) if high else rng.uniform(0.12, 0.25)
    pose, reps = _jumps(rng, budget, reps, height, 0.0, rng.uniform(0.85, 1.2))
    adj = "high" if high else "a little"
    times = how_often(reps)
    phrases = [f"jumps in place {times}", f"jumps up and down {times}" if reps > 1 else "jumps up once",
               f"jumps {adj} {times}", f"hops {adj} in place" + (f" {times}" if reps > 1 else ""),
               f"bends {{pos}} knees and jumps straight up {times}"]
    return Action("jump_in_place", pose, phrases, dict(reps=reps, high=high))


def jump_forward(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.choice([1, 1, 2, 3]))
    far = bool(rng.random() < 0.5)
    distance = rng.uniform(0.8, 1.2) if far else rng.uniform(0.35, 0.6)
    pose, reps = _jumps(rng, budget, reps, rng.uniform(0.2, 0.35), distance, rng.uniform(0.85, 1.15))
    times = how_often(reps)
    adj = "far" if far else "a short distance"
    phrases = [f"jumps forward {times}", f"jumps {adj} forward" + (f" {times}" if reps > 1 else ""),
               f"leaps forward {times}", f"swings {{pos}} arms and jumps forward {times}",
               f"does {NUMBER_WORDS[reps]} {'long' if far else 'short'} jumps forward" if reps > 1
               else f"does a {'long' if far else 'short'} jump forward"]
    return Action("jump_forward", pose, phrases, dict(reps=reps, far=far))

def _turn(rng, side: str, budget: TimeBudget) -> Action:
    angle = float(rng.choice([90.0, 180.0, 360.0], p=[0.4, 0.4, 0.2]))
    cadence = rng.uniform(1.6, 2.2)
    # about 30 degrees a step: a planted foot then twists at most ~35 degrees against the pelvis
    steps = int(np.ceil(angle / 30.0)) + int(rng.integers(0, 2))
    steps += steps % 2  # an even number, so the feet end side by side
    pose, steps, _, _ = _take_steps(rng, budget, MARCH, steps, cadence, 1.0,
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


def turn_left(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _turn(rng, "left", budget)


def turn_right(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _turn(rng, "right", budget)


def _sidestep(rng, side: str, budget: TimeBudget) -> Action:
    pairs = int(rng.integers(2, 6))
    period = rng.uniform(0.7, 1.1)
    width = rng.uniform(0.25, 0.45)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    pairs = budget.fit(pairs, period, lead_in + lead_out, lo=1)
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
               f"shuffles {n} steps to the {side}", f"moves sideways to the {side} {how_often(pairs)}",
               f"takes {n} side steps to the {side}"]
    return Action(f"sidestep_{side}", pose, phrases, dict(side=side, steps=pairs))


def sidestep_left(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _sidestep(rng, "left", budget)


def sidestep_right(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _sidestep(rng, "right", budget)
