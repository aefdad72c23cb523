"""Combat: blocking, dodging, hit reactions, roundhouse kicks, uppercuts.

  block               both forearms snap up before the face (high) or across the stomach (low) and the body
                      flinches back, `reps` times (params reps, height)
  dodge_left/_right   one explosive lean and step: the lead foot lands 0.3-0.55 m out, the pelvis follows it
                      over a bent knee while the trunk ducks and leans; then back, or it stays (side, back, width)
  hit_reaction_front  the head and chest snap back, arms flung up, 1-3 stagger steps back (steps, first)
  hit_reaction_back   the body lurches forward, arms thrown back, 1-3 steps forward, then a look back over a
                      shoulder (steps, first, look)
  roundhouse_kick     the kicking leg swings up and around, the hips turning 60-80 degrees over the standing
                      foot, which pivots on its ball; waist or head height (side, reps, height)
  uppercut            from the guard the fist drops by the hip with the knees, then drives up to in front of
                      the chin, close to the body (side, reps)

Each is a family as action.py describes, `(rng, budget) -> Action`. FAMILIES lists this module's families in
their fixed order (families.py appends it to the registry); WORDS holds every caption word they use that the
shared lexicon (captions.py) lacks; LAST_ONLY names the families that do not end standing.
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget
from .captions import NUMBER_WORDS, how_often
from .curves import Keys, ease
from .pose import OTHER, SIDES, Pose, flat_foot, seconds_to_frames


def _knees(pose: Pose, pitch, dip) -> None:
    """Both legs bent by `dip` (0..1 of a 30 degree knee bend) under a trunk pitched `pitch`, feet flat."""
    thigh = 18.0 * np.asarray(dip)
    flex, knee = thigh + pitch, 2.0 * thigh
    for side in SIDES:
        pose.leg(side, flex=flex, abd=3.0 * np.asarray(dip), knee=knee, dorsi=flat_foot(pitch, flex, knee))


# --- block -------------------------------------------------------------------------------------------------

# (flex, abd, twist, elbow, across) of each arm: forearms upright in front of the face (high), or stacked
# across the chest and stomach (low); the ready guard the arms drop to between blocks
_BLOCK_ARMS = {"high": {"left": (85, 0, 0, 100, 25), "right": (85, 0, 0, 100, 25)},
               "low": {"left": (35, 15, -55, 100, 25), "right": (25, 15, -65, 95, 15)}}
_READY = (40, 8, 0, 105, 15)
_REST = (3, 4, 0, 12, 0)


def block(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.choice([1, 2, 2, 3, 4]))
    height = str(rng.choice(["high", "low"]))
    tempo = rng.uniform(0.85, 1.2)
    snap, hold, relax, rest = 0.18 / tempo, rng.uniform(0.35, 0.8), 0.3 / tempo, rng.uniform(0.15, 0.4)
    raise_t, lower_t = 0.4, 0.5
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)
    reps = budget.fit(reps, snap + hold + relax + rest, lead_in + lead_out + raise_t + lower_t)
    away = float(rng.choice([-1.0, 1.0]))  # the way the head turns from the blow
    # g: 0 rest -> 1 ready guard; b: 0 ready -> 1 blocking; f: the flinch back at each block
    k = Keys(g=0, b=0, f=0)
    t = lead_in
    k.add(t, g=0)
    k.add(t + raise_t, g=1)
    t += raise_t
    for _ in range(reps):
        k.add(t, b=0, f=0)
        k.add(t + snap, "stop", b=1)
        k.add(t + snap + 0.12, f=1)
        k.add(t + snap + hold, b=1, f=0.6)
        t += snap + hold + relax
        k.add(t, b=0, f=0)
        t += rest
    k.add(t, g=1)
    t += lower_t
    k.add(t, g=0)
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    g, b, f = k("g", tt), k("b", tt), k("f", tt)
    pitch = 4.0 * g - 7.0 * f  # a slight forward fighting stance; the flinch tips the pelvis back
    pose.root(pitch=pitch)
    _knees(pose, pitch, 0.4 * g + 0.5 * f)
    pose.spine(bend=2.0 + 3.0 * g - 6.0 * f)
    pose.head(nod=10.0 * b + 6.0 * f, turn=away * 18.0 * f)
    for side in SIDES:
        arm = [(1 - g) * r + g * ((1 - b) * q + b * h)
               for r, q, h in zip(_REST, _READY, _BLOCK_ARMS[height][side])]
        pose.arm(side, flex=arm[0], abd=arm[1], twist=arm[2], elbow=arm[3], across=arm[4])
    times = how_often(reps)
    if height == "high":
        phrases = [f"blocks high {times} with both forearms in front of {{pos}} face",
                   f"raises {{pos}} forearms to guard {{pos}} head {times}",
                   f"puts up a high guard and flinches back {times}",
                   f"covers {{pos}} face with both arms {times}",
                   f"does {NUMBER_WORDS[reps]} high blocks" if reps > 1 else "does a high block"]
    else:
        phrases = [f"blocks low {times} with {{pos}} forearms across {{pos}} body",
                   f"guards {{pos}} stomach with both forearms {times}",
                   f"covers {{pos}} body with {{pos}} arms and flinches back {times}",
                   f"does {NUMBER_WORDS[reps]} low blocks" if reps > 1 else "does a low block"]
    return Action("block", pose, phrases, dict(reps=reps, height=height))


# --- dodge -------------------------------------------------------------------------------------------------

LEG = 0.82  # hip -> ankle of a straight leg, m (thigh 0.39 + shank 0.43)


def _crouch_to_level(abd_self, abd_other, crouch_other, lift=0.0):
    """Crouch (thigh forward c, knee 2c: the ankle stays under the hip) that puts a leg abducted `abd_self`
    with its foot `lift` m up level with the other leg (abducted `abd_other`, crouched `crouch_other`), so both
    feet stand on the floor in a wide stance. Degrees in, degrees out."""
    r = np.radians
    reach = (LEG * np.cos(r(abd_other)) * np.cos(r(crouch_other)) - lift) / (LEG * np.cos(r(abd_self)))
    return np.degrees(np.arccos(np.clip(reach, 0.2, 1.0)))


def _dodge(rng, side: str, budget: TimeBudget) -> Action:
    width = rng.uniform(0.3, 0.55)          # how far the lead foot lands out to the side, m
    back = bool(rng.random() < 0.5)         # return to where it stood, or stay out there
    duck = rng.uniform(12.0, 25.0)          # forward duck of the trunk
    lean = rng.uniform(18.0, 28.0)          # sideways lean of the trunk toward the dodge
    tempo = rng.uniform(0.9, 1.15)
    out, shift, hold = 0.2 / tempo, 0.16 / tempo, rng.uniform(0.4, 1.0)
    ret = 0.55 / tempo
    lead_in, lead_out = rng.uniform(0.4, 0.8), rng.uniform(0.4, 0.8)
    # one dodge always fits: at most 0.8 + 0.1 + 0.22 + 0.18 + 1.0 + 0.61 + 0.3 + 0.8 s
    sg = SIDES[side]["sign"]
    alpha = np.degrees(np.arcsin(0.5 * width / LEG))  # each leg's share of the wide stance
    # channels: la / ta lead and trail abduction, lift (m) of the swinging foot, crouch of the trail leg,
    # trunk lean and duck, arms up; lead_up / trail_up: which foot is off the floor
    k = Keys(la=0, ta=0, lift=0, tc=0, dk=0, ln=0, arms=0, lead_up=0, trail_up=0)
    t = lead_in
    k.add(t, la=0, ta=0, lift=0, tc=0, dk=0, ln=0, arms=0, lead_up=0)
    t += 0.1                                               # the quick dip that loads the push
    k.add(t, tc=12, dk=0.3, arms=0.5, lead_up=1, lift=0)
    k.add(t + 0.5 * out, lift=0.1, la=0.6 * alpha, ta=0.4 * alpha)
    t += out                                               # the lead foot lands out to the side
    k.add(t, "stop", la=alpha, ta=alpha, lift=0, lead_up=1)
    k.add(t, tc=8, dk=0.8, ln=0.7, arms=1)
    k.add(t + 0.05, lead_up=0)
    t += shift                                             # the body follows it over the lead foot
    k.add(t, la=0.15 * alpha, ta=1.85 * alpha, tc=5, dk=1, ln=1, arms=1)
    t += hold
    k.add(t, la=0.15 * alpha, ta=1.85 * alpha, tc=5, dk=1, ln=1, arms=1, lead_up=0, trail_up=0)
    if back:  # push back over the trail foot, then step the lead foot back in
        k.add(t + 0.5 * ret, la=alpha, ta=alpha, tc=8, dk=0.6, ln=0.5, arms=0.8, lead_up=0)
        k.add(t + 0.5 * ret + 0.05, lead_up=1)
        k.add(t + 0.75 * ret, lift=0.08)
        t += ret
        k.add(t, la=0, ta=0, lift=0, lead_up=1)
    else:  # draw the trail foot in beside the lead foot, the lead leg rising from its crouch as it comes
        low = float(_crouch_to_level(0.15 * alpha, 1.85 * alpha, 5.0))
        k.add(t, lc=low)
        k.add(t + 0.05, trail_up=1)
        k.add(t + 0.5 * ret, lift=0.08)
        t += ret
        k.add(t, la=0, ta=0, lift=0, trail_up=1, lc=0.4 * low)
    k.add(t + 0.05, lead_up=0, trail_up=0)
    t += 0.3
    k.add(t, tc=0, dk=0, ln=0, arms=0, lc=0)
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    la, ta, lift, tc = k("la", tt), k("ta", tt), k("lift", tt), k("tc", tt)
    dk, ln, arms = k("dk", tt), k("ln", tt), k("arms", tt)
    lead_up, trail_up = k("lead_up", tt) > 0.5, k("trail_up", tt) > 0.5
    lead, trail = side, OTHER[side]
    pitch = 6.0 * dk
    pose.root(pitch=pitch)
    # the lead leg bends to stand level with the trail leg (or clears the floor by `lift`); while the trail
    # foot is drawn in, the lead leg carries the body and the trail leg bends to clear the floor
    lc = np.where(trail_up, k("lc", tt), _crouch_to_level(la, ta, tc, np.where(lead_up, lift, 0.0)))
    tc = np.where(trail_up, _crouch_to_level(ta, la, lc, lift), tc)
    for leg, abd, c in ((lead, la, lc), (trail, ta, tc)):
        flex, knee = c + pitch, 2 * c
        pose.leg(leg, flex=flex, abd=abd, knee=knee, dorsi=flat_foot(pitch, flex, knee))
    pose.support[:, 0 if lead == "left" else 1] = ~lead_up
    pose.support[:, 0 if trail == "left" else 1] = ~trail_up
    pose.spine(bend=2 + duck * dk, lean=sg * lean * ln)
    pose.head(tilt=-sg * 0.5 * lean * ln, nod=-0.3 * duck * dk)
    for s in SIDES:  # hands come up by the face as the body slips away
        pose.arm(s, flex=3 + 32 * arms, abd=4 + 10 * arms, elbow=12 + 98 * arms, across=12 * arms)
    where = "comes back" if back else "stays there"
    phrases = [f"dodges to the {side} and {where}", f"ducks and leans to the {side} to dodge",
               f"quickly dodges {side} and {where}", f"evades to {{pos}} {side} with a quick lean",
               f"bends {{pos}} knees and slips to the {side}" + (" and back" if back else "")]
    return Action(f"dodge_{side}", pose, phrases, dict(side=side, back=back, width=round(float(width), 2)))


def dodge_left(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _dodge(rng, "left", budget)


def dodge_right(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _dodge(rng, "right", budget)


# --- hit reactions -----------------------------------------------------------------------------------------

def _legs_level(pose: Pose, pitch, swing: dict, lift: dict, bend: float = 6.0) -> None:
    """Legs in the sagittal plane: each hip -> ankle line at `swing[side]` degrees from vertical (> 0 forward),
    feet flat. The leg reaching further from vertical keeps a soft knee (up to `bend`), the other bends its
    knee just enough that both feet stand level (a split stance), less `lift[side]` m for a foot in the air."""
    r = np.radians
    widest = np.maximum(np.abs(swing["left"]), np.abs(swing["right"]))
    soft = bend * np.clip(widest / 10.0, 0.0, 1.0)  # straight legs when standing square
    height = LEG * np.cos(r(soft)) * np.cos(r(widest))
    for side in SIDES:
        c = np.degrees(np.arccos(np.clip((height - lift[side]) / (LEG * np.cos(r(swing[side]))), 0.2, 1.0)))
        flex, knee = swing[side] + c + pitch, 2 * c
        pose.leg(side, flex=flex, knee=knee, dorsi=flat_foot(pitch, flex, knee))


def _steps_plan(t: np.ndarray, start: float, step_t: float, stride: float, steps: int, first: str, d: float):
    """Staggering `steps` steps of `stride` m the way `d` (+1 forward, -1 back), then a closing step that
    brings the trailing foot beside the other. -> (hip -> ankle angle per side, foot lift per side, foot off
    the floor per side, end time). The pelvis is keyed between the feet and the legs are angled to reach
    the feet where the plan puts them, so the floor solver carries the body along."""
    foot = {"left": np.zeros_like(t), "right": np.zeros_like(t)}
    lift = {"left": np.zeros_like(t), "right": np.zeros_like(t)}
    up = {"left": np.zeros(t.shape, bool), "right": np.zeros(t.shape, bool)}
    at = {"left": 0.0, "right": 0.0}
    pelvis = Keys(x=0)
    pelvis.add(start, x=0)
    side = first
    for i in range(steps + 1):
        a, b = start + i * step_t, start + (i + 1) * step_t
        target = d * stride * min(i + 1, steps)
        u = np.clip((t - a - 0.03) / (b - a - 0.03), 0.0, 1.0)
        moving = (t > a + 0.03) & (t < b)
        foot[side] = np.where(t >= a, at[side] + (target - at[side]) * ease(u), foot[side])
        foot[OTHER[side]] = np.where(t >= a, at[OTHER[side]], foot[OTHER[side]])
        lift[side] = lift[side] + np.where(moving, (0.07 if i < steps else 0.05) * np.sin(np.pi * u), 0.0)
        up[side] |= moving
        at[side] = target
        pelvis.add(b, x=d * stride * (i + 0.5) if i < steps else d * stride * steps)
        side = OTHER[side]
    x = pelvis("x", t)
    angle = {s: np.degrees(np.arcsin(np.clip((foot[s] - x) / (0.99 * LEG), -0.6, 0.6))) for s in SIDES}
    return angle, lift, up, start + (steps + 1) * step_t


def _stagger(rng, struck: str, budget: TimeBudget) -> Action:
    """Struck from the front (the body is thrown back and staggers backward) or from behind (it lurches
    forward and steps forward to catch itself)."""
    d = -1.0 if struck == "front" else 1.0   # the way the blow throws the body
    steps = int(rng.choice([1, 2, 2, 3]))
    stride = rng.uniform(0.25, 0.4) * (0.8 if struck == "front" else 1.0)
    step_t = rng.uniform(0.28, 0.36)
    first = str(rng.choice(["left", "right"]))
    look = str(rng.choice(["left", "right"]))  # from behind: the shoulder it looks back over
    recover = rng.uniform(0.6, 0.9)
    look_t = 1.4 if struck == "back" else 0.0
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.6)
    steps = budget.fit(steps, step_t, lead_in + lead_out + 0.1 + step_t + recover + look_t)
    k = Keys(hit=0, look=0, arms=0)
    t = lead_in
    k.add(t, hit=0)
    k.add(t + 0.12, "stop", hit=1)           # the blow: a snap within a few frames
    k.add(t, arms=0)
    k.add(t + 0.25, arms=1)                  # the arms are flung a moment later
    t += 0.1
    steps_from = t
    t += (steps + 1) * step_t
    k.add(t - step_t, hit=0.5, arms=0.8)
    t += recover
    k.add(t, hit=0, arms=0)
    if look_t:
        k.add(t - 0.2, look=0)
        k.add(t + 0.45, look=1)
        k.add(t + 0.95, look=1)
        k.add(t + look_t, look=0)
        t += look_t
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    hit, look_c, arms = k("hit", tt), k("look", tt), k("arms", tt)
    # the arms are thrown against the blow and wave for balance while the feet catch up
    flail = arms * np.sin(2 * np.pi * 2.2 * np.clip(tt - lead_in, 0, None))
    if struck == "front":
        pitch = -9.0 * hit
        pose.spine(bend=2 - 14 * hit)
        pose.head(nod=-22 * hit)
        for s in SIDES:
            sgn = 1.0 if s == "left" else -1.0
            pose.arm(s, flex=3 + 45 * arms + 20 * sgn * flail, abd=4 + 50 * arms - 10 * sgn * flail,
                     elbow=12 + 30 * arms)
    else:
        pitch = 12.0 * hit
        pose.spine(bend=2 + 12 * hit, twist=(30 if look == "left" else -30) * look_c)
        pose.head(nod=-20 * hit + 5 * look_c, turn=(55 if look == "left" else -55) * look_c)
        for s in SIDES:
            sgn = 1.0 if s == "left" else -1.0
            pose.arm(s, flex=-35 * arms + 15 * sgn * flail, abd=4 + 30 * arms, elbow=12 + 15 * arms)
    pose.root(pitch=pitch)
    angle, lift, up, _ = _steps_plan(tt, steps_from, step_t, stride, steps, first, d)
    _legs_level(pose, pitch, angle, lift)
    pose.support[:, 0] = ~up["left"]
    pose.support[:, 1] = ~up["right"]
    n = NUMBER_WORDS[steps]
    s = "a step" if steps == 1 else f"{n} steps"
    if struck == "front":
        phrases = [f"gets hit in the face and staggers back {s}", f"is struck from the front and reels backward {s}",
                   f"reels back from a blow and takes {s} backward", f"gets knocked back {s} with {{pos}} arms flailing",
                   f"recoils from a hit in front and staggers back {s}"]
    else:
        phrases = [f"gets hit from behind and staggers forward {s}",
                   f"is struck in the back and lurches forward {s}, then looks back over {{pos}} {look} shoulder",
                   f"gets shoved from behind, takes {s} forward and looks back",
                   f"lurches forward {s} after a hit in the back",
                   f"is hit from behind, catches {{pos}} balance and looks over {{pos}} {look} shoulder"]
    params = dict(steps=steps, first=first, **(dict(look=look) if struck == "back" else {}))
    return Action(f"hit_reaction_{struck}", pose, phrases, params)


def hit_reaction_front(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _stagger(rng, "front", budget)


def hit_reaction_back(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    return _stagger(rng, "back", budget)


# --- roundhouse kick ---------------------------------------------------------------------------------------

def roundhouse_kick(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    side = str(rng.choice(["left", "right"]))
    reps = int(rng.choice([1, 1, 2, 3]))
    height = str(rng.choice(["middle", "high"]))
    tempo = rng.uniform(0.85, 1.1)
    turn = rng.uniform(60.0, 80.0)             # how far the hips turn over the standing foot
    # the kicking leg out to the side (abd), a little forward (flex), the pelvis tipped away (roll)
    abd, flex, roll = (rng.uniform(68, 75), rng.uniform(25, 35), rng.uniform(18, 25)) if height == "middle" \
        else (rng.uniform(78, 85), rng.uniform(38, 48), rng.uniform(28, 34))
    chamber, strike, back, down, rest = 0.3 / tempo, 0.26 / tempo, 0.25 / tempo, 0.35 / tempo, rng.uniform(0.3, 0.6)
    guard_t, lead_in, lead_out = 0.4, rng.uniform(0.3, 0.6), rng.uniform(0.4, 0.7)
    reps = budget.fit(reps, chamber + strike + back + down + rest, lead_in + lead_out + 2 * guard_t)
    sg = SIDES[side]["sign"]
    zero = dict(yaw=0, roll=0, fl=0, ab=0, kn=0, up=0, heel=0, arm=0, pt=0)
    k = Keys(**zero, g=0)
    t = lead_in
    k.add(t, g=0)
    t += guard_t
    k.add(t, g=1)
    for _ in range(reps):
        k.add(t, **zero)
        k.add(t + 0.05, up=1)
        t += chamber                            # knee up and across, the hips start to turn, heel up
        k.add(t, yaw=0.35 * turn, roll=0.3 * roll, fl=70, ab=25, kn=110, up=1, heel=12, arm=0.4, pt=0.5)
        t += strike                             # hips turn over, the shin whips out level
        k.add(t, yaw=turn, roll=roll, fl=flex, ab=abd, kn=8, up=1, heel=12, arm=1, pt=1)
        t += back                               # snap the shin back in
        k.add(t, yaw=0.7 * turn, roll=0.6 * roll, fl=55, ab=45, kn=100, up=1, heel=12, arm=0.6, pt=0.6)
        k.add(t + 0.7 * down, fl=12, ab=6, kn=25, up=1, pt=0)
        t += down                               # turn back to face front and set the foot down beside the other
        k.add(t, **zero)
        t += rest
    k.add(t, g=1)
    t += guard_t
    k.add(t, g=0)
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    yaw, roll_c, heel, arm, g = k("yaw", tt), k("roll", tt), k("heel", tt), k("arm", tt), k("g", tt)
    kicking, standing = side, OTHER[side]
    # the pelvis turns toward the standing side (away from the kicking leg) and tips away from the kick
    pose.root(yaw=-sg * yaw, roll=-sg * roll_c)
    pose.spine(bend=2.0, lean=sg * 0.5 * roll_c)
    pose.head(turn=sg * 0.6 * yaw, tilt=sg * 0.5 * roll_c)  # the eyes stay on the target ahead
    fl, kn = k("fl", tt), k("kn", tt)
    pt = k("pt", tt)  # the kicking foot points (instep first) only while it is up
    # (no twist of the kicking thigh: turned in, the knee would bend backward against the hips' axis)
    pose.leg(kicking, flex=fl, abd=k("ab", tt), knee=kn, dorsi=(1 - pt) * flat_foot(0.0, fl, kn) - 20 * pt)
    # the standing foot pivots on its ball: it turns 60% of the way with the hips, the leg takes the rest
    pose.leg(standing, abd=roll_c, yaw=sg * 0.4 * yaw, dorsi=flat_foot(0.0, 0.0, 0.0, lift=heel))
    pose.support[:, 0 if kicking == "left" else 1] = k("up", tt) < 0.02
    for s in SIDES:  # a fighting guard; the kicking side's arm swings down and back against the kick
        on = arm if s == kicking else 0.0
        pose.arm(s, flex=(1 - on) * g * 40 - 25 * on, abd=4 + g * 10 + 25 * on, across=(1 - on) * g * 18,
                 elbow=12 + (1 - on) * g * 108 - 0 * on)
    times = how_often(reps)
    how = "high" if height == "high" else "at waist height"
    phrases = [f"throws a {side} roundhouse kick {how}" if reps == 1 else
               f"throws {NUMBER_WORDS[reps]} {side} roundhouse kicks {how}",
               f"pivots on one foot and swings {{pos}} {side} leg around in a roundhouse kick {times}",
               f"does a roundhouse kick with the {side} leg {times}",
               f"turns {{pos}} hips over and whips {{pos}} {side} shin around {how}",
               f"delivers a {side} roundhouse kick {how}" + (f" {times}" if reps > 1 else "")]
    return Action("roundhouse_kick", pose, phrases, dict(side=side, reps=reps, height=height))


# --- uppercut -----------------------------------------------------------------------------------------------

_GUARD = (40, 14, 0, 120, 18)     # (flex, abd, twist, elbow, across): fists up by the chin
_LOADED = (0, 12, 0, 85, 0)       # the punching fist dropped by the hip, elbow bent
_UPPER = (70, 0, 0, 110, 20)      # ... driven up in front of the chin, forearm upright, elbow in


def uppercut(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    side = str(rng.choice(["left", "right"]))
    reps = int(rng.integers(1, 5))
    tempo = rng.uniform(0.85, 1.1)
    load, drive, back, rest = 0.28 / tempo, 0.25 / tempo, 0.3 / tempo, rng.uniform(0.2, 0.5)
    guard_t, lead_in, lead_out = 0.45, rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)
    reps = budget.fit(reps, load + drive + back + rest, lead_in + lead_out + 2 * guard_t)
    sg = SIDES[side]["sign"]
    # g: guard up; u: -1 loaded (fist by the hip, knees dipped, shoulders wound back) .. +1 uppercut
    k = Keys(g=0, u=0)
    t = lead_in
    k.add(t, g=0)
    t += guard_t
    k.add(t, g=1)
    for _ in range(reps):
        k.add(t, u=0)
        t += load
        k.add(t, u=-1)
        t += drive
        k.add(t, "stop", u=1)
        k.add(t + 0.12, u=1)
        t += back
        k.add(t, u=0)
        t += rest
    k.add(t, g=1)
    t += guard_t
    k.add(t, g=0)
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    g, u = k("g", tt), k("u", tt)
    loaded, up = np.clip(-u, 0, 1), np.clip(u, 0, 1)
    pitch = 5.0 * g + 4.0 * loaded - 3.0 * up
    pose.root(pitch=pitch)
    _knees(pose, pitch, 0.35 * g + 0.9 * loaded)           # the knees dip, then drive the punch up
    pose.spine(bend=2 + 6 * loaded - 4 * up, twist=sg * (14 * loaded - 20 * up))
    pose.head(nod=-5 * up)
    for s in SIDES:
        if s == side:
            w0, w1, w2 = 1 - loaded - up, loaded, up
            arm = [(1 - g) * r + g * (w0 * q + w1 * a + w2 * b) for r, q, a, b in zip(_REST, _GUARD, _LOADED, _UPPER)]
        else:
            arm = [(1 - g) * r + g * q for r, q in zip(_REST, _GUARD)]
        pose.arm(s, flex=arm[0], abd=arm[1], twist=arm[2], elbow=arm[3], across=arm[4])
    times = how_often(reps)
    phrases = [f"throws a {side} uppercut" if reps == 1 else f"throws {NUMBER_WORDS[reps]} {side} uppercuts",
               f"dips {{pos}} knees and drives a {side} uppercut up to chin height {times}",
               f"does {NUMBER_WORDS[reps]} rising {side} uppercuts" if reps > 1 else f"does a rising {side} uppercut",
               f"uppercuts {times} with {{pos}} {side} fist",
               f"brings {{pos}} {side} fist up from the hip in an uppercut {times}"]
    return Action("uppercut", pose, phrases, dict(side=side, reps=reps))


FAMILIES: tuple = (block, dodge_left, dodge_right, hit_reaction_front, hit_reaction_back, roundhouse_kick, uppercut)
WORDS: dict = {
    "NOUN": {"face": "face", "forearms": "forearm", "stomach": "stomach", "blow": "blow", "balance": "balance",
             "shin": "shin", "hips": "hip", "hip": "hip", "chin": "chin"},
    "ADJ": "roundhouse rising",
    "VERB": {"covers": "cover", "flinches": "flinch", "dodges": "dodge", "ducks": "duck", "leans": "lean",
             "comes": "come", "evades": "evade", "slips": "slip", "gets": "get", "staggers": "stagger",
             "struck": "strike", "reels": "reel", "knocked": "knock", "flailing": "flail", "recoils": "recoil",
             "lurches": "lurch", "shoved": "shove", "catches": "catch", "pivots": "pivot", "whips": "whip",
             "delivers": "deliver", "dips": "dip", "drives": "drive"},
    "ADV": "there behind",
    "ADP": "from across",
    "NOUN_OR_VERB": {"block": "block", "blocks": "block", "guard": "guard", "guards": "guard", "dodge": "dodge",
                     "lean": "lean", "hit": "hit",
                     "uppercut": "uppercut", "uppercuts": "uppercut"},
}
LAST_ONLY: tuple[str, ...] = ()
