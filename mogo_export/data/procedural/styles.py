"""Locomotion styles: sneaking (a crouched walk), limping, tiptoeing, skipping, marching (forward or in
place), stumbling and hopping on one foot.

Each is a family as action.py describes, `(rng, budget) -> Action`. The walking styles lay a gait cycle of
their own (a `GaitStyle`, gaits.py) along a phase track and add layers on top of it: the sneak's crouch,
the limp's uneven phase and trunk dip, the tiptoe's raised heels, the march's stiff arms, the stumble's
lurch and catch steps. Skipping and hopping have two contacts per cycle on one foot, which the gait
engine cannot say, so they key their legs here. FAMILIES lists this module's families in their fixed
order (families.py appends it to the registry); WORDS holds every caption word they use that the shared
lexicon (captions.py) lacks; LAST_ONLY names the families that do not end standing (none: they all end
on their feet).
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget
from .captions import NUMBER_WORDS, adverb, how_often
from .curves import Keys, cyclic, ease, envelope
from .gaits import GaitStyle, gait
from .pose import OTHER, SIDES, Pose, flat_foot, seconds_to_frames

SNEAK = GaitStyle(  # careful steps: the foot is set down flat, rolls off without a strong push
    stance=0.7,
    hip=[(0.0, 20), (0.15, 14), (0.55, -12), (0.7, -8), (0.82, 14), (0.92, 24)],
    knee=[(0.0, 4), (0.2, 8), (0.5, 4), (0.65, 16), (0.8, 40), (0.9, 18), (0.97, 4)],
    foot=[(0.0, 0), (0.55, 0), (0.68, 18), (0.78, 10), (0.9, 0)],
    arm_swing=0.25, elbow=(0.0, 0.0), lean=0.0, pelvis_yaw=0.1)

TIPTOE = GaitStyle(  # on the balls of the feet (the heel raise is a layer): short, quick, springy steps
    stance=0.64,
    hip=[(0.0, 16), (0.12, 12), (0.64, -12), (0.7, -4), (0.78, 14), (0.88, 21)],
    knee=[(0.0, 8), (0.15, 14), (0.4, 6), (0.58, 18), (0.7, 48), (0.8, 52), (0.9, 22), (0.97, 8)],
    foot=[(0.0, 0), (0.4, 0), (0.6, 8), (0.68, 14), (0.82, 6), (0.92, 0)],
    arm_swing=0.3, elbow=(0.0, 0.0), lean=2.0, pelvis_yaw=0.1)

LIMP = GaitStyle(  # the walk, a little shorter and slower; the limp is a layer
    stance=0.62,
    hip=[(0.0, 20), (0.12, 17), (0.5, -10), (0.62, -5), (0.75, 16), (0.85, 25)],
    knee=[(0.0, 3), (0.13, 14), (0.38, 4), (0.55, 20), (0.65, 48), (0.73, 58), (0.85, 24), (0.93, 2)],
    foot=[(0.0, -12), (0.07, -2), (0.12, 0), (0.45, 0), (0.52, 5), (0.62, 25), (0.7, 20), (0.8, 0), (0.9, -8)],
    arm_swing=0.6, elbow=(16.0, 0.4), lean=4.0, pelvis_yaw=0.12)

MARCH_FORWARD = GaitStyle(  # the knee comes up to a level thigh and the foot is set down under the body
    stance=0.55,
    hip=[(0.0, 14), (0.25, 0), (0.52, -12), (0.62, 10), (0.72, 80), (0.8, 86), (0.89, 42), (0.95, 20)],
    knee=[(0.0, 2), (0.2, 6), (0.5, 4), (0.6, 45), (0.72, 88), (0.8, 90), (0.88, 40), (0.94, 6)],
    foot=[(0.0, 0), (0.45, 0), (0.55, 12), (0.62, 10), (0.8, 0)],
    arm_swing=0.0, elbow=(6.0, 0.0), lean=0.0, pelvis_yaw=0.0)

MARCH_IN_PLACE = GaitStyle(  # stepping on the spot with high knees (gaits.MARCH lifts them to 28 degrees)
    stance=0.5,
    hip=[(0.0, 0), (0.48, 0), (0.6, 40), (0.72, 84), (0.8, 86), (0.9, 30), (0.96, 6)],
    knee=[(0.0, 0), (0.48, 0), (0.6, 45), (0.72, 86), (0.8, 88), (0.9, 56), (0.96, 12)],
    foot=[(0.0, 0), (0.5, 0)],
    arm_swing=0.0, elbow=(6.0, 0.0), lean=0.0, pelvis_yaw=0.0, hip_lifts=True)

STUMBLE = GaitStyle(  # the walk, with the lurch and the catch steps layered on by `stumble`
    stance=0.62,
    hip=[(0.0, 21), (0.12, 18), (0.5, -11), (0.62, -5), (0.75, 17), (0.85, 27)],
    knee=[(0.0, 3), (0.13, 15), (0.38, 4), (0.55, 20), (0.65, 50), (0.73, 62), (0.85, 25), (0.93, 2)],
    foot=[(0.0, -12), (0.07, -2), (0.12, 0), (0.45, 0), (0.52, 5), (0.62, 30), (0.7, 25), (0.8, 0),
          (0.9, -8)],
    arm_swing=0.9, elbow=(14.0, 0.5), lean=3.0, pelvis_yaw=0.15)


def _squeeze(budget: TimeBudget, core: float, *leads: float) -> list[float]:
    """The lead-in / lead-out times `leads`, shortened (to no less than half) so that they and `core`
    seconds of the action itself fit a short budget."""
    k = float(np.clip((budget.seconds - 0.05 - core) / sum(leads), 0.5, 1.0))
    return [k * x for x in leads]


def _walk_timeline(budget: TimeBudget, steps: int, cadence: float, lead_in: float, lead_out: float,
                   min_steps: int = 2) -> tuple[int, Pose, float, float]:
    """Fit `steps` steps at `cadence` between a lead-in and lead-out: (steps, pose, first step, last step)."""
    steps = budget.fit(steps, 1.0 / cadence, lead_in + lead_out, lo=min_steps)
    pose = Pose(seconds_to_frames(lead_in + steps / cadence + lead_out))
    start = lead_in
    stop = min(start + steps / cadence, pose.t[-1] - 0.1)
    return steps, pose, start, stop


def _walk(pose: Pose, style: GaitStyle, phase: np.ndarray, start: float, stop: float, cadence: float,
          stride: float, swing_scale=1.0) -> tuple[dict, np.ndarray, np.ndarray]:
    """Lay `style` on `pose` as locomotion._take_steps does (stride ramps in and out, knees and feet settle
    before the first and after the last step): -> (stance masks, stride amplitude, lift)."""
    t = pose.t
    amp = stride * envelope(t, start, stop, 0.7 / cadence)
    lift = envelope(t, start - 0.3, stop + 0.3, 0.3)
    pose.spine(bend=2.0)
    stance = gait(pose, phase, amp, style, np.zeros(pose.T), lift, swing_scale)
    pose.support = np.stack([stance["left"], stance["right"]], axis=1)
    return stance, amp, lift


def _linear_phase(t: np.ndarray, start: float, stop: float, steps: int) -> np.ndarray:
    """Left-leg phase from just past a left heel strike to the heel strike ending `steps` steps (as _take_steps)."""
    return 0.12 + (0.5 * steps - 0.12) * np.clip((t - start) / (stop - start), 0.0, 1.0)


def _crouch_layer(pose: Pose, c: np.ndarray, thigh: float, shank: float, pitch: float) -> None:
    """Bend both legs by c (0..1) of a crouch (thigh and shank degrees from vertical, trunk pitch), feet flat."""
    p = c * pitch
    flex, knee = c * thigh + p, c * (thigh + shank)
    pose.root(pitch=p)
    for side in SIDES:
        pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(p, flex, knee))


# --- sneak ---------------------------------------------------------------------------------------------------

def sneak(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """A crouched, slow walk: knees bent, pelvis 15-25 cm low, trunk forward, hands held up in front."""
    speed = str(rng.choice(["slow", "normal"]))
    cadence = {"slow": 0.95, "normal": 1.25}[speed] * rng.uniform(0.92, 1.08)
    stride = rng.uniform(1.0, 1.2)
    depth = rng.uniform(30.0, 37.0)     # thigh and shank degrees from vertical: with the gait, 15-23 cm lower
    down, up = _squeeze(budget, 1.0 / cadence + 0.5, rng.uniform(0.6, 0.9), rng.uniform(0.6, 0.9))
    steps, pose, start, stop = _walk_timeline(budget, int(rng.integers(3, 11)), cadence, down + 0.2,
                                              up + 0.3, 1)
    t = pose.t
    c = ease((t - 0.1) / down) * ease((t[-1] - 0.1 - t) / up)   # crouch before the first step, rise after the last
    _walk(pose, SNEAK, _linear_phase(t, start, stop, steps), start, stop, cadence, stride)
    pitch = rng.uniform(18.0, 26.0)
    _crouch_layer(pose, c, depth, depth, pitch)
    pose.spine(bend=c * 6.0)
    pose.head(nod=-c * (pitch + 4.0), turn=c * rng.uniform(-1, 1) * 12.0 * np.sin(2 * np.pi * t / 3.0))
    for side in SIDES:  # hands drawn up in front of the chest, elbows in, close to the body
        pose.arm(side, flex=c * 30.0, abd=8.0, elbow=14.0 + c * 76.0, across=c * 10.0)
    n = NUMBER_WORDS[steps]
    phrases = [f"sneaks forward{adverb(speed)}", f"sneaks forward {n} steps in a crouch",
               "walks crouched like a sneaking thief", f"creeps forward{adverb(speed) or ' carefully'} with bent knees",
               f"sneaks ahead {n} steps with {{pos}} knees bent", "walks crouched down low"]
    return Action("sneak", pose, phrases, dict(speed=speed, steps=steps, depth=round(float(depth), 1)))


# --- limp ----------------------------------------------------------------------------------------------------

def _warped_phase(t: np.ndarray, start: float, stop: float, steps: int, fast: float, a: np.ndarray) -> np.ndarray:
    """_linear_phase, advancing (1 + a) times its mean rate around phase `fast` (mod 1) and (1 - a) times it
    half a cycle away. `a` (per frame, < 1) is 0 at the first and last step, so the phase still runs from
    just past a heel strike to a heel strike."""
    u = _linear_phase(t, start, stop, steps)
    return u + a / (2 * np.pi) * np.sin(2 * np.pi * (u - fast))


def limp(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """An uneven walk favouring the `side` leg: a short, stiff-kneed stance on it, the trunk dipping toward it."""
    side = str(rng.choice(["left", "right"]))
    sign = SIDES[side]["sign"]
    cadence = rng.uniform(1.15, 1.5)
    stride = rng.uniform(0.75, 0.95)
    lead_in, lead_out = _squeeze(budget, 2.0 / cadence, rng.uniform(0.4, 0.8), rng.uniform(0.4, 0.8))
    steps, pose, start, stop = _walk_timeline(budget, int(rng.integers(4, 11)), cadence, lead_in, lead_out, 2)
    t = pose.t
    # the bad leg's single support (left phase 0.12-0.5 for the left leg) is hurried through
    off = 0.0 if side == "left" else 0.5
    uneven = rng.uniform(0.5, 0.6) * envelope(t, start, stop, 1.2 / cadence)  # not on the first and last steps
    phase = _warped_phase(t, start, stop, steps, 0.31 + off, uneven)
    stance, amp, lift = _walk(pose, LIMP, phase, start, stop, cadence, stride)
    on = amp / stride
    ph = phase + off                                # the bad leg's own phase
    load = on * cyclic(ph, [(0.0, 0.0), (0.12, 0.0), (0.31, 1.0), (0.5, 0.0), (0.75, 0.0)])  # its single support
    swing = on * cyclic(ph, [(0.0, 0.0), (0.62, 0.0), (0.7, 0.6), (0.77, 1.0), (0.88, 0.5), (0.97, 0.0)])
    dip = rng.uniform(13.0, 18.0)
    # the trunk (and head) lean over the bad leg while it carries the body; its knee gives a little
    pose.spine(lean=sign * dip * load, bend=4.0 * on)
    pose.head(tilt=-0.4 * sign * dip * load, nod=3.0 * load)
    # (only while the other foot is high in its swing: lower, it would scuff the floor)
    knee_give = 7.0 * on * cyclic(ph, [(0.0, 0.0), (0.18, 0.0), (0.3, 1.0), (0.42, 0.0), (0.75, 0.0)])
    # in the swing the bad leg stays stiff and circles out (its knee bends half as much)
    knee_cut = -0.45 * lift * cyclic(ph, LIMP.knee) * np.clip(swing / 0.6, 0, 1)
    flex = 0.4 * knee_give
    pose.leg(side, flex=flex, knee=knee_give + knee_cut, abd=7.0 * swing,
             dorsi=flat_foot(0.0, flex, knee_give + knee_cut))
    pose.arm(side, abd=on * 10.0)               # the bad side's arm out a little, for balance
    n = NUMBER_WORDS[steps]
    phrases = [f"limps forward on {{pos}} {side} leg", f"walks with a limp on the {side} leg",
               f"limps forward favouring {{pos}} {side} leg", f"limps {n} steps forward, {{pos}} {side} leg hurt",
               f"walks forward with a limp, {{pos}} {side} leg injured"]
    return Action("limp", pose, phrases, dict(side=side, steps=steps))


# --- tiptoe --------------------------------------------------------------------------------------------------

def tiptoe(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Walking on the toes: heels up through every stance, short quick steps, arms held a little out."""
    speed = str(rng.choice(["slow", "normal"]))
    cadence = {"slow": 1.9, "normal": 2.4}[speed] * rng.uniform(0.93, 1.07)
    stride = rng.uniform(0.55, 0.75)
    rise, lower = _squeeze(budget, 2.0 / cadence + 0.55, rng.uniform(0.4, 0.6), rng.uniform(0.4, 0.6))
    steps, pose, start, stop = _walk_timeline(budget, int(rng.integers(4, 15)), cadence, rise + 0.25, lower + 0.3, 2)
    t = pose.t
    _walk(pose, TIPTOE, _linear_phase(t, start, stop, steps), start, stop, cadence, stride, swing_scale=0.5)
    # up onto the balls of both feet before the first step, down after the last
    toes = ease((t - 0.15) / rise) * ease((t[-1] - 0.15 - t) / lower)
    heel = rng.uniform(28.0, 36.0)
    for side in SIDES:
        pose.leg(side, dorsi=-heel * toes)
        pose.arm(side, abd=toes * rng.uniform(18.0, 26.0), elbow=toes * 40.0, flex=toes * 12.0, twist=toes * 20.0)
    pose.head(nod=toes * 8.0)                      # watching where the feet go
    n = NUMBER_WORDS[steps]
    phrases = [f"tiptoes forward{adverb(speed)}", f"tiptoes {n} steps forward",
               f"walks forward on tiptoe{adverb(speed)}",
               f"walks on {{pos}} toes{adverb(speed) or ' quietly'}", f"takes {n} small steps forward on {{pos}} toes"]
    return Action("tiptoe", pose, phrases, dict(speed=speed, steps=steps))


# --- march ---------------------------------------------------------------------------------------------------

def march(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Marching, forward or on the spot: knees up to a level thigh, straight arms swung to shoulder height."""
    in_place = bool(rng.random() < 0.4)
    cadence = rng.uniform(1.5, 1.9)
    lead_in, lead_out = _squeeze(budget, 2.0 / cadence, rng.uniform(0.4, 0.8), rng.uniform(0.4, 0.8))
    count = int(rng.integers(2, 7)) * 2                # an even count: the feet end side by side
    steps, pose, start, stop = _walk_timeline(budget, count, cadence, lead_in, lead_out, 2)
    steps -= steps % 2
    stop = min(start + steps / cadence, pose.t[-1] - 0.1)
    t = pose.t
    phase = _linear_phase(t, start, stop, steps)
    style = MARCH_IN_PLACE if in_place else MARCH_FORWARD
    stance, amp, lift = _walk(pose, style, phase, start, stop, cadence, 1.0 if in_place else rng.uniform(0.85, 1.0))
    on = envelope(t, start - 0.2, stop + 0.2, 0.4)
    swing = rng.uniform(70.0, 85.0)                # the forward arm reaches about shoulder height
    for side, off in (("left", 0.5), ("right", 0.0)):  # each arm swings with the other leg's knee
        arm = on * cyclic(phase + off, [(0.0, -0.1), (0.25, -0.35), (0.5, -0.1), (0.62, 0.3), (0.77, 1.0),
                                        (0.9, 0.6)])
        pose.arm(side, flex=swing * arm, abd=4.0, elbow=-4.0 * on)
    pose.spine(bend=-3.0 * on)                     # chest up
    pose.head(nod=-3.0 * on)
    n = NUMBER_WORDS[steps]
    if in_place:
        phrases = ["marches in place", f"marches in place for {n} steps",
                   "marches on the spot lifting {pos} knees high",
                   f"stands and marches in place, swinging {{pos}} arms", f"marches {n} steps in place"]
    else:
        phrases = ["marches forward", f"marches forward {n} steps", "marches ahead lifting {pos} knees high",
                   "marches forward swinging {pos} arms high", f"marches {n} steps forward like a soldier"]
    return Action("march", pose, phrases, dict(in_place=in_place, steps=steps))


# --- skip ----------------------------------------------------------------------------------------------------

# One leg over a cycle of two skips, phase 0 = this foot lands its step: it carries the body and pushes off
# into a small hop (0.2), lands it (0.3), carries the body while the other foot steps (0.5), leaves the
# floor (0.53), and drives its knee up while the other foot hops (0.74). The foot's fore-aft place under
# the hip (m) is keyed, stance at a constant speed back, the swing smooth; the hip angle that puts it there
# follows from the knee (`_thigh_for`).
SKIP_CONTACTS = ((0.0, 0.2), (0.3, 0.53))
SKIP_BACK = 1.5                          # m the planted foot moves back under the hip per cycle
SKIP_LANDS = {0.0: 0.15, 0.3: 0.0}       # where the foot lands, m ahead of the hip
SKIP_KNEE = [(0.0, 10), (0.08, 26), (0.2, 8), (0.25, 24), (0.3, 14), (0.38, 28), (0.53, 12), (0.58, 45),
             (0.64, 75), (0.74, 95), (0.88, 45), (0.96, 12)]
SKIP_HEEL = [(0.0, 4), (0.06, 0), (0.14, 6), (0.2, 30), (0.25, 15), (0.3, 10), (0.36, 0), (0.44, 0), (0.53, 30),
             (0.58, 10), (0.66, 0), (0.8, 0), (0.95, 2)]
# the arm swings up with the other leg's knee (keys over the other leg's phase)
SKIP_ARM = [(0.0, 0), (0.22, -30), (0.5, -10), (0.62, 50), (0.74, 115), (0.86, 70)]
THIGH, SHIN = 0.39, 0.43


def _skip_reach(ph: np.ndarray) -> np.ndarray:
    """The foot's place ahead of the hip (m) at phase ph: linear (a constant speed back) on the floor, a cubic
    in the air that leaves and lands at that speed."""
    ph = np.mod(ph, 1.0)
    out = np.zeros_like(ph)
    segs = [(a, b, SKIP_LANDS[a], SKIP_LANDS[a] - SKIP_BACK * (b - a)) for a, b in SKIP_CONTACTS]
    for i, (a, b, z0, z1) in enumerate(segs):
        on = (ph >= a) & (ph < b)
        out[on] = z0 + (z1 - z0) * (ph[on] - a) / (b - a)
        na, _, nz, _ = segs[(i + 1) % len(segs)]
        span = (na - b) % 1.0
        air = np.mod(ph - b, 1.0) < span
        air &= ~on
        s = np.mod(ph[air] - b, 1.0) / span
        m = -SKIP_BACK * span
        out[air] = ((2 * s**3 - 3 * s**2 + 1) * z1 + (s**3 - 2 * s**2 + s) * m + (-2 * s**3 + 3 * s**2) * nz
                    + (s**3 - s**2) * m)
    return out


def _thigh_for(reach: np.ndarray, knee: np.ndarray) -> np.ndarray:
    """Thigh angle from vertical (degrees, > 0 forward) that puts the ankle `reach` m ahead of the hip with
    the knee bent `knee` degrees: THIGH sin(h) + SHIN sin(h - knee) = reach."""
    c = THIGH + SHIN * np.exp(-1j * np.radians(knee))
    amp, phi = np.abs(c), np.angle(c)
    return np.degrees(np.arcsin(np.clip(reach / amp, -0.99, 0.99)) - phi)


def skip(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Skipping: step-hop on alternate feet, a small flight in each hop, the free knee and the other arm high."""
    speed = str(rng.choice(["slow", "normal", "fast"], p=[0.3, 0.4, 0.3]))
    per = {"slow": 0.72, "normal": 0.64, "fast": 0.56}[speed] * rng.uniform(0.95, 1.05)   # seconds a skip
    stride = rng.uniform(0.85, 1.0)
    lead_in, lead_out = _squeeze(budget, 2 * per, rng.uniform(0.4, 0.8), rng.uniform(0.4, 0.8))
    skips = budget.fit(int(rng.integers(3, 11)), per, lead_in + lead_out, lo=2)
    pose = Pose(seconds_to_frames(lead_in + skips * per + lead_out))
    t = pose.t
    start, stop = lead_in, min(lead_in + skips * per, t[-1] - 0.1)
    amp = stride * envelope(t, start, stop, 0.5 * per)
    lift = envelope(t, start - 0.2, stop + 0.2, 0.3)
    phase = 0.5 * skips * np.clip((t - start) / (stop - start), 0.0, 1.0)   # left-leg phase, 1 per two skips
    lean = 8.0 * amp
    pose.root(pitch=lean)
    pose.spine(bend=2.0)
    stance = {}
    for side, off in (("left", 0.0), ("right", 0.5)):
        ph = np.mod(phase + off, 1.0)
        knee = lift * cyclic(ph, SKIP_KNEE)
        flex = _thigh_for(amp * _skip_reach(ph), knee) + lean
        pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(lean, flex, knee, lift=lift * cyclic(ph, SKIP_HEEL)))
        stance[side] = np.any([(ph >= a) & (ph < b) for a, b in SKIP_CONTACTS], axis=0) | (amp < 0.05)
        other = np.mod(ph + 0.5, 1.0)
        arm = amp * cyclic(other, SKIP_ARM)
        pose.arm(side, flex=arm, abd=10.0, elbow=25.0 + 0.35 * np.maximum(arm, 0))
    pose.support = np.stack([stance["left"], stance["right"]], axis=1)
    pose.flight = ~(stance["left"] | stance["right"]) & (amp > 0.7 * stride)
    pose.head(nod=-0.5 * lean)
    times = how_often(skips) if skips <= 10 else f"{NUMBER_WORDS[skips]} times"
    phrases = [f"skips forward{adverb(speed)}", f"skips forward {times}",
               f"skips along{adverb(speed)}, swinging {{pos}} arms", f"skips ahead {times} on alternating feet",
               "happily skips forward" if speed != "slow" else "skips forward slowly and happily"]
    return Action("skip", pose, phrases, dict(speed=speed, steps=skips))


# --- hop on one foot -----------------------------------------------------------------------------------------

def hop_on_one_foot(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Hopping on the `side` foot, the other foot held up behind (knee bent), arms a little out for balance."""
    side = str(rng.choice(["left", "right"]))
    sign = SIDES[side]["sign"]
    reps = int(rng.integers(2, 7))
    height = rng.uniform(0.06, 0.12)
    flight = np.sqrt(8.0 * height / 9.81)
    crouch, push, land = 0.2 * rng.uniform(0.9, 1.15), 0.12, 0.16
    per = crouch + push + flight + land
    raise_t, lower_t, lead_in, lead_out = _squeeze(budget, per + 0.2, rng.uniform(0.45, 0.65), rng.uniform(0.45, 0.65),
                                                   rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6))
    reps = budget.fit(reps, per, lead_in + lead_out + raise_t + lower_t + 0.2)
    k = Keys(thigh=0, knee=0, heel=0, arm=0)
    t = lead_in + raise_t
    offs = []
    for _ in range(reps):
        k.add(t, thigh=8, knee=16, heel=0, arm=0)
        t += crouch
        k.add(t, thigh=16, knee=34, heel=0, arm=-12)
        t += push
        k.add(t, "stop", thigh=0, knee=4, heel=30)           # take-off from the ball of the foot
        k.add(t, arm=25)
        offs.append((t, t + flight))
        k.add(t + 0.5 * flight, thigh=2, knee=6, heel=22, arm=28)
        t += flight
        k.add(t, "start", thigh=4, knee=8, heel=12)           # touch-down on the ball of the foot, giving way
        k.add(t, arm=15)
        t += land
    k.add(t + 0.2, thigh=8, knee=16, heel=0, arm=0)
    end = t + 0.2
    T = seconds_to_frames(end + lower_t + lead_out)
    pose = Pose(T)
    tt = pose.t
    up = ease((tt - lead_in) / raise_t) * ease((end + lower_t - tt) / lower_t)   # the other foot held up
    thigh, knee = k("thigh", tt), k("knee", tt)
    pitch = 0.4 * thigh + 4.0 * up
    pose.root(pitch=pitch)
    flex = thigh + pitch
    # the pelvis shifts over the hopping foot (its leg adducts) before the other foot leaves the floor
    pose.leg(side, flex=flex, knee=knee, abd=-6.0 * up, dorsi=flat_foot(pitch, flex, knee, lift=k("heel", tt)))
    other = OTHER[side]
    oflex, oknee = pitch - 12.0 * up, 85.0 * up         # thigh a little behind the body, shin up behind
    pose.leg(other, flex=oflex, knee=oknee, abd=-6.0 * up, dorsi=flat_foot(pitch, oflex, oknee) - 20.0 * up)
    pose.support[:, 0 if other == "left" else 1] = up < 0.02
    pose.spine(bend=2.0, lean=-sign * 3.0 * up)
    for s in SIDES:
        pose.arm(s, abd=4.0 + up * 22.0, elbow=12.0 + up * 30.0, flex=k("arm", tt) + 10.0 * up)
    for a, b in offs:
        air = (tt > a) & (tt < b)
        pose.flight |= air
        pose.leap |= air
    times = how_often(reps)
    n = NUMBER_WORDS[reps]
    phrases = [f"hops on {{pos}} {side} foot {times}", f"hops on the {side} foot {times}",
               f"stands on {{pos}} {side} leg and hops {times}", f"hops {n} times on one foot, the {side} one"
               if reps > 1 else f"hops once on one foot, the {side} one",
               f"lifts one foot and hops on {{pos}} {side} foot {times}"]
    return Action("hop_on_one_foot", pose, phrases, dict(side=side, reps=reps))


# --- stumble -------------------------------------------------------------------------------------------------

def stumble(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Walking, then a trip: the trunk lurches forward, arms thrown out, two or three fast, long catch steps,
    then upright again, walking on or standing."""
    cadence = rng.uniform(1.7, 2.0)
    stride = rng.uniform(0.95, 1.1)
    before, catch = int(rng.integers(2, 5)), int(rng.integers(2, 4))
    walks_on = bool(rng.random() < 0.5)
    after = int(rng.integers(2, 4)) if walks_on else 0
    fast = rng.uniform(1.5, 1.75)                # the catch steps' cadence, times the walk's
    lead_in, lead_out = _squeeze(budget, (1 + catch / fast) / cadence, rng.uniform(0.4, 0.8), rng.uniform(0.5, 0.9))
    fixed = lead_in + lead_out + catch / (fast * cadence)
    if after:  # a short budget drops the steps after the trip first, then those before it
        after = budget.fit(after, 1.0 / cadence, fixed + before / cadence, lo=0)
        walks_on = after > 0
    before = budget.fit(before, 1.0 / cadence, fixed + after / cadence, lo=1)
    steps = before + catch + after
    t1 = lead_in + before / cadence
    t2 = t1 + catch / (fast * cadence)
    stop = t2 + after / cadence
    pose = Pose(seconds_to_frames(stop + lead_out))
    t = pose.t
    k = Keys()
    for time, value in ((lead_in, 0.12), (t1, 0.5 * before), (t2, 0.5 * (before + catch)), (stop, 0.5 * steps)):
        k.add(time, phase=value)
    phase = k("phase", t)
    lurch = ease((t - t1 + 0.12) / 0.3) * ease((t2 + 0.35 - t) / (t2 + 0.35 - t1 - 0.15))  # sudden, then eased off
    amp = stride * envelope(t, lead_in, stop, 0.7 / cadence) * (1.0 + 0.3 * lurch)
    if not walks_on:  # the catch steps end the walk: the stride still runs out over the last one
        amp = stride * envelope(t, lead_in, stop, 0.5 / (fast * cadence)) * (1.0 + 0.3 * lurch)
    lift = envelope(t, lead_in - 0.3, stop + 0.3, 0.3)
    pose.spine(bend=2.0)
    stance = gait(pose, phase, amp, STUMBLE, np.zeros(pose.T), lift, swing_scale=1.0 - 0.85 * lurch)
    pose.support = np.stack([stance["left"], stance["right"]], axis=1)
    pitch = rng.uniform(22.0, 32.0) * lurch
    pose.root(pitch=pitch)
    for side in SIDES:  # the legs keep their swing relative to the floor; both knees give a little
        flex, knee = pitch + 10.0 * lurch, 20.0 * lurch
        pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(pitch, flex, knee))
        pose.arm(side, flex=lurch * rng.uniform(50.0, 75.0) - 0.5 * pitch, abd=lurch * rng.uniform(35.0, 55.0),
                 elbow=lurch * 10.0)
    pose.spine(bend=-0.2 * pitch)
    pose.head(nod=-0.6 * pitch)
    n = NUMBER_WORDS[catch]
    then = "walks on" if walks_on else "stops"
    phrases = [f"stumbles forward and catches {{pos}} balance", f"trips and catches {{pos}} balance, then {then}",
               f"walks, trips and stumbles forward {n} quick steps", f"walks, trips and throws {{pos}} arms out",
               f"walks and stumbles, then {'keeps walking' if walks_on else 'stands still'}"]
    return Action("stumble", pose, phrases,
                  dict(steps=steps, catch_steps=catch, walks_on=walks_on, trip_at=round(t1, 2)))


FAMILIES: tuple = (sneak, limp, tiptoe, skip, march, stumble, hop_on_one_foot)
WORDS: dict = {
    "ADJ": "crouched sneaking",
    "ADP": "like for",
    "ADV": "quietly along happily",
    "NOUN": {"thief": "thief", "crouch": "crouch", "limp": "limp", "tiptoe": "tiptoe", "toes": "toe",
             "spot": "spot", "soldier": "soldier", "feet": "foot", "balance": "balance"},
    "VERB": {"sneaks": "sneak", "creeps": "creep", "bent": "bend", "limps": "limp", "favouring": "favour",
             "hurt": "hurt", "injured": "injure", "tiptoes": "tiptoe", "marches": "march",
             "lifting": "lift", "swinging": "swing", "skips": "skip", "stumbles": "stumble", "trips": "trip",
             "catches": "catch", "keeps": "keep", "walking": "walk", "stops": "stop"},
}
LAST_ONLY: tuple[str, ...] = ()
