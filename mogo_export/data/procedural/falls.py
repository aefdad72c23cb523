"""Going down onto the floor and, but for the collapse, getting back up: collapsing to the ground clutching a hurt leg
(onto the seat, then back onto the floor, the hurt knee held to the chest), falling down (backward onto the back,
or forward onto the hands and knees) and getting back up, and lying down flat on the back and getting back up.

Each is a family as action.py describes, `(rng, budget) -> Action`, its key poses solved with floorwork.py.
FAMILIES lists this module's families in their fixed order (families.py appends it to the registry right after
transitions.py's); their caption words are in transitions.WORDS; LAST_ONLY: collapse_holding_leg ends on the floor.
"""
from __future__ import annotations

import numpy as np

from .action import FULL_BUDGET, Action, TimeBudget
from .captions import adverb
from .curves import Keys, ease
from .floorwork import (ARM_KEYS, BODY_KEYS, body_layers, clutch_keys, down_keys, fit_pose, floor_points, foot_at,
                        hold_within)
from .pose import OTHER, Pose, seconds_to_frames


# --- collapse_holding_leg ---------------------------------------------------------------------------------


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
    stay = hold_within(budget, rng.uniform(1.0, 2.5), fixed * squeeze, 0.6)

    def build(p, c):
        body_layers(p, c, side)
    # bent over the hurt leg, its knee lifted high, both hands holding the shin just below the knee
    hold = clutch_keys({**BODY_KEYS, "pitch": rng.uniform(20, 24), "bend": 40, "nod": 18, "ithigh": 65, "ishank": 50,
                    "ilift": -10, "gthigh": 4, "gshank": 8, "iabd": 3}, side, 0.1)
    # the hurt foot comes down ahead, level with the other
    step = fit_pose({**hold, "pitch": 10, "bend": 24, "ithigh": 24, "ishank": 6, "ilift": 0, "gthigh": -4, "gshank": 6},
                build, ("ishank", "gshank"), lambda q: [foot_at(q, side)[1] - foot_at(q, OTHER[side])[1]])
    step = clutch_keys(step, side, 0.1)
    half, squat, seat, back = down_keys(rng, step, side, build, True)
    k = Keys(**BODY_KEYS)
    t = lead_in
    k.add(t, **BODY_KEYS)
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
    c = {n: k(n, tt) for n in BODY_KEYS}
    c["nod"] = c["nod"] + 3.0 * np.sin(2 * np.pi * (tt - t) / rng.uniform(1.2, 2.0)) * ease((tt - t) / 0.4)
    body_layers(pose, c, side)
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
    """c with both arms (the `BODY_KEYS` arm channels) set alike."""
    return {**c, **{a + n: v for a in "lr" for n, v in zip(ARM_KEYS, (flex, abd, across, elbow))}}


def _feet_kept(c: dict, build, q0: dict, side: str) -> dict:
    """c (`BODY_KEYS` channels, `side` the "i" leg) with both legs' thigh / shank / lift / abduction solved so each
    foot is flat on the floor level with the seat, its toes where they are from the seat in the one-frame
    points q0 (ahead, and to the side): keys the seat and feet carry together, so nothing pinned slides."""
    def res(q):
        return [v for s in (side, OTHER[side]) for v in (
            q[f"{s}_toe"][2] - q["pelvis"][2] - (q0[f"{s}_toe"][2] - q0["pelvis"][2]),
            q[f"{s}_toe"][0] - q["pelvis"][0] - (q0[f"{s}_toe"][0] - q0["pelvis"][0]),
            q[f"{s}_toe"][1] - q["pelvis"][1], q[f"{s}_heel"][1] - q["pelvis"][1])]
    return fit_pose(c, build, ("ithigh", "ishank", "ilift", "iabd", "gthigh", "gshank", "glift", "gabd"), res)


def _lying(c: dict, build) -> dict:
    """c with both arms' flexion and the nod solved so the hands and the back of the head rest on the floor
    (level with the seat)."""
    return fit_pose(c, build, ("lflex", "rflex", "nod"), lambda q: [q["left_hand"][1] - q["pelvis"][1],
                                                               q["right_hand"][1] - q["pelvis"][1],
                                                               q["head"][1] - q["pelvis"][1]])


def _fall_back_keys(rng, side: str, build) -> dict:
    """The backward fall's key poses, each fit so the feet keep their places (relative to each other while
    standing, and to the seat once it is down): a knee buckle, a squat over the heels, the seat down hard
    behind the feet (knees up), and lying on the back, both feet flat on the floor, knees up."""
    o = OTHER[side]

    def level(c, channels=("ishank", "gshank")):  # both feet flat and level, the toes as far apart as standing
        return fit_pose(c, build, channels, lambda q: [foot_at(q, side)[1] - foot_at(q, o)[1],
                                                    q[f"{side}_toe"][2] - q[f"{o}_toe"][2]])
    buckle = level(_arms({**BODY_KEYS, "pitch": rng.uniform(12, 18), "bend": 8, "nod": 10, "ithigh": 50, "ishank": 30,
                          "gthigh": 50, "gshank": 30, "iabd": 4, "gabd": 4}, 55, 20, 20))
    squat = level(_arms({**BODY_KEYS, "pitch": rng.uniform(10, 15), "bend": 12, "nod": 16, "ithigh": 88, "ishank": 20,
                         "gthigh": 88, "gshank": 20, "iabd": 6, "gabd": 6}, 70, 25, 20))
    # the seat down behind the heels, level with them, the trunk upright, arms thrown forward
    seat = fit_pose(_arms({**squat, "pitch": rng.uniform(0, 6), "bend": 10, "nod": 20, "ithigh": 125, "ishank": -40,
                       "gthigh": 125, "gshank": -40}, 75, 30, 15), build, ("ishank", "gshank"),
                lambda q: [foot_at(q, side)[1] - q["pelvis"][1], foot_at(q, o)[1] - q["pelvis"][1]])
    qs = floor_points(lambda p: build(p, seat))

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
    buckle = fit_pose(_arms({**BODY_KEYS, "pitch": rng.uniform(18, 24), "bend": 10, "nod": -5, "ithigh": 40, "ishank": 50,
                         "gthigh": 40, "gshank": 50, "iabd": 4, "gabd": 4}, 50, 12, 15), build, ("ishank", "gshank"),
                  lambda q: [foot_at(q, side)[1] - foot_at(q, o)[1], q[it][2] - q[gt][2]])
    # both knees down, the toes tucked under where they stood, leaning forward with the arms reaching down
    knees = fit_pose(_arms({**BODY_KEYS, "pitch": rng.uniform(38, 45), "bend": 12, "nod": -10, "ithigh": 12, "ishank": 95,
                        "ilift": 70, "gthigh": 12, "gshank": 95, "glift": 70, "iabd": 5, "gabd": 5}, 75, 14, 10),
                 build, ("ishank", "gshank", "ilift", "glift"),
                 lambda q: [q[ik][1] - q[it][1], q[gk][1] - q[gt][1], q[it][1] - q[gt][1], q[it][2] - q[gt][2]])
    # on the hands and knees: the trunk near level, the hands flat on the floor under the shoulders
    fours = fit_pose(_arms({**knees, "pitch": rng.uniform(70, 76), "bend": 6, "nod": -35, "ithigh": 4, "gthigh": 4},
                       70, 10, 8), build, ("ishank", "gshank", "lflex", "rflex"),
                 lambda q2: [q2[ik][1] - q2[it][1], q2[gk][1] - q2[gt][1], q2["left_hand"][1] - q2[it][1],
                             q2["right_hand"][1] - q2[it][1]])
    upright = fit_pose(_arms({**knees, "pitch": rng.uniform(2, 6), "bend": 4, "nod": 4, "ithigh": -2, "gthigh": -2},
                         10, 8, 25), build, ("ishank", "gshank"),
                   lambda q2: [q2[ik][1] - q2[it][1], q2[gk][1] - q2[gt][1]])
    # the other foot comes forward, flat in front, the knee up (kneel_down's one-knee pose)
    half = fit_pose({**upright, "pitch": rng.uniform(2, 6), "nod": 6, "gthigh": 88, "gshank": 18, "glift": 0},
                build, ("gthigh",), lambda q2: [q2[ik][1] - q2[gt][1]])
    half = _arms(half, 3, 6, 12)
    half = {**half, "racross" if o == "right" else "lacross": 8,
            ("r" if o == "right" else "l") + "flex": 55, ("r" if o == "right" else "l") + "elbow": 45}
    qh = floor_points(lambda p: build(p, half))
    gap = qh[it][2] - qh[gt][2]                                      # kneeling toes behind the front foot
    # rising: the knee comes off the floor as the front knee straightens, the toes pivoting where they are ...
    lift = fit_pose({**half, "gthigh": 78, "gshank": 16, "pitch": 4, "nod": 3, "ithigh": -15, "ishank": 80,
                 "ilift": 65}, build, ("ithigh", "ishank"),
                lambda q2: [q2[it][1] - q2[gt][1], q2[it][2] - q2[gt][2] - gap])
    # ... until it stands on the front foot with the back leg stretched behind, toes on the floor
    stride = fit_pose({**half, "gthigh": 62, "gshank": 14, "pitch": 4, "nod": 0, "ithigh": -30, "ishank": 60,
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
    stay = hold_within(budget, rng.uniform(0.4, 1.2), sum(moves) * squeeze, 0.4)
    k = Keys(**BODY_KEYS)
    t = lead_in
    k.add(t, **BODY_KEYS)
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
    k.add(t + swing, **BODY_KEYS)
    i_up = (t + 0.05, t + swing - 0.05)
    t += swing
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    c = {n: k(n, tt) for n in BODY_KEYS}
    body_layers(pose, c, side)
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
        body_layers(p, c, side)
    if way == "backward":
        keys = _fall_back_keys(rng, side, build)
        lead_in, buckle, drop, roll = (rng.uniform(0.3, 0.6), rng.uniform(0.25, 0.3), rng.uniform(0.5, 0.6),
                                       rng.uniform(0.4, 0.55))
        sit, rock, rise, lead_out = (rng.uniform(0.7, 0.9), rng.uniform(0.6, 0.8), rng.uniform(0.8, 1.0),
                                     rng.uniform(0.3, 0.5))
        moves = [lead_in, buckle, drop, roll, sit, rock, rise, lead_out]
        squeeze = min(1.0, (budget.seconds - 0.05 - 0.5) / sum(moves))
        lead_in, buckle, drop, roll, sit, rock, rise, lead_out = (x * squeeze for x in moves)
        lie = hold_within(budget, rng.uniform(0.5, 2.0), sum(moves) * squeeze, 0.5)
        k = Keys(**BODY_KEYS)
        t = lead_in
        k.add(t, **BODY_KEYS)
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
        k.add(t + rise, **BODY_KEYS)
        t += rise
        pose = Pose(seconds_to_frames(t + lead_out))
        tt = pose.t
        c = {n: k(n, tt) for n in BODY_KEYS}
        body_layers(pose, c, side)
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
    squat = fit_pose(_arms({**BODY_KEYS, "pitch": rng.uniform(30, 36), "bend": 14, "nod": 10, "ithigh": 85, "ishank": 35,
                        "gthigh": 85, "gshank": 35, "iabd": 6, "gabd": 6}, 45, 10, 25), build, ("ishank", "gshank"),
                 lambda q: [foot_at(q, side)[1] - foot_at(q, o)[1], q[f"{side}_toe"][2] - q[f"{o}_toe"][2]])
    seat = fit_pose(_arms({**squat, "pitch": rng.uniform(6, 12), "bend": 10, "nod": 4, "ithigh": 130, "ishank": -40,
                       "gthigh": 130, "gshank": -40, "iabd": 3, "gabd": 3}, 35, 12, 30), build, ("ishank", "gshank"),
                lambda q: [foot_at(q, side)[1] - q["pelvis"][1], foot_at(q, o)[1] - q["pelvis"][1]])
    qs = floor_points(lambda p: build(p, seat))
    arms = rng.uniform(8, 16)                                        # how far the arms lie from the sides
    back = _lying(_feet_kept(_arms({**seat, "pitch": -86, "bend": -6, "nod": -28}, 0, arms, 10), build, qs, side),
                  build)
    # between the seat and the back the feet would rise off the floor (the hips swing about the seat): fit there
    leaning = [_feet_kept({n: (1 - f) * seat[n] + f * back[n] for n in seat}, build, qs, side)
               for f in (0.25, 0.5, 0.75)]

    def above(c, h):  # c with the thighs solved so both feet are h above the floor (the seat on it)
        return fit_pose(c, build, ("ithigh", "gthigh"), lambda q: [foot_at(q, side)[1] - q["pelvis"][1] - h,
                                                                foot_at(q, o)[1] - q["pelvis"][1] - h])
    # flat: both legs along the floor (knees a little bent), toes up, the heels just on it: 6 mm up, so that
    # grounding never pins them (a pinned heel that moves is held by leg IK, which has no good knee
    # direction for a leg lying along the floor)
    flat = fit_pose({**back, "ithigh": 94, "ishank": -86, "ilift": -55, "gthigh": 94, "gshank": -86, "glift": -55},
                build, ("ishank", "gshank"), lambda q: [q[f"{side}_heel"][1] - q["pelvis"][1] - 0.006,
                                                        q[f"{o}_heel"][1] - q["pelvis"][1] - 0.006])
    # on the way out (or in) the feet ride above the floor so they do not drag, and the heels set down (or
    # lift) with the legs already stretched out: each leg turns about its hip as one piece (a heel pinned on
    # the floor does not move along it before it lifts)
    sliding = above({n: 0.5 * (back[n] + flat[n]) for n in back}, 0.07)
    qb = floor_points(lambda p: build(p, back))
    lifted = fit_pose(back, build, ("ithigh", "ishank", "gthigh", "gshank"),   # the soles straight up off the floor
                  lambda q: [v for s in (side, o) for v in (q[f"{s}_heel"][2] - qb[f"{s}_heel"][2],
                                                             foot_at(q, s)[1] - q["pelvis"][1] - 0.03)])
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
        body_layers(p, c, side)
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
    stay = hold_within(budget, rng.uniform(1.0, 3.0), sum(moves) * squeeze + out, 1.0)
    if squeeze < 0.85:  # squeezed this much it is no slow motion any more
        speed = "normal"
    k = Keys(**BODY_KEYS)
    t = lead_in
    k.add(t, **BODY_KEYS)
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
    k.add(t + rise, **BODY_KEYS)
    t += rise
    pose = Pose(seconds_to_frames(t + lead_out))
    tt = pose.t
    c = {n: k(n, tt) for n in BODY_KEYS}
    # breathing while lying flat: the chest rises and falls (a little spine bend), the head rocks with it
    breathe = np.sin(2 * np.pi * (tt - flat) / rng.uniform(3.0, 4.0)) * ease((tt - flat) / 0.5) * (tt < t - rise
                                                                                                 - rock - up - draw)
    c["nod"] = c["nod"] + 1.5 * breathe
    body_layers(pose, c, side)
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




FAMILIES: tuple = (collapse_holding_leg, fall_and_get_up, lie_down_and_get_up)
WORDS: dict = {}   # in transitions.WORDS
LAST_ONLY: tuple[str, ...] = ("collapse_holding_leg",)
