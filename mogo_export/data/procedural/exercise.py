"""Exercise and play: jumping jacks, lunges, arm circles, swimming strokes standing and dance steps.

Each is a family as action.py describes, `(rng, budget) -> Action`. FAMILIES lists this module's families in
their fixed order (families.py appends it to the registry); WORDS holds every caption word they use that the
shared lexicon (captions.py) lacks; LAST_ONLY names the families that do not end standing (none here).

- jumping_jacks: small hops (pose.flight, a leap in place) that spread the feet while both arms swing from
  the sides up over the head, and close them with the arms back down; reps, speed.
- lunges: a long step forward into a deep lunge (front knee ~90 deg, back knee close above the floor, back
  heel raised) and a push back to standing; reps, side (left, right or alternating), speed. The legs are
  posed by planar leg IK (`_leg_ik`) from where the hips and feet must be, so the feet keep their pins.
- arm_circles: both arms held out to the sides circle forward or backward; reps (circles), direction, size,
  speed.
- swim_strokes: standing in place, the arms swim: alternating overhead front-crawl strokes or breaststroke;
  reps (strokes), style.
- dance: about two beats a second, on the spot: a step-touch from side to side (it keeps changing direction
  and comes back) or a groove in place with alternating knee pops; knees bounce, hips sway, arms swing or
  roll; style, beats (bars of four), first side, bpm.
"""
from __future__ import annotations

import numpy as np

from mogo_runtime.kinematics.skeleton import HUMANML3D

from .action import FULL_BUDGET, Action, TimeBudget, sample_speed
from .captions import NUMBER_WORDS, adverb, how_often
from .curves import Keys, cyclic, ease, envelope
from .kinematics import FOOT_PITCH
from .pose import OTHER, SIDES, Pose, flat_foot, seconds_to_frames

STAND = 0.875  # root (and hip) height of the neutral standing pose, m (kinematics of Pose(1))


def _leg_dims(side: str) -> tuple[float, float, float, float, float]:
    """(thigh, shank, foot bone, standing foot pitch deg, standing ankle height) of one leg."""
    s = SIDES[side]
    knee, ankle = s["knee"], s["ankle"]
    toe = HUMANML3D.foot_left[1] if side == "left" else HUMANML3D.foot_right[1]
    l1, l2, lf = (float(HUMANML3D.bone_lengths[j]) for j in (knee, ankle, toe))
    return l1, l2, lf, float(FOOT_PITCH[ankle]), STAND - l1 - l2


def _leg_ik(dz, dy, l1: float, l2: float) -> tuple[np.ndarray, np.ndarray]:
    """Planar two-bone IK of a leg: hip -> ankle vector (forward dz, up dy) -> (thigh angle forward of the
    vertical, knee bend), degrees. The knee bends forward, as knees do."""
    dz, dy = np.asarray(dz, dtype=np.float64), np.asarray(dy, dtype=np.float64)
    d = np.clip(np.hypot(dz, dy), abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    knee = 180.0 - np.degrees(np.arccos(np.clip((l1 * l1 + l2 * l2 - d * d) / (2 * l1 * l2), -1, 1)))
    beta = np.degrees(np.arctan2(dz, -dy))
    thigh = beta + np.degrees(np.arccos(np.clip((l1 * l1 + d * d - l2 * l2) / (2 * l1 * d), -1, 1)))
    return thigh, knee


def _toe_to_ankle(side: str, toe_z, toe_y, lift) -> tuple[np.ndarray, np.ndarray]:
    """Ankle (z, y) of a foot whose toe is at (toe_z, toe_y) with its heel raised `lift` degrees (the toe joint
    is on the floor, y = 0, when the foot stands flat)."""
    _, _, lf, p0, _ = _leg_dims(side)
    a = np.radians(p0 + np.asarray(lift))
    return np.asarray(toe_z) - lf * np.cos(a), np.asarray(toe_y) + lf * np.sin(a)


# --- jumping jacks -------------------------------------------------------------------------------------


def jumping_jacks(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.integers(3, 11))
    speed = sample_speed(rng)
    settle = {"slow": 0.32, "normal": 0.14, "fast": 0.03}[speed] * rng.uniform(0.85, 1.15)
    flight = rng.uniform(0.2, 0.26)           # a hop of 5-8 cm
    push, land = 0.13, 0.15
    spread = rng.uniform(11.0, 15.0)          # each leg's abduction: feet ~0.55-0.65 m apart
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.4, 0.8)
    hop = push + flight + land + settle
    reps = budget.fit(reps, 2 * hop, lead_in + lead_out + 0.5)
    k = Keys(thigh=0, shank=0, heel=0, arm=0, abd=0)
    offs = []
    t = lead_in
    k.add(t, thigh=0, shank=0, heel=0)
    t += 0.2
    k.add(t, thigh=14, shank=8, heel=0)       # soft knees before the first hop
    for i in range(2 * reps):
        out = i % 2 == 0                      # hops out (arms up), then back in (arms down)
        k.add(t, arm=0 if out else 1, abd=0 if out else 1)
        t += push
        k.add(t, "stop", thigh=-2, shank=2, heel=22)  # take-off: legs straight, on the toes
        offs.append((t, t + flight))
        k.add(t + 0.5 * flight, thigh=2, shank=0, heel=10)
        t += flight
        k.add(t, arm=1 if out else 0, abd=1 if out else 0)
        k.add(t, "start", thigh=5, shank=0, heel=4)  # touch-down, legs giving way
        t += land
        k.add(t, thigh=18, shank=10, heel=0)
        t += settle
        k.add(t, thigh=14, shank=8, heel=0)
    k.add(t + 0.3, thigh=0, shank=0, heel=0)
    pose = Pose(seconds_to_frames(t + 0.3 + lead_out))
    tt = pose.t
    thigh, shank, heel = k("thigh", tt), k("shank", tt), k("heel", tt)
    pitch = 0.25 * thigh
    flex, knee = thigh + pitch, thigh + shank
    pose.root(pitch=pitch)
    pose.spine(bend=2.0 - 0.2 * pitch)
    arm, abd = k("arm", tt), k("abd", tt)
    for side in SIDES:
        pose.leg(side, flex=flex, knee=knee, abd=spread * abd, dorsi=flat_foot(pitch, flex, knee, lift=heel))
        # arms straight out of the sides and over the head, palms turning up on the way
        pose.arm(side, abd=6 + 160 * arm, flex=6 * np.sin(np.pi * arm), twist=60 * arm, elbow=10 - 4 * arm)
    pose.head(nod=-4 * arm)
    for a, b in offs:
        air = (tt > a) & (tt < b)
        pose.flight |= air
        pose.leap |= air                      # in place: the feet's midpoint lands where it took off
    times = how_often(reps)
    n = NUMBER_WORDS[reps]
    phrases = [f"does {n} jumping jacks{adverb(speed)}", f"does jumping jacks {times}",
               f"does {n} star jumps, arms up over {{pos}} head and legs apart",
               f"bounces {{pos}} feet apart and back together {times}, swinging both arms over {{pos}} head",
               f"spreads {{pos}} arms and legs{adverb(speed)} and brings them back together {times}"]
    return Action("jumping_jacks", pose, phrases, dict(reps=reps, speed=speed))


# --- lunges --------------------------------------------------------------------------------------------


def lunges(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.integers(1, 7))
    side = str(rng.choice(["left", "right", "alternating"]))
    speed = str(rng.choice(["slow", "normal", "fast"], p=[0.35, 0.45, 0.2]))
    tempo = {"slow": 0.75, "normal": 1.0, "fast": 1.3}[speed] * rng.uniform(0.92, 1.08)
    step, lower, hold, rise, rest = 0.6 / tempo, 0.55 / tempo, rng.uniform(0.1, 0.4), 0.8 / tempo, rng.uniform(0.2, 0.5)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    per = step + lower + hold + rise + rest
    # a short budget (5 s) still holds one slow lunge: the standing before and after shrinks first
    spare = budget.seconds - 0.05 - per
    lead_in, lead_out = min(lead_in, max(0.2, spare / 2)), min(lead_out, max(0.2, spare / 2))
    reps = budget.fit(reps, per, lead_in + lead_out)
    if reps == 1 and side == "alternating":  # one lunge cannot alternate: it is a lunge on one side
        side = str(rng.choice(["left", "right"]))
    stride = rng.uniform(0.82, 0.95)          # front ankle ahead of where it stood, m
    front_thigh = rng.uniform(74.0, 84.0)     # front thigh at the bottom, degrees forward of the vertical
    shin_lean = rng.uniform(5.0, 12.0)        # front knee a little ahead of the ankle
    pitch_bottom = rng.uniform(2.0, 8.0)      # trunk stays nearly upright
    T = seconds_to_frames(lead_in + reps * (step + lower + hold + rise + rest) + lead_out)
    pose = Pose(T)
    tt = pose.t
    legs = {s: dict(flex=np.zeros(T), knee=np.zeros(T), dorsi=np.zeros(T)) for s in SIDES}
    pitch = np.zeros(T)
    fronts = []
    t = lead_in
    for r in range(reps):
        front = side if side != "alternating" else ("right" if r % 2 == 0 else "left")
        back = OTHER[front]
        fronts.append(front)
        l1f, l2f, _, _, af = _leg_dims(front)
        l1b, l2b, lfb, p0b, ab = _leg_dims(back)
        rad = np.radians
        hz_b = stride - l1f * np.sin(rad(front_thigh)) + l2f * np.sin(rad(shin_lean))
        hy_b = af + l2f * np.cos(rad(shin_lean)) + l1f * np.cos(rad(front_thigh))
        touch = stride - 0.5  # the front leg lands reaching ~35 deg forward, hips over the middle
        k = Keys(hz=0, hy=STAND, fz=0, fy=0, lift=0, pitch=0)
        t0 = t
        k.add(t, hz=0, hy=STAND, fz=0, fy=0, lift=0, pitch=0)
        k.add(t + 0.5 * step, fz=0.45 * stride, fy=0.09, hz=0.3 * touch, hy=STAND - 0.04, lift=12)
        t += step
        k.add(t, "stop", fz=stride, fy=0.0)
        k.add(t, hz=touch, hy=STAND - 0.16, lift=32, pitch=0.5 * pitch_bottom)
        t += lower
        k.add(t, hz=hz_b, hy=hy_b, lift=62, pitch=pitch_bottom, fz=stride, fy=0.0)
        t += hold
        k.add(t, hz=hz_b - 0.01, hy=hy_b + 0.005, lift=62, pitch=pitch_bottom, fz=stride, fy=0.0)
        # push back: the hips rise and move back over the back foot, then the front foot leaves the floor
        k.add(t + 0.45 * rise, hz=touch - 0.03, hy=STAND - 0.17, lift=34, pitch=0.6 * pitch_bottom, fz=stride, fy=0.0)
        k.add(t + 0.75 * rise, fz=0.45 * stride, fy=0.08, hz=0.25 * touch, hy=STAND - 0.04, lift=10)
        t += rise
        k.add(t, "stop", fz=0, fy=0)
        k.add(t, hz=0, hy=STAND, lift=0, pitch=0)
        on = (tt >= t0) & (tt < t + 1e-9)
        hz, hy, fz, fy, lift = (k(c, tt[on]) for c in ("hz", "hy", "fz", "fy", "lift"))
        p = k("pitch", tt[on])
        pitch[on] = p
        # the hips' x offsets do not matter in the sagittal plane; the root is the hips' midpoint
        th_f, kn_f = _leg_ik(fz - hz, (af + fy) - hy, l1f, l2f)
        bz, by = _toe_to_ankle(back, lfb * np.cos(rad(p0b)), 0.0, lift)
        th_b, kn_b = _leg_ik(bz - hz, by - hy, l1b, l2b)
        fl_f, fl_b = th_f + p, th_b + p
        legs[front]["flex"][on], legs[front]["knee"][on] = fl_f, kn_f
        legs[front]["dorsi"][on] = flat_foot(p, fl_f, kn_f) + 8 * np.clip(fy / 0.09, 0, 1)  # toes up in the air
        legs[back]["flex"][on], legs[back]["knee"][on] = fl_b, kn_b
        legs[back]["dorsi"][on] = flat_foot(p, fl_b, kn_b, lift=lift)
        pose.support[on, 0 if front == "left" else 1] = fy < 0.004
        t += rest
    pose.root(pitch=pitch)
    for s in SIDES:
        pose.leg(s, **legs[s])
    depth = np.clip((STAND - _hip_height(legs, pitch)) / 0.4, 0, 1)
    pose.relaxed()
    for s in SIDES:
        pose.arm(s, abd=6 * depth, flex=-0.8 * pitch)
    pose.spine(bend=-0.5 * pitch)
    times = how_often(reps)
    n = NUMBER_WORDS[reps]
    if side == "alternating":
        phrases = [f"does {n} lunges{adverb(speed)}, alternating legs", f"lunges forward {times} alternating legs",
                   f"steps forward into a deep lunge {times}, switching legs each time",
                   f"does {n} lunges, one leg and then the other", f"lunges{adverb(speed)} with left and right legs"]
    else:
        phrases = [f"lunges forward with {{pos}} {side} leg" + (f" {times}" if reps > 1 else ""),
                   (f"does {n} lunges" if reps > 1 else "does a lunge") + f" on the {side} leg{adverb(speed)}",
                   f"steps forward with the {side} foot into a deep lunge {times}",
                   f"lunges{adverb(speed)} on {{pos}} {side} leg and rises back up {times}",
                   f"takes a big step with {{pos}} {side} leg, bends both knees and steps back {times}"]
    return Action("lunges", pose, phrases, dict(reps=reps, side=side, speed=speed))


def _hip_height(legs: dict, pitch: np.ndarray) -> np.ndarray:
    """Rough hip height of a lunge from its angles (the higher of the two legs' straight-line reach)."""
    out = []
    for s in SIDES:
        l1, l2, _, _, a = _leg_dims(s)
        th = np.radians(legs[s]["flex"] - pitch)
        sh = th - np.radians(legs[s]["knee"])
        out.append(a + l1 * np.cos(th) + l2 * np.cos(sh))
    return np.minimum(*out)


# --- arm circles ---------------------------------------------------------------------------------------


def arm_circles(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    reps = int(rng.integers(3, 11))
    direction = str(rng.choice(["forward", "backward"]))
    big = bool(rng.random() < 0.5)
    speed = sample_speed(rng)
    freq = {"slow": 0.75, "normal": 1.1, "fast": 1.6}[speed] * rng.uniform(0.9, 1.1) * (0.85 if big else 1.0)
    radius = rng.uniform(38, 48) if big else rng.uniform(20, 27)
    raise_t, lower_t = rng.uniform(0.5, 0.8), rng.uniform(0.5, 0.8)
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    reps = budget.fit(reps, 1.0 / freq, lead_in + lead_out + raise_t + lower_t)
    start = lead_in + raise_t
    stop = start + reps / freq
    pose = Pose(seconds_to_frames(stop + lower_t + lead_out))
    tt = pose.t
    up = ease((tt - lead_in) / raise_t) * ease((stop + lower_t - tt) / lower_t)
    sign = 1.0 if direction == "forward" else -1.0
    theta = 2 * np.pi * freq * np.clip(tt - start, 0, stop - start)
    # the circle's size grows over the first quarter turn and shrinks over the last: it starts and ends level
    r = radius * envelope(tt, start, stop, 0.25 / freq)
    pose.relaxed()
    for side in SIDES:
        # theta = 0 at the top of the circle; forward circles move the hand forward over the top
        pose.arm(side, abd=up * 84 + r * (np.cos(theta) - 1) + r, flex=sign * r * np.sin(theta),
                 elbow=-up * 8, twist=up * 20)
    pose.spine(bend=-1.5 * up)
    pose.head(nod=-3 * up)
    times = how_often(reps)
    n = NUMBER_WORDS[reps]
    size = "big" if big else "small"
    phrases = [f"holds {{pos}} arms out to the sides and rotates them {direction} in circles {times}",
               f"does {n} {size} arm circle{'s' if reps > 1 else ''} {direction}{adverb(speed)}",
               f"rotates both arms {direction} in {size} circles{adverb(speed)}",
               f"makes {n} {size} {direction} circle{'s' if reps > 1 else ''} with both arms",
               f"swings {{pos}} outstretched arms around in circles {times}"]
    return Action("arm_circles", pose, phrases, dict(reps=reps, direction=direction, big=big, speed=speed))


# --- swimming strokes standing -------------------------------------------------------------------------

# one arm's freestyle (front crawl) cycle from the hand's entry above the head: the pull down the front to the
# thigh, then the recovery with the elbow high out to the side and the hand back over the shoulder
CRAWL = [(0.0, dict(flex=168, abd=14, elbow=8, twist=0)), (0.2, dict(flex=105, abd=10, elbow=38, twist=-10)),
         (0.42, dict(flex=-12, abd=14, elbow=20, twist=0)), (0.6, dict(flex=-8, abd=58, elbow=95, twist=30)),
         (0.78, dict(flex=60, abd=95, elbow=110, twist=55)), (0.92, dict(flex=140, abd=45, elbow=45, twist=20))]
# both arms' breaststroke cycle from the glide: hands together straight ahead, sweep out wide, elbows in with
# the hands under the chin, then shoot forward again
BREAST = [(0.0, dict(flex=92, abd=6, across=13, elbow=4)), (0.3, dict(flex=84, abd=16, across=-38, elbow=12)),
          (0.5, dict(flex=60, abd=28, across=-12, elbow=80)), (0.68, dict(flex=55, abd=10, across=20, elbow=118)),
          (0.86, dict(flex=85, abd=6, across=16, elbow=40))]


def _cycle(phase: np.ndarray, keys: list, channel: str) -> np.ndarray:
    """One channel of a keyed stroke cycle (CRAWL, BREAST) at `phase` (cycles)."""
    return cyclic(phase, [(p, v[channel]) for p, v in keys])


def swim_strokes(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    style = str(rng.choice(["freestyle", "breaststroke"]))
    reps = int(rng.integers(2, 9))
    period = (rng.uniform(1.0, 1.4) if style == "freestyle" else rng.uniform(1.2, 1.7))
    ramp = 0.6
    lead_in, lead_out = rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)
    # freestyle: a stroke is one arm's pull, the arms half a cycle apart; breaststroke: both arms together
    per = period / 2 if style == "freestyle" else period
    reps = budget.fit(reps, per, lead_in + lead_out + 2 * ramp)
    start = lead_in + ramp
    stop = start + reps * per
    pose = Pose(seconds_to_frames(stop + ramp + lead_out))
    tt = pose.t
    on = ease((tt - lead_in) / ramp) * ease((stop + ramp - tt) / ramp)
    phase = np.clip(tt - start, 0, stop - start) / period
    pitch = 10 * on
    pose.root(pitch=pitch)
    flex, knee = pitch + 6 * on, 8 * on
    for s in SIDES:
        pose.leg(s, flex=flex, knee=knee, dorsi=flat_foot(pitch, flex, knee))
    pose.relaxed()
    if style == "freestyle":
        ph = {"right": phase - 0.25, "left": phase + 0.25}  # the right hand enters first
        for s in SIDES:
            rest = dict(flex=0, abd=0, elbow=0, twist=0)
            w = on
            pose.arm(s, **{c: w * _cycle(ph[s], CRAWL, c) + (1 - w) * rest[c] for c in rest})
        # shoulders roll with the pulling arm and the head turns to breathe every other stroke
        roll = np.sin(2 * np.pi * phase)
        pose.spine(bend=-pitch + 8 * on, twist=10 * on * roll)
        pose.head(turn=on * 28 * np.clip(np.sin(np.pi * phase), 0, 1) ** 2, nod=-8 * on)
    else:
        for s in SIDES:
            pose.arm(s, **{c: on * _cycle(phase, BREAST, c) for c in ("flex", "abd", "across", "elbow")})
        lift = np.clip(np.sin(2 * np.pi * (phase - 0.35)), 0, 1)  # the head comes up as the hands sweep in
        pose.spine(bend=-pitch + 8 * on - 6 * on * lift)
        pose.head(nod=-on * (6 + 14 * lift))
        for s in SIDES:
            pose.leg(s, flex=4 * on * lift, knee=8 * on * lift, dorsi=flat_foot(0, 4 * on * lift, 8 * on * lift))
    times = how_often(reps)
    n = NUMBER_WORDS[reps]
    if style == "freestyle":
        phrases = ["does a swimming motion standing in place",
                   f"swims freestyle in place, {n} arm stroke{'s' if reps > 1 else ''}",
                   f"mimes freestyle swimming with alternating arms {times}",
                   f"pretends to swim, reaching over {{pos}} head with one arm after the other {times}",
                   f"makes {n} overhead swimming stroke{'s' if reps > 1 else ''} standing still"]
    else:
        phrases = ["does a swimming motion standing in place", f"mimes the breaststroke {times}",
                   f"does {n} breaststroke arm stroke{'s' if reps > 1 else ''} standing in place",
                   f"pretends to swim breaststroke, sweeping both arms out and back in {times}",
                   f"swims breaststroke in place with {{pos}} arms {times}"]
    return Action("swim_strokes", pose, phrases, dict(reps=reps, style=style))


# --- dance ---------------------------------------------------------------------------------------------


def dance(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    style = str(rng.choice(["step_touch", "groove"]))
    bpm = rng.uniform(105, 130)
    beat = 60.0 / bpm
    bars = int(rng.integers(1, 5))            # four beats each
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6)
    bars = budget.fit(bars, 4 * beat, lead_in + lead_out + 0.4)
    start = lead_in + 0.2
    stop = start + 4 * bars * beat
    pose = Pose(seconds_to_frames(stop + 0.2 + lead_out))
    tt = pose.t
    on = envelope(tt, lead_in, stop + 0.2, 0.3)
    b = np.clip((tt - start) / beat, 0, 4 * bars)   # beats done so far
    frac = b - np.floor(b)
    frac[b >= 4 * bars] = 0.0
    dancing = (tt >= start) & (tt < stop)
    # knees dip on every beat
    bounce = on * (0.5 - 0.5 * np.cos(2 * np.pi * b))
    first = str(rng.choice(["left", "right"]))
    pose.relaxed(arms=False)
    if style == "step_touch":
        width = rng.uniform(0.28, 0.4)
        alpha = np.degrees(np.arcsin(0.5 * width / 0.85))
        beat_i = np.floor(b).astype(int)
        # beats 0, 2: the lead foot steps out (first to `first`, then the other way); 1, 3: the other closes in
        out_beat = (beat_i % 2 == 0) & dancing
        lead = np.where((beat_i % 4) < 2, first, OTHER[first])
        move = ease((frac - 0.2) / 0.6)  # the feet travel while they are up, not as they leave or reach the floor
        spread = alpha * np.where(out_beat, move, np.where(dancing, 1 - move, 0.0))
        bump = np.where(dancing, np.sin(np.pi * frac), 0.0) ** 1.5
        for s in SIDES:
            mover = np.where(out_beat, lead == s, lead != s) & dancing
            lift_ = bump * mover
            fl, kn = 22 * lift_ + 13 * bounce, 45 * lift_ + 28 * bounce
            pose.leg(s, flex=fl, knee=kn, abd=spread, dorsi=flat_foot(0, fl, kn) - 12 * lift_)
            pose.support[:, 0 if s == "left" else 1] = ~mover | (lift_ < 0.05)
        # the body swings toward the side it steps to: hips, shoulders and both arms
        toward = (1.0 if first == "left" else -1.0) * on * np.where(dancing, np.sin(np.pi * b / 2), 0.0)  # > 0: left
        pose.spine(lean=-4 * toward, twist=8 * toward)
        for s in SIDES:
            sg = SIDES[s]["sign"]
            pose.arm(s, flex=on * (35 + 15 * sg * toward), abd=on * (12 + 10 * sg * toward) + 5,
                     elbow=on * (85 + 10 * bounce) + 12, across=on * 8 * toward * sg)
        params = dict(style=style, beats=4 * bars, first=first, bpm=round(float(bpm), 1))
    else:
        # feet planted a little apart; on each beat one knee pops forward (heel up, toes down), the hips
        # sway to the other side and turn, and the forearms roll in front of the chest
        pop = {s: on * np.where(dancing, np.clip(np.sin(np.pi * (b + (0 if s == first else 1))), 0, 1), 0.0) ** 2
               for s in SIDES}
        hip_y = STAND - 0.025 * bounce - 0.01 * on
        yaw = 0.0 * on * np.where(dancing, np.sin(np.pi * b), 0.0) * (1 if first == "left" else -1)
        pose.root(yaw=yaw)
        for s in SIDES:
            l1, l2, lf, p0, _ = _leg_dims(s)
            heel = 28 * pop[s]
            az, ay = _toe_to_ankle(s, lf * np.cos(np.radians(p0)), 0.0, heel)
            th, kn = _leg_ik(az, ay - hip_y, l1, l2)
            pose.leg(s, flex=th, knee=kn, yaw=-yaw, dorsi=flat_foot(0, th, kn, lift=heel))
        sway = pop["left"] - pop["right"]
        pose.spine(lean=-5 * sway, twist=-0.6 * yaw)
        roll = 2 * np.pi * b / 2
        for s in SIDES:
            sg = SIDES[s]["sign"]
            c = np.cos(roll + (0 if s == "left" else np.pi))
            pose.arm(s, flex=on * (55 + 14 * c) + 2, abd=on * 12 + 5, across=on * 14,
                     elbow=on * (95 - 15 * c) + 12, twist=0.0)
        params = dict(style=style, beats=4 * bars, first=first, bpm=round(float(bpm), 1))
    pose.head(nod=3 * bounce, tilt=2 * np.sin(np.pi * b))
    if style == "step_touch":
        phrases = ["dances, stepping side to side", "dances a step touch to the left and right with swinging arms",
                   f"steps side to side to a beat and sways {{pos}} hips, {NUMBER_WORDS[4 * bars]} steps",
                   "does a little dance in place with bouncing knees", "grooves from side to side"]
    else:
        phrases = ["dances in place", "grooves to the music, bouncing {pos} knees and rolling {pos} arms",
                   "does a little dance on the spot, swaying {pos} hips",
                   f"dances in place for {NUMBER_WORDS[4 * bars]} beats", "bobs and sways to a beat"]
    return Action("dance", pose, phrases, params)


FAMILIES: tuple = (jumping_jacks, lunges, arm_circles, swim_strokes, dance)
WORDS: dict = {
    "ADJ": "big outstretched",
    "ADV": "apart overhead",
    "ADP": "for from",
    "DET": "each",
    "NOUN": {"beat": "beat", "beats": "beat", "breaststroke": "breaststroke",
             "circles": "circle", "feet": "foot", "freestyle": "freestyle", "hips": "hip", "jacks": "jack",
             "legs": "leg", "motion": "motion", "music": "music", "stroke": "stroke",
             "spot": "spot",
             "star": "star", "strokes": "stroke", "swimming": "swimming", "time": "time", "touch": "touch"},
    "VERB": {"bobs": "bob", "bounces": "bounce", "bouncing": "bounce", "grooves": "groove",
             "jumping": "jump", "mimes": "mime", "pretends": "pretend", "reaching": "reach",
             "rolling": "roll", "rotates": "rotate", "spreads": "spread", "stepping": "step", "sways": "sway",
             "swaying": "sway", "sweeping": "sweep", "swim": "swim", "swims": "swim", "swinging": "swing",
             "switching": "switch"},
    "NOUN_OR_VERB": {"dance": "dance", "dances": "dance", "lunge": "lunge", "lunges": "lunge"},
}
LAST_ONLY: tuple[str, ...] = ()
