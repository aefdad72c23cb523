"""A procedural HumanML3D-layout dataset: forward kinematics of keyframed actions, captions, and the writer.

Pipeline per clip: actions.py gives joint-angle tracks -> `forward_kinematics` on the HUMANML3D skeleton
(root at the origin) -> `solve_ground` places the root so heels and toes that land on the floor stay
where they landed, and the lowest one is on y=0 -> `lock_feet` takes up what the pose leaves over with
leg IK -> joints (T, 22, 3) -> `extract_features` (T-1, 263). `build_dataset` writes the HumanML3D
folder layout; see its docstring for every file. Same seed -> byte-identical files.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import shutil
import time
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mogo_runtime.features import FeatureLayout
from mogo_runtime.skeleton import HUMANML3D

from . import actions as A
from .humanml3d import canonicalize, extract_features

GENERATOR_VERSION = 1
SPLITS = (("train", 0.80), ("val", 0.15), ("test", 0.05))

FPS = A.FPS

# ---------------------------------------------------------------------------------------- kinematics


def _rot(axis: int, deg: np.ndarray) -> np.ndarray:
    """(...,) degrees -> (..., 3, 3) rotation about x (0), y (1) or z (2)."""
    r = np.radians(deg)
    c, s = np.cos(r), np.sin(r)
    m = np.zeros(np.shape(deg) + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[..., axis, axis] = 1.0
    m[..., i, i] = c
    m[..., j, j] = c
    m[..., i, j] = -s
    m[..., j, i] = s
    return m


def _foot_pitches(skeleton=HUMANML3D, left_deg: float = 20.0) -> dict[int, float]:
    """Standing pitch of each ankle -> toe bone (degrees down). The measured legs differ by ~1 cm, so the
    shorter leg's foot points down a little more and both toes touch the floor when standing straight."""
    drop = {}
    for ankle, toe in (skeleton.foot_left, skeleton.foot_right):
        knee = skeleton.parents[ankle]
        drop[ankle] = skeleton.bone_lengths[knee] + skeleton.bone_lengths[ankle]  # hip -> ankle, straight
    (la, lt), (ra, rt) = skeleton.foot_left, skeleton.foot_right
    toe_y = drop[la] + skeleton.bone_lengths[lt] * np.sin(np.radians(left_deg))
    return {la: left_deg, ra: float(np.degrees(np.arcsin((toe_y - drop[ra]) / skeleton.bone_lengths[rt])))}


FOOT_PITCH = _foot_pitches()


def _posture() -> np.ndarray:
    """Constant rotations turning the raw-offset rest pose (arms hanging from 13 cm below the collar ends,
    head in front of the neck, feet flat) into a standing person's posture, matched by eye to the
    HumanML3D fixture clip: shoulders up and out from the collar ends (about 18 cm beside the spine and
    12 cm below the neck), head above and slightly in front of the neck, toes below the ankles."""
    p = np.tile(np.eye(3), (HUMANML3D.num_joints, 1, 1))
    for collar, shoulder, sign in ((13, 16, 1.0), (14, 17, -1.0)):
        p[collar] = _rot(2, sign * 160.0)  # collar -> shoulder bone points up and out, like the trapezius
        p[shoulder] = _rot(2, -sign * 160.0)  # undo it for the arm, which hangs down again
    p[12] = _rot(0, -57.0)                  # neck -> head bone points up and slightly forward
    for ankle, deg in FOOT_PITCH.items():
        p[ankle] = _rot(0, deg)             # ankle -> toe bone points forward and down
    return p


POSTURE = _posture()


def _heel(ankle: int, toe: int, skeleton=HUMANML3D) -> np.ndarray:
    """A virtual heel 4.5 cm behind the ankle, level with the toe when standing (in the ankle's frame)."""
    down = skeleton.bone_lengths[toe] * np.sin(np.radians(FOOT_PITCH[ankle]))
    return _rot(0, -FOOT_PITCH[ankle]) @ np.array([0.0, -down, -0.045])


HEELS = {ankle: _heel(ankle, toe) for ankle, toe in (HUMANML3D.foot_left, HUMANML3D.foot_right)}


def local_rotations(angles: np.ndarray) -> np.ndarray:
    """(T, J, 3) degrees (actions.Pose convention) -> (T, J, 3, 3) local joint rotations."""
    x, y, z = angles[..., 0], angles[..., 1], angles[..., 2]
    rot = POSTURE @ _rot(2, z) @ _rot(0, x) @ _rot(1, y)
    rot[:, 0] = _rot(1, y[:, 0]) @ _rot(0, x[:, 0]) @ _rot(2, -z[:, 0])  # root: yaw, pitch, roll
    return rot


def forward_kinematics(angles: np.ndarray, skeleton=HUMANML3D) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions (T, J, 3) with the root at the origin, and global rotations (T, J, 3, 3).

    Joint j's rotation turns the bones to its children: pos[c] = pos[j] + G[j] @ offset[c]. Bone lengths
    are the skeleton's by construction.
    """
    local = local_rotations(angles)
    offsets = skeleton.offsets
    T, J = angles.shape[:2]
    glob = np.empty((T, J, 3, 3))
    pos = np.zeros((T, J, 3))
    for j, parent in enumerate(skeleton.parents):  # parents come before children in HumanML3D order
        if parent < 0:
            glob[:, j] = local[:, j]
            continue
        glob[:, j] = glob[:, parent] @ local[:, j]
        pos[:, j] = pos[:, parent] + glob[:, parent] @ offsets[j]
    return pos, glob


def contact_points(pos: np.ndarray, glob: np.ndarray, skeleton=HUMANML3D) -> np.ndarray:
    """(T, 4, 3): left heel, left toe, right heel, right toe (the heels are virtual, below the ankles)."""
    pts = []
    for ankle, toe in (skeleton.foot_left, skeleton.foot_right):
        pts.append(pos[:, ankle] + glob[:, ankle] @ HEELS[ankle])
        pts.append(pos[:, toe])
    return np.stack(pts, axis=1)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in a 1-D bool array."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


TOUCH = 0.02    # m: a pinned heel or toe stays pinned until it rises above this
LAND = 0.01     # m: a heel or toe this low on a supporting foot gets pinned where it is
GRAZE = 0.004   # m: ... and so does any heel or toe this low, support or not (a landing foot)


def _root_heights(points: np.ndarray, flight: np.ndarray) -> np.ndarray:
    """Root y: the lowest contact point on the floor; in the air a ballistic arc from take-off to landing."""
    T = len(points)
    ground = -points[..., 1].min(axis=1)
    y = ground.copy()
    for a, b in _runs(flight):
        a, b = max(a, 1), min(b, T - 1)  # keep a grounded frame on each side
        if b <= a:
            continue
        dur = (b - a + 1) / FPS
        s = np.arange(1, b - a + 1) / FPS
        base = np.interp(np.arange(a, b), [a - 1, b], [ground[a - 1], ground[b]])
        y[a:b] = np.maximum(base + 0.5 * A.GRAVITY * s * (dur - s), ground[a:b])
    return y


def solve_ground(points: np.ndarray, support: np.ndarray, flight: np.ndarray, air_speed: np.ndarray,
                 yaw_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Root translation (T, 3), per-foot floor corrections (T, 2, 3) and whether each foot is pinned
    (T, 2), for contact points (T, 4, 3) given relative to the root (heel, toe of left then right foot).

    Every heel or toe that comes down on the floor (on a foot the action marks as support, or grazing
    it) is pinned where it lands, and stays pinned until it rises above TOUCH. Each frame the root is
    placed where the pinned points, given the pose, best keep their pins (least squares; newly pinned
    and lifting points, and those of feet the action no longer marks as support, weigh less, so
    hand-overs between feet do not jerk the body). Whatever a foot still misses its pins by is its
    correction, which `lock_feet` applies with leg IK and blends away once the foot lifts. With nothing
    pinned the root keeps its velocity; in the air (`flight`) it follows a ballistic arc and moves at
    `air_speed` m/s along the heading where that is set.
    """
    T = len(points)
    root = np.zeros((T, 3))
    root[:, 1] = _root_heights(points, flight)
    xz = points[..., [0, 2]].tolist()                       # (T, 4, 2) as lists: the loop is per frame
    height = (points[..., 1] + root[:, 1:2]).tolist()
    sup = support.tolist()
    air = flight.tolist()
    yaw = np.radians(yaw_deg)
    air_vel = (np.stack([np.sin(yaw), np.cos(yaw)], -1) * (air_speed / FPS)[:, None]).tolist()
    pin = [None] * 4                                        # [x, z, frames pinned] per point
    corr = np.zeros((T, 2, 3))
    pinned = np.zeros((T, 2), dtype=bool)
    rx = rz = vx = vz = 0.0
    for t in range(T):
        h = height[t]
        for p in range(4):
            if pin[p] is not None and (h[p] > TOUCH or air[t]):
                pin[p] = None
        # root from the points pinned so far; weights grow over a pin's first frames and shrink as it lifts
        sw = sx = sz = 0.0
        for p in range(4):
            if pin[p] is not None:
                w = min(1.0, (pin[p][2] + 1) / 4.0) * max(0.05, 1.0 - h[p] / TOUCH)
                if not sup[t][p // 2]:  # a foot the action is lifting is held down, not leant on
                    w *= 0.02
                sw += w
                sx += w * (pin[p][0] - xz[t][p][0])
                sz += w * (pin[p][1] - xz[t][p][1])
        if air[t] and air_vel[t] != [0.0, 0.0]:
            vx, vz = air_vel[t]
            nx, nz = rx + vx, rz + vz
        elif sw > 0:
            nx, nz = sx / sw, sz / sw
        else:  # nothing on the floor: keep going as before (e.g. the feet of a running stride)
            nx, nz = rx + vx, rz + vz
        if t > 0:
            vx, vz = nx - rx, nz - rz
        rx, rz = nx, nz
        root[t, 0], root[t, 2] = rx, rz
        # pin what just came down, where it is now
        for p in range(4):
            if pin[p] is None and not air[t] and (h[p] < GRAZE or (sup[t][p // 2] and h[p] < LAND)):
                pin[p] = [rx + xz[t][p][0], rz + xz[t][p][1], 0]
            elif pin[p] is not None:
                pin[p][2] += 1
        for f in range(2):  # a foot's correction: the mean miss of its pinned points
            missed = [(pin[p][0] - rx - xz[t][p][0], pin[p][1] - rz - xz[t][p][1])
                      for p in (2 * f, 2 * f + 1) if pin[p] is not None]
            if missed:
                pinned[t, f] = True
                corr[t, f, 0] = sum(m[0] for m in missed) / len(missed)
                corr[t, f, 2] = sum(m[1] for m in missed) / len(missed)
    return root, corr, pinned


def two_bone_ik(hip: np.ndarray, knee: np.ndarray, target: np.ndarray, l1: float, l2: float,
                forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """New (knee, ankle) (N, 3) reaching `target` from `hip` with bone lengths l1, l2, bending in the plane
    of the old knee, toward `forward` (the foot's direction) when the leg is near straight, so a knee
    never flips backwards. Out-of-reach targets are approached as far as the straight leg allows."""
    axis = target - hip
    d = np.linalg.norm(axis, axis=-1, keepdims=True)
    u = axis / np.maximum(d, 1e-9)
    d = np.clip(d, abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    pole = (knee - hip) + 0.05 * forward / np.maximum(np.linalg.norm(forward, axis=-1, keepdims=True), 1e-9)
    pole = pole - (pole * u).sum(-1, keepdims=True) * u
    pole = pole / np.maximum(np.linalg.norm(pole, axis=-1, keepdims=True), 1e-9)
    a = (l1 * l1 - l2 * l2 + d * d) / (2 * d)
    r = np.sqrt(np.maximum(l1 * l1 - a * a, 0.0))
    return hip + a * u + r * pole, hip + d * u


def lock_feet(joints: np.ndarray, corr: np.ndarray, pinned: np.ndarray, skeleton=HUMANML3D,
              blend_s: float = 0.4) -> np.ndarray:
    """Move each foot by its floor correction (T, 2, 3) while pinned (T, 2), re-solving the leg with
    two-bone IK (hip fixed, foot translated, so bone lengths are unchanged). The correction a foot lifts
    off with is blended away over the swing (at most `blend_s` seconds), so it rejoins its kinematic
    path smoothly."""
    out = joints.copy()
    T = len(joints)
    for f, (ankle, toe) in enumerate((skeleton.foot_left, skeleton.foot_right)):
        c = np.where(pinned[:, f, None], corr[:, f], 0.0)
        runs = _runs(pinned[:, f])
        for i, (a, b) in enumerate(runs):
            end = min(runs[i + 1][0] if i + 1 < len(runs) else T, b + int(blend_s * FPS))
            if end > b:
                w = A.ease((np.arange(b, end) - b + 1) / (end - b + 1))[:, None]
                c[b:end] = c[b - 1] * (1 - w)
        fix = np.flatnonzero(np.abs(c).sum(-1) > 1e-7)
        if len(fix) == 0:
            continue
        knee = skeleton.parents[ankle]
        hip = skeleton.parents[knee]
        new_knee, new_ankle = two_bone_ik(joints[fix, hip], joints[fix, knee], joints[fix, ankle] + c[fix],
                                          float(skeleton.bone_lengths[knee]), float(skeleton.bone_lengths[ankle]),
                                          forward=joints[fix, toe] - joints[fix, ankle])
        out[fix, knee] = new_knee
        out[fix, toe] = joints[fix, toe] + (new_ankle - joints[fix, ankle])
        out[fix, ankle] = new_ankle
    return out


def pose_to_joints(pose: "A.Pose") -> np.ndarray:
    """(T, 22, 3) world joint positions (metres, y up) for an actions.Pose."""
    rel, glob = forward_kinematics(pose.angles)
    root, corr, pinned = solve_ground(contact_points(rel, glob), pose.support, pose.flight, pose.air_speed,
                                      pose.angles[:, 0, 1])
    return lock_feet(rel + root[:, None, :], corr, pinned)


# ----------------------------------------------------------------------------------------------- clips

BLEND_FRAMES = 10  # 0.5 s cross-fade between the two actions of a sequence
SEQUENCE_EVERY = 5  # every 5th clip (index % 5 == 4) is a two-action sequence
NOT_FIRST = ("sit_down",)  # ends seated: cannot hand over to a standing action in 0.5 s


def blend(a: "A.Pose", b: "A.Pose", frames: int = BLEND_FRAMES) -> "A.Pose":
    """`a` then `b`, cross-fading joint angles over `frames` frames; b keeps the heading a ends with.

    Root velocity is not a track here: it follows from the feet (solve_ground), so cross-fading the legs'
    angles cross-fades it too.
    """
    n = min(frames, a.T - 1, b.T - 1)
    b_angles = b.angles.copy()
    b_angles[:, 0, 1] += a.angles[-1, 0, 1] - b.angles[0, 0, 1]
    w = A.ease((np.arange(n) + 1.0) / (n + 1))
    out = A.Pose(a.T + b.T - n)
    mid = (1 - w)[:, None, None] * a.angles[a.T - n:] + w[:, None, None] * b_angles[:n]
    out.angles = np.concatenate([a.angles[:a.T - n], mid, b_angles[n:]])
    out.flight = np.concatenate([a.flight[:a.T - n], a.flight[a.T - n:] | b.flight[:n], b.flight[n:]])
    out.air_speed = np.concatenate([a.air_speed[:a.T - n], np.maximum(a.air_speed[a.T - n:], b.air_speed[:n]),
                                    b.air_speed[n:]])
    out.support = np.concatenate([a.support[:a.T - n], a.support[a.T - n:] | b.support[:n], b.support[n:]])
    return out


def family_plan(num_clips: int, seed: int) -> list[tuple[str, ...]]:
    """Which families each clip shows: singles cycle through every family in a shuffled order (so any
    SEQUENCE_EVERY * 21 / (SEQUENCE_EVERY - 1) consecutive clips cover them all); every SEQUENCE_EVERY-th
    clip is a pair of two different families."""
    names = list(A.FAMILIES)
    plan, singles, order = [], 0, []
    for i in range(num_clips):
        if i % SEQUENCE_EVERY == SEQUENCE_EVERY - 1:
            rng = np.random.default_rng([seed, i, 1])
            first = str(rng.choice([f for f in names if f not in NOT_FIRST]))
            plan.append((first, str(rng.choice([f for f in names if f != first]))))
            continue
        if singles % len(names) == 0:
            order = list(np.random.default_rng([seed, singles // len(names), 2]).permutation(names))
        plan.append((str(order[singles % len(names)]),))
        singles += 1
    return plan


def label_for(families: tuple[str, ...]) -> str:
    """`walk_forward` for a single action, `seq:walk_forward+jump_in_place` for a sequence (in order)."""
    return families[0] if len(families) == 1 else "seq:" + "+".join(families)


def generate_clip(families: tuple[str, ...], rng: np.random.Generator) -> tuple[np.ndarray, list[str]]:
    """World joints (T, 22, 3) and 3-4 captions for one clip of one action or a two-action sequence."""
    heading = rng.uniform(-180.0, 180.0)
    max_frames = int(round(A.MAX_SECONDS * FPS))
    if len(families) == 1:
        action = A.FAMILIES[families[0]](rng)
        pose, captions = action.pose, _captions([action.phrases], rng)
    else:
        for _ in range(20):  # redraw until both fit in MAX_SECONDS (rarely needed)
            with A.time_budget(A.MAX_SECONDS - A.MIN_SECONDS + BLEND_FRAMES / FPS):
                first = A.FAMILIES[families[0]](rng)
            with A.time_budget(A.MAX_SECONDS + BLEND_FRAMES / FPS - first.pose.T / FPS):
                second = A.FAMILIES[families[1]](rng)
            pose = blend(first.pose, second.pose)
            if pose.T <= max_frames:
                break
        captions = _captions([first.phrases, second.phrases], rng)
    pose.angles[:, 0, 1] += heading
    joints = pose_to_joints(pose)[:max_frames]
    return joints, captions


# -------------------------------------------------------------------------------------------- captions

SUBJECTS = (("a person", "their"), ("a man", "his"), ("a woman", "her"), ("someone", "their"),
            ("the person", "their"), ("a human", "their"), ("the man", "his"), ("this person", "their"))
SEQUENCE_TEMPLATES = ("{s} {a} and then {b}", "{s} {a}, then {b}", "{s} first {a} and then {b}",
                      "{s} {a} and after that {b}", "{s} {a}, and afterwards {b}")


def _captions(phrase_sets: list[list[str]], rng: np.random.Generator) -> list[str]:
    """3 or 4 differently worded captions: distinct phrasings, each with a sampled subject."""
    n = int(rng.integers(3, 5))
    picks = [rng.permutation(len(p)) for p in phrase_sets]
    out: list[str] = []
    for i in range(n):
        subject, pos = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
        parts = [p[int(k[i % len(k)])].replace("{pos}", pos) for p, k in zip(phrase_sets, picks)]
        if len(parts) == 1:
            text = f"{subject} {parts[0]}"
        else:
            tpl = SEQUENCE_TEMPLATES[int(rng.integers(len(SEQUENCE_TEMPLATES)))]
            text = tpl.format(s=subject, a=parts[0], b=parts[1])
        out.append(text + ".")
    return list(dict.fromkeys(out))  # same subject and phrasing twice: keep one


# A small POS lexicon covering every word the captions use, tagged like HumanML3D's texts (spaCy's
# universal tags, only NOUN and VERB lemmatised, punctuation dropped). The build fails loudly on a word
# missing here rather than guessing.
_WORDS = {
    "DET": "a the this both all his her their",
    "PRON": "someone it nothing them that",
    "AUX": "is",
    "CCONJ": "and",
    "ADP": "above at in into of on over to with without after before",
    "INTJ": "hello",
    "NUM": "one two three four five six seven eight nine ten eleven twelve thirteen fourteen fifteen "
           "sixteen seventeen eighteen nineteen twenty sixty eighty ninety hundred",
    "ADJ": "left right slow quick normal deep full half high low middle long short small seated upper other "
           "idle little quarter",
    "ADV": "ahead afterwards backward backwards back calmly carefully clockwise counterclockwise deeply down "
           "far fast forward quickly slightly slowly still then together up once twice around much out "
           "sideways straight first",
}
_NOUNS = {"person": "person", "man": "man", "woman": "woman", "human": "human", "arm": "arm", "arms": "arm",
          "hand": "hand", "hands": "hand", "fist": "fist", "fists": "fist", "foot": "foot", "leg": "leg",
          "knees": "knee", "head": "head", "body": "body", "chair": "chair", "chest": "chest",
          "circle": "circle", "distance": "distance", "height": "height", "line": "line", "pace": "pace",
          "place": "place", "position": "position", "seat": "seat", "shoulder": "shoulder", "side": "side",
          "sides": "side", "times": "time", "way": "way", "waist": "waist", "degrees": "degree",
          "front": "front"}
_VERBS = {"applauds": "applaud", "bends": "bend", "boxes": "box", "brings": "bring", "claps": "clap",
          "does": "do", "faces": "face", "held": "hold", "holds": "hold", "hops": "hop", "jabs": "jab",
          "jogging": "jog", "jogs": "jog", "leaps": "leap", "lifts": "lift", "looks": "look", "lowers": "lower",
          "makes": "make", "moves": "move", "moving": "move", "puts": "put", "raises": "raise", "rises": "rise",
          "runs": "run", "running": "run", "shuffles": "shuffle", "sidesteps": "sidestep", "sits": "sit",
          "spins": "spin", "sprints": "sprint", "stands": "stand", "standing": "stand", "stays": "stay",
          "swings": "swing", "takes": "take", "throws": "throw", "turning": "turn", "walks": "walk",
          "waves": "wave", "alternating": "alternate", "using": "use"}
# NOUN after a determiner, number or adjective ("does two squats"), VERB otherwise ("squats down")
_NOUN_OR_VERB = {"jump": "jump", "jumps": "jump", "kick": "kick", "kicks": "kick", "punch": "punch",
                 "punches": "punch", "squat": "squat", "squats": "squat", "step": "step", "steps": "step",
                 "bow": "bow", "bows": "bow", "turn": "turn", "turns": "turn"}
LEXICON = {w: (w, pos) for pos, words in _WORDS.items() for w in words.split()}
LEXICON.update({w: (lemma, "NOUN") for w, lemma in _NOUNS.items()})
LEXICON.update({w: (lemma, "VERB") for w, lemma in _VERBS.items()})


def pos_tokens(caption: str) -> str:
    """HumanML3D's token field: 'a person walks forward.' -> 'a/DET person/NOUN walk/VERB forward/ADV'."""
    out, prev = [], None
    for word in caption.lower().replace("-", "").split():
        word = "".join(ch for ch in word if ch.isalpha())
        if not word:
            continue
        if word in _NOUN_OR_VERB:
            pos = "NOUN" if prev in ("DET", "NUM", "ADJ") else "VERB"
            lemma = _NOUN_OR_VERB[word]
        elif word in LEXICON:
            lemma, pos = LEXICON[word]
        else:
            raise ValueError(f"caption word {word!r} is not in the procedural POS lexicon: {caption!r}")
        out.append(f"{lemma}/{pos}")
        prev = pos
    return " ".join(out)


def caption_line(caption: str) -> str:
    """One line of a HumanML3D texts/ file: caption#tokens#start#end (0.0#0.0: the whole clip)."""
    return f"{caption}#{pos_tokens(caption)}#0.0#0.0"


# ---------------------------------------------------------------------------------------------- writer

def mean_std(features, num_joints: int) -> tuple[np.ndarray, np.ndarray]:
    """HumanML3D's `mean_variance`: per-dimension mean; per-dimension std, then replaced in each feature
    group (root rot vel, root lin vel, root y, ric, rot6d, local vel, foot contact) by the group's mean
    std. HumanML3D divides each group by a weight that is 1.0 in the released code (the "feat_bias" of 5
    on root and foot terms is applied later, by T2M's evaluator training, not in Mean/Std.npy); so do we.

    `features`: a sequence of (T, D) arrays, or of paths to .npy files (read twice, never all at once).
    """
    load = (lambda f: np.load(f).astype(np.float64)) if not isinstance(features[0], np.ndarray) else \
        (lambda f: f.astype(np.float64))
    n, total = 0, 0.0
    for f in features:  # two passes in float64: the mean, then squared deviations from it
        x = load(f)
        n, total = n + len(x), total + x.sum(axis=0)
    mean = total / n
    sq = 0.0
    for f in features:
        sq = sq + ((load(f) - mean) ** 2).sum(axis=0)
    std = np.sqrt(sq / n)
    for sl in FeatureLayout(num_joints).slices().values():
        std[sl] = std[sl].mean()
    return mean.astype(np.float32), std.astype(np.float32)


def _write_clip(index: int, plan: list[tuple[str, ...]], seed: int, root: Path) -> tuple[str, str, int]:
    clip_id = f"{index:06d}"
    families = plan[index]
    joints, captions = generate_clip(families, np.random.default_rng([seed, index]))
    features = extract_features(joints, HUMANML3D)
    np.save(root / "new_joint_vecs" / f"{clip_id}.npy", features)
    np.save(root / "new_joints" / f"{clip_id}.npy", canonicalize(joints, HUMANML3D).astype(np.float32))
    (root / "texts" / f"{clip_id}.txt").write_text("".join(caption_line(c) + "\n" for c in captions),
                                                  encoding="utf-8")
    label = label_for(families)
    (root / "labels" / f"{clip_id}.txt").write_text(label + "\n", encoding="utf-8")
    return clip_id, label, len(joints)


def split_ids(ids: list[str], seed: int) -> dict[str, list[str]]:
    """Deterministic 80/15/5 split of clip ids (each split sorted); from 3 clips on, no split is empty."""
    n = len(ids)
    order = np.random.default_rng([seed, 3]).permutation(n)
    n_val = int(round(SPLITS[1][1] * n))
    n_test = n - int(round(SPLITS[0][1] * n)) - n_val
    if n >= 3:
        n_val, n_test = max(1, n_val), max(1, n_test)
    n_train = n - n_val - n_test
    parts = {"train": order[:n_train], "val": order[n_train:n_train + n_val], "test": order[n_train + n_val:]}
    return {name: sorted(ids[i] for i in idx) for name, idx in parts.items()}


def _build_into(tmp: Path, num_clips: int, seed: int, progress: bool, workers: int) -> None:
    """Write every file of the dataset into `tmp` (see build_dataset)."""
    plan = family_plan(num_clips, seed)
    job = partial(_write_clip, plan=plan, seed=seed, root=tmp)
    bar = tqdm(total=num_clips, desc="procedural clips", unit="clip", disable=not progress)
    results = []
    if workers > 1 and num_clips > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            for r in pool.imap(job, range(num_clips), chunksize=8):
                results.append(r)
                bar.update()
    else:
        for i in range(num_clips):
            results.append(job(i))
            bar.update()
    bar.close()

    ids = [r[0] for r in results]
    splits = split_ids(ids, seed)
    for name, members in splits.items():
        (tmp / f"{name}.txt").write_text("".join(m + "\n" for m in members), encoding="utf-8")
    train = [tmp / "new_joint_vecs" / f"{m}.npy" for m in splits["train"] or ids]
    mean, std = mean_std(train, HUMANML3D.num_joints)
    np.save(tmp / "Mean.npy", mean)
    np.save(tmp / "Std.npy", std)

    labels = [r[1] for r in results]
    frames = np.array([r[2] for r in results])
    info = {
        "generator": "mogo_export.data.procedural",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "num_clips": num_clips,
        "splits": {k: len(v) for k, v in splits.items()},
        "families": list(A.FAMILIES),
        "label_counts": {k: labels.count(k) for k in sorted(set(labels))},
        "label_format": "family name, or 'seq:<first>+<second>' for a two-action sequence (in order)",
        "num_sequences": sum(lab.startswith("seq:") for lab in labels),
        "fps": FPS,
        "frames": {"min": int(frames.min()), "max": int(frames.max()), "mean": round(float(frames.mean()), 2)},
        "feature_dim": FeatureLayout(HUMANML3D.num_joints).dim,
        "skeleton": HUMANML3D.to_dict(),
        "std_convention": "HumanML3D mean_variance: std averaged within each feature group, weights 1.0; "
                          "computed over the train split",
    }
    (tmp / "dataset.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n", encoding="utf-8")


def build_dataset(out_dir, num_clips: int = 2000, seed: int = 0, progress: bool = True, workers: int = 2,
                  overwrite: bool = False) -> Path:
    """Write a procedural dataset in the HumanML3D folder layout and return its path.

      new_joint_vecs/NNNNNN.npy  (T-1, 263) float32 features (mogo_export.data.humanml3d.extract_features)
      new_joints/NNNNNN.npy      (T, 22, 3) float32 joints, canonicalised as HumanML3D's are (floor y=0,
                                 frame 0 root at x=z=0 facing +z); the features have one frame fewer
      texts/NNNNNN.txt           3-4 lines `caption#word/POS ...#0.0#0.0`
      labels/NNNNNN.txt          the family (`squat`) or, for a two-action sequence, `seq:first+second`
      train.txt val.txt test.txt clip ids, an 80/15/5 split
      Mean.npy Std.npy           feature statistics over the train split (see `mean_std`)
      dataset.json               generator version, seed, counts, families, fps, skeleton
    Everything is a function of (num_clips, seed): the same call writes byte-identical files, whatever
    `workers` is. The dataset is built in a temporary sibling folder and renamed into place at the end.
    """
    out = Path(out_dir)
    if num_clips < 1:
        raise ValueError(f"num_clips must be >= 1, got {num_clips}")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass overwrite=True (--overwrite) to replace it")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.building-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    for sub in ("new_joint_vecs", "new_joints", "texts", "labels"):
        (tmp / sub).mkdir(parents=True)

    try:
        _build_into(tmp, num_clips, seed, progress, workers)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)  # never leave a half dataset behind, even a hidden one
        raise

    if out.exists():  # overwrite: swap in the new one, then drop the old
        trash = out.with_name(f".{out.name}.old-{os.getpid()}")
        out.rename(trash)
        tmp.rename(out)
        shutil.rmtree(trash)
    else:
        tmp.rename(out)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m mogo_export.data.procedural",
                                 description="Write a procedural text-to-motion dataset in the HumanML3D layout.")
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--clips", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--overwrite", action="store_true", help="replace OUT_DIR if it exists")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = build_dataset(args.out_dir, args.clips, args.seed, progress=not args.quiet, workers=args.workers,
                        overwrite=args.overwrite)
    print(f"wrote {args.clips} clips to {out} in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
