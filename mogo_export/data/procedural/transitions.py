"""Getting down toward or onto the floor: crouching low (and rising again), kneeling down on one knee or both,
sitting down on the ground, collapsing to the ground clutching a hurt leg (onto the seat, then back onto
the floor, the hurt knee held to the chest), falling down (backward onto the back, or forward onto the hands
and knees) and getting back up, and lying down flat on the back and getting back up.

Each is a family as action.py describes, `(rng, budget) -> Action`. Key poses are given by world angles of
the legs (`_legs`) and solved (`_fit`) so that what should touch the floor together (a knee and the toes
behind it, the seat and the heels, the hands) comes down level, and what is pinned stays where it landed;
the parts besides the feet that carry the body are named with `Pose.rest_on` (the Pose's `resting` track,
which cross-fades and holds carry), so grounding puts the body on them. FAMILIES lists this module's
families in their fixed order (families.py appends it to the registry); WORDS holds every caption word they
use that the shared lexicon (captions.py) lacks; LAST_ONLY names the families that do not end standing
(kneel_down, sit_on_ground, collapse_holding_leg).
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget, sample_speed
from .captions import adverb, how_often
from .curves import Keys, ease
from .kinematics import body_points, contact_points, forward_kinematics
from .pose import CONTACTS, OTHER, SIDES, Pose, flat_foot, seconds_to_frames


def _legs(pose: Pose, side: str, thigh, shank, pitch, lift=0.0, abd=0.0, yaw=0.0, dorsi=0.0) -> None:
    """One leg by its world angles in the body's sagittal plane: the thigh `thigh` degrees forward of straight
    down, the shank `shank` degrees the other way (the knee ahead of the ankle), the foot flat on the floor
    under a root pitched `pitch` but for `lift` degrees of heel raise (and `dorsi` more toes-up)."""
    flex, knee = np.asarray(thigh) + pitch, np.asarray(thigh) + shank
    pose.leg(side, flex=flex, knee=knee, abd=abd, yaw=yaw,
             dorsi=flat_foot(pitch, flex, knee, lift) + np.asarray(dorsi))


def _points(build) -> dict[str, np.ndarray]:
    """Where what may touch the floor is, relative to the root, in the one-frame pose `build(pose)` makes:
    each foot's heel and toe ("left_heel", ...) and every body part of pose.CONTACTS (its surface below)."""
    pose = Pose(1)
    build(pose)
    rel, glob = forward_kinematics(pose.angles)
    feet = contact_points(rel, glob)[0]
    body = body_points(rel, np.ones((1, len(CONTACTS)), bool))[0]
    out = dict(zip(CONTACTS, body))
    out.update(zip(("left_heel", "left_toe", "right_heel", "right_toe"), feet))
    return out


def _fit(c: dict, build, channels: tuple[str, ...], residual, iters: int = 12) -> dict:
    """c with `channels` changed (Gauss-Newton, finite differences) so that residual(_points(...)) -> 0, or as
    near as the body reaches: the key poses whose contacts must meet the floor together, or stay where they
    were pinned."""
    c = dict(c)
    x = np.array([c[n] for n in channels], dtype=np.float64)

    def r(v):
        return np.asarray(residual(_points(lambda p: build(p, {**c, **dict(zip(channels, v))}))), np.float64)
    for _ in range(iters):
        r0 = r(x)
        if np.abs(r0).max() < 1e-5:
            break
        J = np.stack([(r(x + 0.1 * e) - r0) / 0.1 for e in np.eye(len(x))], axis=1)
        # damped (a pose at the end of its reach, a straight thigh, has no gradient) and at most 20 degrees a step
        step = np.linalg.solve(J.T @ J + 1e-6 * np.eye(len(x)), J.T @ r0)
        x = x - step * min(1.0, 20.0 / max(np.abs(step).max(), 1e-12))
    c.update(zip(channels, x.tolist()))
    return c


def _fit_hold(budget: TimeBudget, hold: float, fixed: float, least: float) -> float:
    """The hold the budget leaves after `fixed` seconds of motion, at most `hold`, at least `least`."""
    return float(max(least, min(hold, budget.seconds - 0.05 - fixed)))


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
    hold = _fit_hold(budget, looks * per_look + rng.uniform(0.3, 0.8), lead_in + down + up + lead_out, 0.8)
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
        _legs(pose, side, d * thigh, d * shank, p, lift=d * lift, abd=d * 16)
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
               f"gets down into a crouch, holds it and stands up again"]
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
        _legs(pose, leg, c[who + "thigh"], c[who + "shank"], pitch, lift=c[who + "lift"], abd=c["abd"])
    pose.spine(bend=c["bend"])
    pose.head(nod=c["nod"])


def kneel_down(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    side = str(rng.choice(["left", "right"]))
    both = bool(rng.random() < 0.5)
    speed = str(rng.choice(["slow", "normal"]))
    step, lower = rng.uniform(0.5, 0.7), (1.4 if speed == "slow" else 0.9) * rng.uniform(0.9, 1.1)
    second = rng.uniform(0.8, 1.1) if both else 0.0
    lead_in = rng.uniform(0.3, 0.6)
    stay = _fit_hold(budget, rng.uniform(1.0, 3.0), lead_in + step + lower + second, 0.6)
    other = OTHER[side]
    bk, bt, ft, fh = f"{side}_knee", f"{side}_toe", f"{other}_toe", f"{other}_heel"

    def build(p, c):
        _kneel_layers(p, c, side)
    stand = dict(pitch=0, bend=2, nod=0, abd=0, bthigh=0, bshank=0, blift=0, fthigh=0, fshank=0, flift=0)
    # key poses, each solved so that what is on the floor is level and what is pinned stays where it landed.
    # The held kneel: the down knee under the hip, toes tucked under; the front shin near upright
    half = _fit({**stand, "pitch": rng.uniform(2, 6), "nod": 6, "abd": 5, "bthigh": -2, "bshank": 100,
                 "blift": 75, "fthigh": 88, "fshank": 18}, build, ("bshank", "fthigh"),
                lambda q: [q[bk][1] - q[ft][1], q[bt][1] - q[ft][1]])
    q = _points(lambda p: build(p, half))
    gap = q[bt][2] - q[ft][2]                                       # back toes behind the front foot
    # the kneeling leg swings back as the front knee bends, and its toes land where they will stay ...
    s_key = _fit({**stand, "fthigh": 62, "fshank": 14, "pitch": 4, "abd": 3, "bthigh": -30, "bshank": 60,
                  "blift": 55}, build, ("bthigh", "bshank"), lambda q: [q[bt][1] - q[ft][1], q[bt][2] - q[ft][2] - gap])
    # ... then the knee sinks to the floor, the toes pivoting under it
    m_key = _fit({**stand, "fthigh": 78, "fshank": 16, "pitch": 4, "abd": 4, "nod": 3, "bthigh": -15,
                  "bshank": 80, "blift": 65}, build, ("bthigh", "bshank"),
                 lambda q: [q[bt][1] - q[ft][1], q[bt][2] - q[ft][2] - gap])
    # both knees: the front foot lifts and its knee comes down beside the other, toes tucked too
    end = half if not both else _fit({**half, "fthigh": half["bthigh"], "fshank": half["bshank"], "flift": 75},
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
        _legs(pose, side, c["thigh"], -np.asarray(c["dir"]), pitch, lift=c["lift"], abd=c["abd"], dorsi=c["toes"])
    pose.spine(bend=c["bend"])
    pose.head(nod=c["nod"])
    for side in SIDES:  # arm_d: the left arm's flexion above the right's (the arms differ by a centimetre)
        pose.arm(side, flex=np.asarray(c["arm"]) + SIDES[side]["sign"] * 0.5 * np.asarray(c["arm_d"]),
                 abd=c["arm_abd"], elbow=c["elbow"])


_SEAT = dict(pitch=0, thigh=0, dir=0, lift=0, abd=0, toes=0, bend=2, nod=0, arm=3, arm_d=0, arm_abd=4, elbow=12)


def _seated(c: dict, channel: str, lo_part: str = "pelvis") -> dict:
    """c with `channel` solved so the heels come down level with `lo_part` (the seat, or the back)."""
    return _fit(c, _seat_layers, (channel,), lambda q: [_sole(q) - q[lo_part][1]])


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
    stay = _fit_hold(budget, rng.uniform(1.0, 3.0), lead_in + down + sit + settle, 0.6)
    squat, seat = _sit_keys(rng)
    if legs == "straight":  # legs stretched out in front, leaning back on both hands behind the hips
        end = _seated({**_SEAT, "pitch": rng.uniform(-22, -12), "thigh": 98, "dir": 88, "toes": -8,
                       "arm": -40, "arm_abd": 14, "elbow": 6, "nod": 10}, "dir")  # knees a little bent
        end = _fit(end, _seat_layers, ("arm", "arm_d"),
                   lambda q: [q["left_hand"][1] - q["pelvis"][1], q["right_hand"][1] - q["pelvis"][1]])
        # the feet lift as the legs stretch out (so they do not drag), the hands swing back with bent elbows
        mid = {**end, "thigh": 122, "dir": 78, "toes": 0, "pitch": 0.5 * (end["pitch"] + seat["pitch"]),
               "arm": -5, "arm_d": 0, "arm_abd": 14, "elbow": 75}
        # ... the legs reach out above the floor and set the heels down, the hands come down behind the hips
        late = {**end, "thigh": end["thigh"] + 6, "arm": end["arm"] - 4, "elbow": 45}
        rest = ["left_hand", "right_hand"]
    else:  # knees drawn up, both arms wrapped around the shins
        q = _points(lambda p: _seat_layers(p, seat))
        gap = q["left_heel"][2] - q["pelvis"][2]                  # the feet stay where the seat came down
        end = _fit({**seat, "pitch": rng.uniform(12, 20), "thigh": 138, "dir": 35, "arm": 50, "arm_abd": 6,
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


# --- collapse_holding_leg ---------------------------------------------------------------------------------

# channels: root pitch / roll (toward the hurt side), the hurt leg ("i") and the good one ("g") by world angles
# as `_legs`, trunk bend, head nod / tilt, and each arm ("l", "r"): flexion, abduction, across, elbow
_FALL = dict(pitch=0, roll=0, ithigh=0, ishank=0, ilift=0, iabd=0, gthigh=0, gshank=0, glift=0, gabd=0,
             bend=2, nod=0, tilt=0, lflex=3, labd=4, lacross=0, lelbow=12, rflex=3, rabd=4, racross=0,
             relbow=12)
_ARM = ("flex", "abd", "across", "elbow")


def _fall_layers(pose: Pose, c: dict, side: str) -> None:
    """The collapse's layers from channel values c (arrays or numbers): the `side` leg is the hurt one."""
    sign = SIDES[side]["sign"]                       # roll > 0 tips the body toward the hurt side
    pitch = c["pitch"]
    pose.root(pitch=pitch, roll=sign * np.asarray(c["roll"]))
    for leg, who in ((side, "i"), (OTHER[side], "g")):
        _legs(pose, leg, c[who + "thigh"], c[who + "shank"], pitch, lift=c[who + "lift"], abd=c[who + "abd"])
    pose.spine(bend=c["bend"])
    pose.head(nod=c["nod"], tilt=-sign * np.asarray(c["tilt"]))
    for arm in SIDES:
        a = arm[0]
        pose.arm(arm, flex=c[a + "flex"], abd=c[a + "abd"], across=c[a + "across"], elbow=c[a + "elbow"])


def _joints(build) -> np.ndarray:
    """(22, 3) joint positions relative to the root of the one-frame pose `build(pose)` makes."""
    pose = Pose(1)
    build(pose)
    return forward_kinematics(pose.angles)[0][0]


def _clutch(c: dict, side: str, at: float = 0.3) -> dict:
    """c with both arms solved so the hands hold the hurt leg's shin `at` of the way from knee to ankle, one
    hand each side of it, a little in front."""
    knee, ankle = SIDES[side]["knee"], SIDES[side]["knee"] + 3
    arms = tuple(a + n for a in "lr" for n in _ARM)

    def residual(v):
        j = _joints(lambda p: _fall_layers(p, {**c, **dict(zip(arms, v))}, side))
        grip = j[knee] + at * (j[ankle] - j[knee])
        lateral = np.cross(j[ankle] - j[knee], j[1] - j[2])     # forward of the shin
        lateral = lateral / max(np.linalg.norm(lateral), 1e-9)
        across = (j[1] - j[2]) / np.linalg.norm(j[1] - j[2])   # to the body's left
        return np.concatenate([j[20] - (grip + 0.05 * across + 0.04 * lateral),
                               j[21] - (grip - 0.05 * across + 0.04 * lateral)])
    x = np.array([c[n] for n in arms], dtype=np.float64)
    for _ in range(40):
        r0 = residual(x)
        if np.abs(r0).max() < 1e-4:
            break
        J = np.stack([(residual(x + 0.1 * e) - r0) / 0.1 for e in np.eye(len(x))], axis=1)
        step = np.linalg.solve(J.T @ J + 1e-3 * np.eye(len(x)), J.T @ r0)
        x = x - step * min(1.0, 20.0 / max(np.abs(step).max(), 1e-12))
    return {**c, **dict(zip(arms, x.tolist()))}


def _foot(q: dict, side: str) -> np.ndarray:
    """The lower of the `side` foot's heel and toe (the one on the floor)."""
    return min((q[f"{side}_heel"], q[f"{side}_toe"]), key=lambda v: v[1])


def _down_keys(rng, c0: dict, side: str, build, clutched: bool) -> tuple[dict, dict, dict, dict]:
    """From a stance c0 (both feet on the floor where they are in c0): the pose half way to a squat over the
    feet, the squat, the seat down on the floor behind them (knees up), and lying on the back with the
    `OTHER[side]` foot where it was (knee up, sole on the floor) and the `side` leg drawn up toward the chest,
    off the floor; every key fit so the feet keep their places relative to each other and, once the seat is
    down, to it (nothing pinned slides). `clutched`: the hands hold the `side` shin throughout (else the arms
    are the caller's)."""
    o = OTHER[side]
    q0 = _points(lambda p: build(p, c0))
    gap = q0[f"{side}_toe"][2] - q0[f"{o}_toe"][2]                # the feet stay where they stand

    def fit(c, channels, res):
        out = _fit(c, build, channels, res)
        return _clutch(out, side, 0.25) if clutched else out
    squat = fit({**c0, "pitch": rng.uniform(28, 34), "bend": 18, "nod": 12, "ithigh": 80, "ishank": 32, "ilift": 0,
                 "gthigh": 84, "gshank": 35, "glift": 0, "iabd": 6, "gabd": 6}, ("ithigh", "ishank"),
                lambda q: [_foot(q, side)[1] - _foot(q, o)[1], q[f"{side}_toe"][2] - q[f"{o}_toe"][2] - gap])
    half = fit({n: 0.5 * (c0[n] + squat[n]) for n in c0}, ("ithigh", "ishank"),   # on the way: the same
               lambda q: [_foot(q, side)[1] - _foot(q, o)[1], q[f"{side}_toe"][2] - q[f"{o}_toe"][2] - gap])
    # the good foot stays put, the seat comes down level with it; the `side` leg is lifted off the floor, held
    seat = fit({**squat, "pitch": rng.uniform(6, 12), "bend": 12, "nod": 10, "ithigh": 118, "ishank": -55,
                "gthigh": 130, "gshank": -40, "iabd": 0, "gabd": 0},
               ("gshank", "ishank"), lambda q: [_foot(q, o)[1] - q["pelvis"][1],
                                                min(q[f"{side}_heel"][1], q[f"{side}_toe"][1]) - q["pelvis"][1] - 0.06])
    qs = _points(lambda p: build(p, seat))
    toe = qs[f"{o}_toe"] - qs["pelvis"]                            # the good foot, from the seat

    def keep(c):  # the good foot flat where the seat left it, relative to the seat (it does not slide)
        return fit(c, ("gthigh", "gshank", "glift"),
                   lambda q: [q[f"{o}_toe"][2] - q["pelvis"][2] - toe[2], q[f"{o}_toe"][1] - q["pelvis"][1],
                              q[f"{o}_heel"][1] - q["pelvis"][1]])
    back = keep({**seat, "pitch": -82, "bend": 4, "nod": 38, "ithigh": 178, "ishank": -85, "ilift": -25,
                 "iabd": 6, "gthigh": 125, "gshank": -40})
    return half, squat, seat, back


def collapse_holding_leg(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Clutches the hurt `side` leg with both hands standing on the other, sets it down for one hobbling step,
    buckles into a squat and drops onto the seat, then falls back onto the floor, the hurt knee drawn up and
    held, the other foot flat on the floor. Ends lying on the back (LAST_ONLY)."""
    side = str(rng.choice(["left", "right"]))
    lead_in, grab = rng.uniform(0.3, 0.6), rng.uniform(0.35, 0.5)
    clutch = rng.uniform(0.5, 0.9)                       # standing on the good leg, the hurt one held up
    limp = rng.uniform(0.45, 0.6)                        # the hurt foot set down ahead ... and it gives way
    sink, drop, fall = rng.uniform(0.55, 0.75), rng.uniform(0.35, 0.5), rng.uniform(0.7, 1.0)
    fixed = lead_in + grab + clutch + limp + sink + drop + fall
    # a short budget (the first action of a pair) squeezes the motion, never past a 5 s budget's worth
    squeeze = min(1.0, (budget.seconds - 0.05 - 0.6) / fixed)
    lead_in, grab, clutch, limp, sink, drop, fall = (x * squeeze for x in (lead_in, grab, clutch, limp, sink,
                                                                           drop, fall))
    stay = _fit_hold(budget, rng.uniform(1.0, 2.5), fixed * squeeze, 0.6)

    def build(p, c):
        _fall_layers(p, c, side)
    # bent over the hurt leg, its knee lifted high, both hands holding the shin just below the knee
    hold = _clutch({**_FALL, "pitch": rng.uniform(20, 24), "bend": 40, "nod": 18, "ithigh": 65, "ishank": 50,
                    "ilift": -10, "gthigh": 4, "gshank": 8, "iabd": 3}, side, 0.1)
    # the hurt foot comes down ahead, level with the other
    step = _fit({**hold, "pitch": 10, "bend": 24, "ithigh": 24, "ishank": 6, "ilift": 0, "gthigh": -4, "gshank": 6},
                build, ("ishank", "gshank"), lambda q: [_foot(q, side)[1] - _foot(q, OTHER[side])[1]])
    step = _clutch(step, side, 0.1)
    half, squat, seat, back = _down_keys(rng, step, side, build, True)
    k = Keys(**_FALL)
    t = lead_in
    k.add(t, **_FALL)
    k.add(t + grab, **hold)
    lifted = (t + 0.05, t + grab + clutch + 0.6 * limp)
    leg_up = t + grab + clutch + limp + 0.6 * sink           # ... and the hurt leg gives way: it comes off the floor
    t += grab
    k.add(t + clutch, **hold)
    t += clutch
    k.add(t + limp, "stop", **step)
    t += limp
    k.add(t + 0.5 * sink, **half)
    k.add(t + sink, **squat)
    t += sink
    k.add(t + drop, "stop", **seat)
    t += drop
    seated = t - 0.1 * drop
    k.add(t + fall, "stop", **back)
    t += fall
    pose = Pose(seconds_to_frames(t + stay))
    tt = pose.t
    c = {n: k(n, tt) for n in _FALL}
    c["nod"] = c["nod"] + 3.0 * np.sin(2 * np.pi * (tt - t) / rng.uniform(1.2, 2.0)) * ease((tt - t) / 0.4)
    _fall_layers(pose, c, side)
    i = 0 if side == "left" else 1
    pose.support[((tt > lifted[0]) & (tt < lifted[1])) | (tt > leg_up), i] = False
    pose.rest_on("pelvis", tt > seated)
    pose.rest_on(["lower_back", "mid_back", "upper_back", "head"], tt > t - 0.5 * fall)
    phrases = [f"holds {{pos}} injured {side} leg and collapses to the ground",
               f"clutches the {side} leg and falls down in pain",
               f"grabs {{pos}} hurt {side} leg and sinks to the ground",
               f"hurts {{pos}} {side} leg, hobbles a step and collapses onto {{pos}} back",
               f"clutches {{pos}} {side} knee and falls to the floor holding it"]
    return Action("collapse_holding_leg", pose, phrases, dict(side=side, stay=round(stay, 2)))


# --- fall_and_get_up ----------------------------------------------------------------------------------------


def _arms(c: dict, flex, abd, elbow, across=0.0) -> dict:
    """c with both arms (the `_FALL` arm channels) set alike."""
    return {**c, **{a + n: v for a in "lr" for n, v in zip(_ARM, (flex, abd, across, elbow))}}


def _feet_kept(c: dict, build, q0: dict, side: str) -> dict:
    """c (`_FALL` channels, `side` the "i" leg) with both legs' thigh / shank / lift / abduction solved so each
    foot is flat on the floor level with the seat, its toes where they are from the seat in the one-frame
    points q0 (ahead, and to the side): keys the seat and feet carry together, so nothing pinned slides."""
    def res(q):
        return [v for s in (side, OTHER[side]) for v in (
            q[f"{s}_toe"][2] - q["pelvis"][2] - (q0[f"{s}_toe"][2] - q0["pelvis"][2]),
            q[f"{s}_toe"][0] - q["pelvis"][0] - (q0[f"{s}_toe"][0] - q0["pelvis"][0]),
            q[f"{s}_toe"][1] - q["pelvis"][1], q[f"{s}_heel"][1] - q["pelvis"][1])]
    return _fit(c, build, ("ithigh", "ishank", "ilift", "iabd", "gthigh", "gshank", "glift", "gabd"), res)


def _lying(c: dict, build) -> dict:
    """c with both arms' flexion and the nod solved so the hands and the back of the head rest on the floor
    (level with the seat)."""
    return _fit(c, build, ("lflex", "rflex", "nod"), lambda q: [q["left_hand"][1] - q["pelvis"][1],
                                                               q["right_hand"][1] - q["pelvis"][1],
                                                               q["head"][1] - q["pelvis"][1]])


def _fall_back_keys(rng, side: str, build) -> dict:
    """The backward fall's key poses, each fit so the feet keep their places (relative to each other while
    standing, and to the seat once it is down): a knee buckle, a squat over the heels, the seat down hard
    behind the feet (knees up), and lying on the back, both feet flat on the floor, knees up."""
    o = OTHER[side]
    legs = ("ithigh", "ishank", "gthigh", "gshank")

    def level(c, channels=("ishank", "gshank")):  # both feet flat and level, the toes as far apart as standing
        return _fit(c, build, channels, lambda q: [_foot(q, side)[1] - _foot(q, o)[1],
                                                    q[f"{side}_toe"][2] - q[f"{o}_toe"][2]])
    buckle = level(_arms({**_FALL, "pitch": rng.uniform(12, 18), "bend": 8, "nod": 10, "ithigh": 50, "ishank": 30,
                          "gthigh": 50, "gshank": 30, "iabd": 4, "gabd": 4}, 55, 20, 20))
    squat = level(_arms({**_FALL, "pitch": rng.uniform(10, 15), "bend": 12, "nod": 16, "ithigh": 88, "ishank": 20,
                         "gthigh": 88, "gshank": 20, "iabd": 6, "gabd": 6}, 70, 25, 20))
    # the seat down behind the heels, level with them, the trunk upright, arms thrown forward
    seat = _fit(_arms({**squat, "pitch": rng.uniform(0, 6), "bend": 10, "nod": 20, "ithigh": 125, "ishank": -40,
                       "gthigh": 125, "gshank": -40}, 75, 30, 15), build, ("ishank", "gshank"),
                lambda q: [_foot(q, side)[1] - q["pelvis"][1], _foot(q, o)[1] - q["pelvis"][1]])
    qs = _points(lambda p: build(p, seat))

    def keep(c):  # both feet flat where the seat left them, relative to it
        return _feet_kept(c, build, qs, side)
    # flat on the back, the knees up; the arms out on the floor beside the body, the back of the head on it
    back = keep(_arms({**seat, "pitch": -86, "bend": -6, "nod": -28, "ithigh": 130, "ishank": -45,
                       "gthigh": 130, "gshank": -45}, 0, rng.uniform(30, 50), 15))
    back = _lying(back, build)
    situp = keep(_arms({**seat, "pitch": rng.uniform(22, 28), "bend": 18, "nod": 14}, 85, 15, 15))
    # half way between the keys the feet would lift off the floor (the hips swing about the seat): fit there too
    rolling = keep({n: 0.5 * (seat[n] + back[n]) for n in seat})
    sitting = keep({n: 0.5 * (back[n] + situp[n]) for n in seat})
    return dict(buckle=buckle, squat=squat, seat=seat, rolling=rolling, back=back, sitting=sitting, situp=situp)


def _fall_forward_keys(rng, side: str, build) -> dict:
    """The forward fall's key poses (`side`: the leg that kneels last, the other steps up first): the knees
    buckling forward over the feet, both knees down on the floor (toes tucked under, where they stood), on
    the hands and knees, kneeling up on both knees, on the `side` knee with the other foot flat in front,
    and the two rising poses of kneel_down's way down, each fit so what is on the floor is level and what is
    pinned stays where it is."""
    o = OTHER[side]
    ik, it, gk, gt = f"{side}_knee", f"{side}_toe", f"{o}_knee", f"{o}_toe"
    buckle = _fit(_arms({**_FALL, "pitch": rng.uniform(18, 24), "bend": 10, "nod": -5, "ithigh": 40, "ishank": 50,
                         "gthigh": 40, "gshank": 50, "iabd": 4, "gabd": 4}, 50, 12, 15), build, ("ishank", "gshank"),
                  lambda q: [_foot(q, side)[1] - _foot(q, o)[1], q[it][2] - q[gt][2]])
    # both knees down, the toes tucked under where they stood, leaning forward with the arms reaching down
    knees = _fit(_arms({**_FALL, "pitch": rng.uniform(38, 45), "bend": 12, "nod": -10, "ithigh": 12, "ishank": 95,
                        "ilift": 70, "gthigh": 12, "gshank": 95, "glift": 70, "iabd": 5, "gabd": 5}, 75, 14, 10),
                 build, ("ishank", "gshank", "ilift", "glift"),
                 lambda q: [q[ik][1] - q[it][1], q[gk][1] - q[gt][1], q[it][1] - q[gt][1], q[it][2] - q[gt][2]])
    q = _points(lambda p: build(p, knees))
    # on the hands and knees: the trunk near level, the hands flat on the floor under the shoulders
    fours = _fit(_arms({**knees, "pitch": rng.uniform(70, 76), "bend": 6, "nod": -35, "ithigh": 4, "gthigh": 4},
                       70, 10, 8), build, ("ishank", "gshank", "lflex", "rflex"),
                 lambda q2: [q2[ik][1] - q2[it][1], q2[gk][1] - q2[gt][1], q2["left_hand"][1] - q2[it][1],
                             q2["right_hand"][1] - q2[it][1]])
    upright = _fit(_arms({**knees, "pitch": rng.uniform(2, 6), "bend": 4, "nod": 4, "ithigh": -2, "gthigh": -2},
                         10, 8, 25), build, ("ishank", "gshank"),
                   lambda q2: [q2[ik][1] - q2[it][1], q2[gk][1] - q2[gt][1]])
    # the other foot comes forward, flat in front, the knee up (kneel_down's one-knee pose)
    half = _fit({**upright, "pitch": rng.uniform(2, 6), "nod": 6, "gthigh": 88, "gshank": 18, "glift": 0},
                build, ("gthigh",), lambda q2: [q2[ik][1] - q2[gt][1]])
    half = _arms(half, 3, 6, 12)
    half = {**half, "racross" if o == "right" else "lacross": 8,
            ("r" if o == "right" else "l") + "flex": 55, ("r" if o == "right" else "l") + "elbow": 45}
    qh = _points(lambda p: build(p, half))
    gap = qh[it][2] - qh[gt][2]                                      # kneeling toes behind the front foot
    # rising: the knee comes off the floor as the front knee straightens, the toes pivoting where they are ...
    lift = _fit({**half, "gthigh": 78, "gshank": 16, "pitch": 4, "nod": 3, "ithigh": -15, "ishank": 80,
                 "ilift": 65}, build, ("ithigh", "ishank"),
                lambda q2: [q2[it][1] - q2[gt][1], q2[it][2] - q2[gt][2] - gap])
    # ... until it stands on the front foot with the back leg stretched behind, toes on the floor
    stride = _fit({**half, "gthigh": 62, "gshank": 14, "pitch": 4, "nod": 0, "ithigh": -30, "ishank": 60,
                   "ilift": 55, "gabd": 3, "iabd": 3}, build, ("ithigh", "ishank"),
                  lambda q2: [q2[it][1] - q2[gt][1], q2[it][2] - q2[gt][2] - gap])
    return dict(buckle=buckle, knees=knees, fours=fours, upright=upright, half=half, lift=lift, stride=stride)


def _fall_forward(rng, budget: TimeBudget, side: str, build) -> tuple[Pose, float]:
    """Falls forward onto the knees and hands, stays there briefly, kneels up, steps the other foot forward
    and stands up through the one-knee pose (kneel_down's way down, backward). Returns the pose and the stay."""
    keys = _fall_forward_keys(rng, side, build)
    lead_in, buckle, drop, catch = (rng.uniform(0.3, 0.6), rng.uniform(0.22, 0.28), rng.uniform(0.22, 0.28),
                                    rng.uniform(0.15, 0.2))
    push, step, rise, swing, lead_out = (rng.uniform(0.6, 0.8), rng.uniform(0.7, 0.9), rng.uniform(0.9, 1.1),
                                         rng.uniform(0.55, 0.7), rng.uniform(0.3, 0.5))
    moves = [lead_in, buckle, drop, catch, push, step, rise, swing, lead_out]
    squeeze = min(1.0, (budget.seconds - 0.05 - 0.4) / sum(moves))
    lead_in, buckle, drop, catch, push, step, rise, swing, lead_out = (x * squeeze for x in moves)
    stay = _fit_hold(budget, rng.uniform(0.4, 1.2), sum(moves) * squeeze, 0.4)
    k = Keys(**_FALL)
    t = lead_in
    k.add(t, **_FALL)
    k.add(t + buckle, **keys["buckle"])
    t += buckle
    k.add(t + drop, "stop", **keys["knees"])
    t += drop
    on_knees = t - 0.1 * drop
    k.add(t + catch, "stop", **keys["fours"])
    t += catch
    on_hands = (t - 0.3 * catch, t + stay + 0.2 * push)
    k.add(t + stay, **keys["fours"])
    t += stay
    k.add(t + push, **keys["upright"])
    t += push
    o = OTHER[side]
    half = keys["half"]
    # the other foot comes up off the floor and forward, and sets down flat (kneel_down's second knee, backward)
    k.add(t + 0.35 * step, gthigh=40, gshank=90, glift=60)
    k.add(t + 0.7 * step, gthigh=half["gthigh"] + 4, gshank=35, glift=20)
    k.add(t + step, "stop", **half)
    g_up = (t + 0.1 * step, t + 0.9 * step)
    knee_up = t + 0.35 * step
    t += step
    k.add(t + 0.5 * rise, **keys["lift"])
    k.add(t + rise, **keys["stride"])
    knee_off = t + 0.2 * rise
    t += rise
    # the back foot swings forward beside the front one as the body straightens over the front foot, and
    # sets down only once that leg is straight (it lands where it stands)
    k.add(t + 0.35 * swing, ithigh=-12, ishank=65, ilift=25, gthigh=36, gshank=10, pitch=3)
    k.add(t + 0.7 * swing, ithigh=14, ishank=26, ilift=-5, gthigh=6, gshank=3, pitch=1)
    k.add(t + swing, **_FALL)
    i_up = (t + 0.05, t + swing - 0.05)
    t += swing
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    c = {n: k(n, tt) for n in _FALL}
    _fall_layers(pose, c, side)
    i, g = (0, 1) if side == "left" else (1, 0)
    pose.support[(tt > i_up[0]) & (tt < i_up[1]), i] = False
    pose.support[(tt > g_up[0]) & (tt < g_up[1]), g] = False
    pose.rest_on(f"{side}_knee", (tt > on_knees) & (tt < knee_off))
    pose.rest_on(f"{o}_knee", (tt > on_knees) & (tt < knee_up))       # pinned until it lifts off the floor
    pose.rest_on(["left_hand", "right_hand"], (tt > on_hands[0]) & (tt < on_hands[1]))
    return pose, stay


def fall_and_get_up(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Falls and gets back up (`way`): backward, the knees buckle and the seat drops hard behind the feet,
    the body rolls onto the back (knees up, feet where they stood, arms out on the floor), lies there 0.5-2 s,
    sits up, rocks forward over the feet and stands; forward, the knees buckle forward onto the floor and the
    hands catch the body (on the hands and knees 0.4-1.2 s), then it kneels up, brings one foot forward and
    stands up through the one-knee pose. Ends standing."""
    way = str(rng.choice(["backward", "forward"]))
    side = str(rng.choice(["left", "right"]))           # the leg that moves first (not captioned)

    def build(p, c):
        _fall_layers(p, c, side)
    if way == "backward":
        keys = _fall_back_keys(rng, side, build)
        lead_in, buckle, drop, roll = (rng.uniform(0.3, 0.6), rng.uniform(0.25, 0.3), rng.uniform(0.5, 0.6),
                                       rng.uniform(0.4, 0.55))
        sit, rock, rise, lead_out = (rng.uniform(0.7, 0.9), rng.uniform(0.6, 0.8), rng.uniform(0.8, 1.0),
                                     rng.uniform(0.3, 0.5))
        moves = [lead_in, buckle, drop, roll, sit, rock, rise, lead_out]
        squeeze = min(1.0, (budget.seconds - 0.05 - 0.5) / sum(moves))
        lead_in, buckle, drop, roll, sit, rock, rise, lead_out = (x * squeeze for x in moves)
        lie = _fit_hold(budget, rng.uniform(0.5, 2.0), sum(moves) * squeeze, 0.5)
        k = Keys(**_FALL)
        t = lead_in
        k.add(t, **_FALL)
        k.add(t + buckle, **keys["buckle"])
        k.add(t + buckle + 0.5 * drop, **keys["squat"])
        t += buckle + drop
        k.add(t, "stop", **keys["seat"])
        seated = t - 0.1 * drop
        k.add(t + 0.5 * roll, **keys["rolling"])
        k.add(t + roll, "stop", **keys["back"])
        t += roll
        on_back = (t - 0.5 * roll, t + lie + 0.4 * sit)
        k.add(t + lie, **keys["back"])
        t += lie
        k.add(t + 0.5 * sit, **keys["sitting"])
        k.add(t + sit, **keys["situp"])
        t += sit
        k.add(t + rock, **keys["squat"])
        up = t + 0.3 * rock
        t += rock
        k.add(t + rise, **_FALL)
        t += rise
        pose = Pose(seconds_to_frames(t + lead_out))
        tt = pose.t
        c = {n: k(n, tt) for n in _FALL}
        _fall_layers(pose, c, side)
        pose.rest_on("pelvis", (tt > seated) & (tt < up))
        pose.rest_on(["lower_back", "mid_back", "upper_back", "head", "left_hand", "right_hand"],
                     (tt > on_back[0]) & (tt < on_back[1]))
        phrases = ["falls down and gets back up", "falls on {pos} back and gets up again",
                   "loses {pos} balance, lands on {pos} back and stands up",
                   "falls over backward, lies on the ground for a moment and then gets up",
                   "falls down backward and gets back up",
                   "sits down hard, falls back onto the floor and gets back on {pos} feet"]
        return Action("fall_and_get_up", pose, phrases, dict(way=way, lie=round(lie, 2)))
    pose, stay = _fall_forward(rng, budget, side, build)
    phrases = ["falls forward onto {pos} hands and knees and gets back up",
               "falls down forward, catches {pos} fall with {pos} hands and stands up again",
               "goes down forward onto {pos} hands and knees, stays there a moment, then stands up",
               "falls to {pos} knees, catches {pos} fall with {pos} hands and gets back on {pos} feet",
               "falls down and gets back up"]
    return Action("fall_and_get_up", pose, phrases, dict(way=way, stay=round(stay, 2)))


# --- lie_down_and_get_up ----------------------------------------------------------------------------------


def _lie_keys(rng, side: str, build) -> dict:
    """Lying down and getting up's key poses: a squat over the feet, the seat down behind them (knees up),
    lying back with the knees still up, the legs lifted on their way out, lying flat (legs along the floor,
    toes up, arms at the sides, head down), and the sit-up on the way back; the knees-up keys fit so the feet
    keep their places relative to the seat, the lying ones so heels, hands and head rest on the floor."""
    o = OTHER[side]
    squat = _fit(_arms({**_FALL, "pitch": rng.uniform(30, 36), "bend": 14, "nod": 10, "ithigh": 85, "ishank": 35,
                        "gthigh": 85, "gshank": 35, "iabd": 6, "gabd": 6}, 45, 10, 25), build, ("ishank", "gshank"),
                 lambda q: [_foot(q, side)[1] - _foot(q, o)[1], q[f"{side}_toe"][2] - q[f"{o}_toe"][2]])
    seat = _fit(_arms({**squat, "pitch": rng.uniform(6, 12), "bend": 10, "nod": 4, "ithigh": 130, "ishank": -40,
                       "gthigh": 130, "gshank": -40, "iabd": 3, "gabd": 3}, 35, 12, 30), build, ("ishank", "gshank"),
                lambda q: [_foot(q, side)[1] - q["pelvis"][1], _foot(q, o)[1] - q["pelvis"][1]])
    qs = _points(lambda p: build(p, seat))
    arms = rng.uniform(8, 16)                                        # how far the arms lie from the sides
    back = _lying(_feet_kept(_arms({**seat, "pitch": -86, "bend": -6, "nod": -28}, 0, arms, 10), build, qs, side),
                  build)
    # between the seat and the back the feet would rise off the floor (the hips swing about the seat): fit there
    leaning = [_feet_kept({n: (1 - f) * seat[n] + f * back[n] for n in seat}, build, qs, side)
               for f in (0.25, 0.5, 0.75)]

    def above(c, h):  # c with the thighs solved so both feet are h above the floor (the seat on it)
        return _fit(c, build, ("ithigh", "gthigh"), lambda q: [_foot(q, side)[1] - q["pelvis"][1] - h,
                                                                _foot(q, o)[1] - q["pelvis"][1] - h])
    # flat: both legs along the floor (knees a little bent), toes up, the heels just on it: 6 mm up, so that
    # grounding never pins them (a pinned heel that moves is held by leg IK, which has no good knee
    # direction for a leg lying along the floor)
    flat = _fit({**back, "ithigh": 94, "ishank": -86, "ilift": -55, "gthigh": 94, "gshank": -86, "glift": -55},
                build, ("ishank", "gshank"), lambda q: [q[f"{side}_heel"][1] - q["pelvis"][1] - 0.006,
                                                        q[f"{o}_heel"][1] - q["pelvis"][1] - 0.006])
    # on the way out (or in) the feet ride above the floor so they do not drag, and the heels set down (or
    # lift) with the legs already stretched out: each leg turns about its hip as one piece (a heel pinned on
    # the floor does not move along it before it lifts)
    sliding = above({n: 0.5 * (back[n] + flat[n]) for n in back}, 0.07)
    qb = _points(lambda p: build(p, back))
    lifted = _fit(back, build, ("ithigh", "ishank", "gthigh", "gshank"),   # the soles straight up off the floor
                  lambda q: [v for s in (side, o) for v in (q[f"{s}_heel"][2] - qb[f"{s}_heel"][2],
                                                             _foot(q, s)[1] - q["pelvis"][1] - 0.03)])
    reaching = {**flat, **{n: flat[n] + d for n, d in (("ithigh", 5), ("ishank", -5), ("gthigh", 5),
                                                        ("gshank", -5))}}
    situp = _feet_kept(_arms({**seat, "pitch": rng.uniform(24, 30), "bend": 18, "nod": 12}, 80, 12, 15),
                       build, qs, side)
    sitting = [_feet_kept({n: (1 - f) * back[n] + f * situp[n] for n in seat}, build, qs, side)
               for f in (0.25, 0.5, 0.75)]
    return dict(squat=squat, seat=seat, leaning=leaning, back=back, lifted=lifted, sliding=sliding,
                reaching=reaching, flat=flat,
                sitting=sitting, situp=situp)


def lie_down_and_get_up(rng, budget: TimeBudget = FULL_BUDGET) -> Action:
    """Squats, sits down on the floor, lies back and stretches the legs out flat, lies there 1-3 s, then
    draws the knees up, sits up, rocks forward over the feet and stands up. Ends standing."""
    speed = str(rng.choice(["slow", "normal"]))
    side = str(rng.choice(["left", "right"]))            # the legs differ by a centimetre (not captioned)

    def build(p, c):
        _fall_layers(p, c, side)
    keys = _lie_keys(rng, side, build)
    f = (1.3 if speed == "slow" else 1.0) * rng.uniform(0.9, 1.1)
    lead_in, lead_out = rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.5)
    # (the legs stretch out slowly enough that the feet's floor corrections, blended away over 0.4 s after they
    # lift, are gone before the legs are straight: leg IK has no good knee direction for a leg along the floor)
    down, sit, back, out, draw, up, rock, rise = (x * f for x in (1.0, 0.8, 0.7, 1.0, 0.7, 0.7, 0.6, 0.8))
    # a short budget squeezes all but the legs stretching out (see above), never past a 5 s budget's worth
    moves = [lead_in, down, sit, back, draw, up, rock, rise, lead_out]
    squeeze = min(1.0, (budget.seconds - 0.05 - 1.0 - out) / sum(moves))
    lead_in, down, sit, back, draw, up, rock, rise, lead_out = (x * squeeze for x in moves)
    stay = _fit_hold(budget, rng.uniform(1.0, 3.0), sum(moves) * squeeze + out, 1.0)
    if squeeze < 0.85:  # squeezed this much it is no slow motion any more
        speed = "normal"
    k = Keys(**_FALL)
    t = lead_in
    k.add(t, **_FALL)
    k.add(t + down, **keys["squat"])
    t += down
    k.add(t + sit, **keys["seat"])
    seated = t + 0.8 * sit
    t += sit
    for f, key in zip((0.25, 0.5, 0.75), keys["leaning"]):
        k.add(t + f * back, **key)
    k.add(t + back, **keys["back"])
    on_back = t + 0.6 * back
    t += back
    k.add(t + 0.12 * out, **keys["lifted"])
    k.add(t + 0.5 * out, **keys["sliding"])
    k.add(t + 0.85 * out, **keys["reaching"])
    k.add(t + out, **keys["flat"])
    sliding_out = (t + 0.05 * out, t + 0.95 * out)
    t += out
    flat = t
    k.add(t + stay, **keys["flat"])
    t += stay
    k.add(t + 0.2 * draw, **keys["reaching"])
    k.add(t + 0.55 * draw, **keys["sliding"])
    k.add(t + 0.85 * draw, **keys["lifted"])
    k.add(t + draw, **keys["back"])
    sliding_in = (t + 0.05 * draw, t + 0.95 * draw)
    t += draw
    for f, key in zip((0.25, 0.5, 0.75), keys["sitting"]):
        k.add(t + f * up, **key)
    k.add(t + up, **keys["situp"])
    off_back = t + 0.4 * up
    t += up
    k.add(t + rock, **keys["squat"])
    lifts = t + 0.3 * rock
    t += rock
    k.add(t + rise, **_FALL)
    t += rise
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    c = {n: k(n, tt) for n in _FALL}
    # breathing while lying flat: the chest rises and falls (a little spine bend), the head rocks with it
    breathe = np.sin(2 * np.pi * (tt - flat) / rng.uniform(3.0, 4.0)) * ease((tt - flat) / 0.5) * (tt < t - rise
                                                                                                 - rock - up - draw)
    c["nod"] = c["nod"] + 1.5 * breathe
    _fall_layers(pose, c, side)
    pose.support[(tt > sliding_out[0]) & (tt < sliding_in[1])] = False
    pose.rest_on("pelvis", (tt > seated) & (tt < lifts))
    pose.rest_on(["lower_back", "mid_back", "upper_back", "head", "left_hand", "right_hand"],
                 (tt > on_back) & (tt < off_back))
    phrases = [f"lies down on the floor{adverb(speed)} and gets back up",
               "sits down, lies flat on {pos} back for a moment and then stands up again",
               f"lies down on {{pos}} back{adverb(speed)}, rests there and gets up",
               "gets down on the ground, lies on {pos} back with {pos} legs stretched out and stands back up",
               "lies down flat on the ground, then sits up and stands"]
    return Action("lie_down_and_get_up", pose, phrases, dict(speed=speed, stay=round(stay, 2)))


FAMILIES: tuple = (crouch, kneel_down, sit_on_ground, collapse_holding_leg, fall_and_get_up, lie_down_and_get_up)
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
LAST_ONLY: tuple[str, ...] = ("kneel_down", "sit_on_ground", "collapse_holding_leg")
