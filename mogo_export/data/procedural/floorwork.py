"""Key poses on the floor, shared by the families that go down to it (transitions.py, falls.py): a leg by its world
angles (`legs_at`), where the parts that may touch the floor are in a one-frame pose (`floor_points`), solving a key
pose so that what must touch the floor together comes down level and what is pinned stays put (`fit_pose`), and the
channels of a body that sinks, sits and lies down (`BODY_KEYS`, `body_layers`, `down_keys`, `clutch_keys`).

Key poses are given by world angles of the legs and solved, because a chain of local angles chosen by hand puts a
knee and the toes behind it, or the seat and the heels, at different heights; the parts besides the feet that
carry the body are named with `Pose.rest_on`, so grounding puts the body on them.
"""
from __future__ import annotations

import numpy as np

from .action import TimeBudget
from .kinematics import body_points, contact_points, forward_kinematics
from .pose import CONTACTS, OTHER, SIDES, Pose, flat_foot



def legs_at(pose: Pose, side: str, thigh, shank, pitch, lift=0.0, abd=0.0, yaw=0.0, dorsi=0.0) -> None:
    """One leg by its world angles in the body's sagittal plane: the thigh `thigh` degrees forward of straight
    down, the shank `shank` degrees the other way (the knee ahead of the ankle), the foot flat on the floor
    under a root pitched `pitch` but for `lift` degrees of heel raise (and `dorsi` more toes-up)."""
    flex, knee = np.asarray(thigh) + pitch, np.asarray(thigh) + shank
    pose.leg(side, flex=flex, knee=knee, abd=abd, yaw=yaw,
             dorsi=flat_foot(pitch, flex, knee, lift) + np.asarray(dorsi))


def floor_points(build) -> dict[str, np.ndarray]:
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


def fit_pose(c: dict, build, channels: tuple[str, ...], residual, iters: int = 12) -> dict:
    """c with `channels` changed (Gauss-Newton, finite differences) so that residual(floor_points(...)) -> 0, or as
    near as the body reaches: the key poses whose contacts must meet the floor together, or stay where they
    were pinned."""
    c = dict(c)
    x = np.array([c[n] for n in channels], dtype=np.float64)

    def r(v):
        return np.asarray(residual(floor_points(lambda p: build(p, {**c, **dict(zip(channels, v))}))), np.float64)
    c.update(zip(channels, gauss_newton(r, x, iters, tol=1e-5, damping=1e-6).tolist()))
    return c


def gauss_newton(residual, x: np.ndarray, iters: int, tol: float, damping: float) -> np.ndarray:
    """x moved (degrees) until max |residual(x)| < tol or `iters` steps: finite-difference Jacobian (0.1 deg),
    damped (a pose at the end of its reach, a straight thigh, has no gradient), at most 20 degrees a step."""
    for _ in range(iters):
        r0 = residual(x)
        if np.abs(r0).max() < tol:
            break
        J = np.stack([(residual(x + 0.1 * e) - r0) / 0.1 for e in np.eye(len(x))], axis=1)
        step = np.linalg.solve(J.T @ J + damping * np.eye(len(x)), J.T @ r0)
        x = x - step * min(1.0, 20.0 / max(np.abs(step).max(), 1e-12))
    return x


def hold_within(budget: TimeBudget, hold: float, fixed: float, least: float) -> float:
    """The hold the budget leaves after `fixed` seconds of motion, at most `hold`, at least `least`."""
    return float(max(least, min(hold, budget.seconds - 0.05 - fixed)))



# channels: root pitch / roll (toward the hurt side), the hurt leg ("i") and the good one ("g") by world angles
# as `legs_at`, trunk bend, head nod / tilt, and each arm ("l", "r"): flexion, abduction, across, elbow
BODY_KEYS = dict(pitch=0, roll=0, ithigh=0, ishank=0, ilift=0, iabd=0, gthigh=0, gshank=0, glift=0, gabd=0,
             bend=2, nod=0, tilt=0, lflex=3, labd=4, lacross=0, lelbow=12, rflex=3, rabd=4, racross=0,
             relbow=12)
ARM_KEYS = ("flex", "abd", "across", "elbow")


def body_layers(pose: Pose, c: dict, side: str) -> None:
    """The collapse's layers from channel values c (arrays or numbers): the `side` leg is the hurt one."""
    sign = SIDES[side]["sign"]                       # roll > 0 tips the body toward the hurt side
    pitch = c["pitch"]
    pose.root(pitch=pitch, roll=sign * np.asarray(c["roll"]))
    for leg, who in ((side, "i"), (OTHER[side], "g")):
        legs_at(pose, leg, c[who + "thigh"], c[who + "shank"], pitch, lift=c[who + "lift"], abd=c[who + "abd"])
    pose.spine(bend=c["bend"])
    pose.head(nod=c["nod"], tilt=-sign * np.asarray(c["tilt"]))
    for arm in SIDES:
        a = arm[0]
        pose.arm(arm, flex=c[a + "flex"], abd=c[a + "abd"], across=c[a + "across"], elbow=c[a + "elbow"])


def body_joints(build) -> np.ndarray:
    """(22, 3) joint positions relative to the root of the one-frame pose `build(pose)` makes."""
    pose = Pose(1)
    build(pose)
    return forward_kinematics(pose.angles)[0][0]


def clutch_keys(c: dict, side: str, at: float = 0.3) -> dict:
    """c with both arms solved so the hands hold the hurt leg's shin `at` of the way from knee to ankle, one
    hand each side of it, a little in front."""
    knee, ankle = SIDES[side]["knee"], SIDES[side]["knee"] + 3
    arms = tuple(a + n for a in "lr" for n in ARM_KEYS)

    def residual(v):
        j = body_joints(lambda p: body_layers(p, {**c, **dict(zip(arms, v))}, side))
        grip = j[knee] + at * (j[ankle] - j[knee])
        lateral = np.cross(j[ankle] - j[knee], j[1] - j[2])     # forward of the shin
        lateral = lateral / max(np.linalg.norm(lateral), 1e-9)
        across = (j[1] - j[2]) / np.linalg.norm(j[1] - j[2])   # to the body's left
        return np.concatenate([j[20] - (grip + 0.05 * across + 0.04 * lateral),
                               j[21] - (grip - 0.05 * across + 0.04 * lateral)])
    x = gauss_newton(residual, np.array([c[n] for n in arms], dtype=np.float64), 40, tol=1e-4, damping=1e-3)
    return {**c, **dict(zip(arms, x.tolist()))}


def foot_at(q: dict, side: str) -> np.ndarray:
    """The lower of the `side` foot's heel and toe (the one on the floor)."""
    return min((q[f"{side}_heel"], q[f"{side}_toe"]), key=lambda v: v[1])


def down_keys(rng, c0: dict, side: str, build, clutched: bool) -> tuple[dict, dict, dict, dict]:
    """From a stance c0 (both feet on the floor where they are in c0): the pose half way to a squat over the
    feet, the squat, the seat down on the floor behind them (knees up), and lying on the back with the
    `OTHER[side]` foot where it was (knee up, sole on the floor) and the `side` leg drawn up toward the chest,
    off the floor; every key fit so the feet keep their places relative to each other and, once the seat is
    down, to it (nothing pinned slides). `clutched`: the hands hold the `side` shin throughout (else the arms
    are the caller's)."""
    o = OTHER[side]
    q0 = floor_points(lambda p: build(p, c0))
    gap = q0[f"{side}_toe"][2] - q0[f"{o}_toe"][2]                # the feet stay where they stand

    def fit(c, channels, res):
        out = fit_pose(c, build, channels, res)
        return clutch_keys(out, side, 0.25) if clutched else out
    squat = fit({**c0, "pitch": rng.uniform(28, 34), "bend": 18, "nod": 12, "ithigh": 80, "ishank": 32, "ilift": 0,
                 "gthigh": 84, "gshank": 35, "glift": 0, "iabd": 6, "gabd": 6}, ("ithigh", "ishank"),
                lambda q: [foot_at(q, side)[1] - foot_at(q, o)[1], q[f"{side}_toe"][2] - q[f"{o}_toe"][2] - gap])
    half = fit({n: 0.5 * (c0[n] + squat[n]) for n in c0}, ("ithigh", "ishank"),   # on the way: the same
               lambda q: [foot_at(q, side)[1] - foot_at(q, o)[1], q[f"{side}_toe"][2] - q[f"{o}_toe"][2] - gap])
    # the good foot stays put, the seat comes down level with it; the `side` leg is lifted off the floor, held
    seat = fit({**squat, "pitch": rng.uniform(6, 12), "bend": 12, "nod": 10, "ithigh": 118, "ishank": -55,
                "gthigh": 130, "gshank": -40, "iabd": 0, "gabd": 0},
               ("gshank", "ishank"), lambda q: [foot_at(q, o)[1] - q["pelvis"][1],
                                                min(q[f"{side}_heel"][1], q[f"{side}_toe"][1]) - q["pelvis"][1] - 0.06])
    qs = floor_points(lambda p: build(p, seat))
    toe = qs[f"{o}_toe"] - qs["pelvis"]                            # the good foot, from the seat

    def keep(c):  # the good foot flat where the seat left it, relative to the seat (it does not slide)
        return fit(c, ("gthigh", "gshank", "glift"),
                   lambda q: [q[f"{o}_toe"][2] - q["pelvis"][2] - toe[2], q[f"{o}_toe"][1] - q["pelvis"][1],
                              q[f"{o}_heel"][1] - q["pelvis"][1]])
    back = keep({**seat, "pitch": -82, "bend": 4, "nod": 38, "ithigh": 178, "ishank": -85, "ilift": -25,
                 "iabd": 6, "gthigh": 125, "gshank": -40})
    return half, squat, seat, back


