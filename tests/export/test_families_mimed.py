"""The mimed interactions (procedural/mimed.py) do what their captions say: picking up, throwing overhand and
underhand, pushing, pulling, carrying, reaching up, climbing a ladder in place and opening a door.

Every measure is taken on the joints a model learns from (the features, recovered: frame 0 faces +z, +x is the
body's left, y up), 8 clips a family. Bounds come from each family's definition in mimed.py, with room for the
body's sway; none is fitted to what the generator happens to output."""
import re

import numpy as np
import pytest

from mogo_export.data.procedural import clips as C, mimed
from mogo_export.data.procedural.pose import FPS

from family_facts import SIDE, STAND_Y, motion_facts, rises, through_features

NAMES = [f.__name__ for f in mimed.FAMILIES]
PELVIS, HEAD, NECK = 0, 15, 12
TRUNK = [3, 6, 9, 12, 15]           # spine joints, neck and head: a hand must not pass through them
ELBOW = {"left": 18, "right": 19}
KNEE = {"left": 4, "right": 5}
TOE = {"left": 10, "right": 11}
SIGN = {"left": 1.0, "right": -1.0}  # +x is the body's left


@pytest.fixture(scope="module")
def clips():
    out = {}
    for i, name in enumerate(NAMES):
        out[name] = []
        for s in range(8):
            clip = C.generate_clip((name,), np.random.default_rng([31, i, s]))
            out[name].append((clip.segments[0].params, through_features(clip.joints), clip.captions))
    return out




def joint_angle(j, a, b, c):
    u, v = j[:, b] - j[:, a], j[:, c] - j[:, b]
    cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def common(j, m):
    """What every mimed family keeps: human speeds, its heading, no hand through the trunk or head."""
    v = np.linalg.norm(np.diff(j, axis=0), axis=-1) * FPS
    gap = min(np.linalg.norm(j[:, w, None] - j[:, TRUNK], axis=-1).min() for w in (20, 21))
    return [("wrists < 15 m/s", v[:, [20, 21]].max() < 15.0), ("pelvis < 8 m/s", v[:, 0].max() < 8.0),
            ("no joint faster than 20 m/s", v.max() < 20.0),
            ("keeps its heading within 15 deg", abs(m["turn"]) < 15),
            (f"hands clear of the trunk and head by 8 cm ({gap:.3f})", gap > 0.08)]


def promises(name, p, j):
    """(promise, kept) for what `name`'s captions say, drawn with parameters p, measured on joints j."""
    m = motion_facts(j)
    out = common(j, m)
    y = j[..., 1]
    fwd = j[..., 2] - j[:, PELVIS, None, 2]     # forward of the pelvis
    floor_fwd = j[..., 2]                       # forward of where the clip starts
    wl, wr = SIDE["left"]["wrist"], SIDE["right"]["wrist"]
    apart = np.linalg.norm(j[:, wl] - j[:, wr], axis=-1)
    if name == "pick_up":
        low = np.maximum(y[:, wl], y[:, wr])   # both hands at once
        t = int(np.argmin(low))
        toes = j[t, [10, 11], 2].max()
        out.append((f"both wrists reach < 25 cm above the floor ({low.min():.2f})", low.min() < 0.25))
        out.append(("in front of the feet", min(j[t, wl, 2], j[t, wr, 2]) > toes))
        out.append(("once: the hands go down one time", rises(-low, -0.35, -0.6) == 1))
        if p["how"] == "waist":  # the thighs bend 52 degrees, the trunk folds past horizontal
            out.append(("bends at the waist: the pelvis drops < 0.3 m", m["drop"] < 0.3))
            out.append(("the head comes down > 0.6 m", m["head_dip"] > 0.6))
        else:  # a deep crouch: the thighs past horizontal
            out.append(("bends the knees: the pelvis drops > 0.3 m", m["drop"] > 0.3))
        out.append(("stands back up", abs(m["end_drop"]) < 0.05))
        end = j[-3:].mean(0)
        out.append(("ends holding the hands at the waist (0.9-1.2 m)", 0.9 < min(end[[wl, wr], 1]) and
                    max(end[[wl, wr], 1]) < 1.2))
        out.append(("in front of the body, 20-50 cm apart", min(end[[wl, wr], 2] - end[PELVIS, 2]) > 0.2
                    and 0.2 < np.linalg.norm(end[wl] - end[wr]) < 0.5))
        out.append(("in place: moves < 0.2 m", m["dist"] < 0.2))
    if name in ("throw_overhand", "throw_underhand"):
        side = p["side"]
        other = "left" if side == "right" else "right"
        w, sh, ow = SIDE[side]["wrist"], SIDE[side]["shoulder"], SIDE[other]["wrist"]
        speed = np.linalg.norm(np.diff(j[:, w], axis=0), axis=-1) * FPS
        ospeed = np.linalg.norm(np.diff(j[:, ow], axis=0), axis=-1) * FPS
        # a throw whips the hand faster than an overhand 5 m/s or an underhand toss 3 m/s; the other arm is
        # only carried round by the trunk's turn, slower than the throwing hand
        fast = 5.0 if name == "throw_overhand" else 3.0
        out.append((f"the {side} hand throws fast: > {fast} m/s ({speed.max():.1f})", speed.max() > fast))
        out.append((f"the {other} hand slower ({ospeed.max():.1f})", ospeed.max() < 0.8 * speed.max()))
        # each throw steps forward with the opposite foot and brings the other up beside it: 0.2-0.7 m
        out.append((f"moves forward 0.2-0.7 m a throw ({m['fwd']:.2f})", 0.2 * p["reps"] < m["fwd"] < 0.7 * p["reps"]))
        oa, sa = SIDE[other]["ankle"], SIDE[side]["ankle"]
        lead = floor_fwd[:, oa] - floor_fwd[:, sa]
        out.append((f"the {other} foot steps out ahead of the {side} one by > 0.25 m", lead.max() > 0.25))
        out.append((f"never the {side} foot ahead", lead.min() > -0.05))
        up = y[:, w] - y[:, sh]
        if name == "throw_overhand":
            above = up > 0.1
            behind = (j[:, w, 2] - j[:, HEAD, 2])[above]
            out.append((f"the {side} hand goes over the shoulder {p['reps']} times", rises(up, 0.1, -0.1) == p["reps"]))
            out.append(("back behind the head", above.any() and behind.min() < -0.05))
            out.append(("and whips through to the front, > 0.35 m ahead of the shoulder", m[f"reach_{side}"] > 0.35))
            out.append((f"the {other} hand stays below the shoulder", m[f"hand_up_{other}"] < 0.0))
        else:
            rel = fwd[:, w]
            out.append((f"the {side} hand stays below the shoulder ({up.max():.2f})", up.max() < 0.0))
            out.append((f"swings back behind the hip {p['reps']} times", rises(-rel, 0.15, 0.0) == p["reps"]))
            out.append(("and forward, > 0.3 m in front of the hip", rel.max() > 0.3))
            t = int(np.argmax(speed))  # the release: the fastest frame of the swing
            out.append((f"letting go at hip height (0.55-1.1 m: {j[t, w, 1]:.2f})", 0.55 < j[t, w, 1] < 1.1))
    if name == "push":
        mid = slice(len(j) // 3, 2 * len(j) // 3)  # while stepping
        steps = p["steps"]
        out.append((f"moves forward 0.08-0.5 m a step ({m['fwd']:.2f})", 0.08 * steps < m["fwd"] < 0.5 * steps))
        out.append(("in a straight line", abs(m["left"]) < 0.1 + 0.1 * m["fwd"]))
        for s in ("left", "right"):
            w, sh = SIDE[s]["wrist"], SIDE[s]["shoulder"]
            out.append((f"the {s} arm held out forward > 0.35 m", (fwd[mid, w] - fwd[mid, sh]).min() > 0.35))
            h = (y[mid, w] - y[mid, sh])
            out.append(("at chest height (-0.3..+0.1 m of the shoulder)", h.min() > -0.3 and h.max() < 0.1))
        lean = np.degrees(np.arctan2(j[mid, NECK, 2] - j[mid, PELVIS, 2], j[mid, NECK, 1] - j[mid, PELVIS, 1]))
        out.append((f"leaning forward 12-35 deg ({np.median(lean):.0f})", 12 < np.median(lean) < 35))
        out.append(("both hands on the thing, 25-55 cm apart", 0.25 < apart[mid].min() and apart[mid].max() < 0.55))
    if name == "pull":
        lean = np.degrees(np.arctan2(j[:, NECK, 2] - j[:, PELVIS, 2], j[:, NECK, 1] - j[:, PELVIS, 1]))
        out.append((f"leans back > 10 deg ({lean.min():.0f})", lean.min() < -10))
        out.append(("reaches forward with both hands > 0.35 m", min(m["reach_left"], m["reach_right"]) > 0.35))
        out.append(("hands below the shoulders", max(m["hand_up_left"], m["hand_up_right"]) < 0.1))
        if p["mode"] == "rope":
            out.append(("in place: moves < 0.2 m", m["dist"] < 0.2))
            d = fwd[:, wr] - fwd[:, wl]  # > 0: the right hand out along the rope
            # the hands take turns, each over the other by more than 15 cm, reps - 1 times or more
            swaps = rises(d, 0.15, -0.15) + rises(-d, 0.15, -0.15)
            out.append((f"hand over hand: the hands change over {swaps} times for {p['reps']}",
                        p["reps"] - 1 <= swaps <= p["reps"] + 1))
        else:
            steps = p["steps"]
            out.append((f"backs up 0.08-0.5 m a step ({m['fwd']:.2f})", 0.08 * steps < -m["fwd"] < 0.5 * steps))
            out.append(("both hands together on the thing", apart[len(j) // 3:2 * len(j) // 3].max() < 0.3))
    if name == "carry":
        steps = p["steps"]
        mid = slice(len(j) // 4, 3 * len(j) // 4)
        out.append((f"walks forward 0.2-0.9 m a step ({m['fwd']:.2f})", 0.2 * steps < m["fwd"] < 0.9 * steps))
        out.append(("in a straight line", abs(m["left"]) < 0.1 + 0.1 * m["fwd"]))
        for s in ("left", "right"):
            w = SIDE[s]["wrist"]
            out.append((f"the {s} hand at waist height (0.9-1.2 m)", 0.9 < y[mid, w].min() and y[mid, w].max() < 1.2))
            out.append(("held in front of the body (0.15-0.5 m)",
                        0.15 < fwd[mid, w].min() and fwd[mid, w].max() < 0.5))
            out.append(("not swinging: moves < 10 cm fore and aft", np.ptp(fwd[mid, w]) < 0.1))
            el = joint_angle(j[mid], SIDE[s]["shoulder"], ELBOW[s], w)
            out.append((f"the {s} elbow bent 65-110 deg", 65 < el.min() and el.max() < 110))
        out.append(("hands 25-45 cm apart, around the box", 0.25 < apart[mid].min() and apart[mid].max() < 0.45))
    if name == "reach_up":
        side = p["side"]
        other = "left" if side == "right" else "right"
        w = SIDE[side]["wrist"]
        up = y[:, w] - y[:, HEAD]
        out.append((f"the {side} hand reaches > 0.25 m above the head", up.max() > 0.25))
        out.append((f"{p['reps']} times", rises(up, 0.25, 0.0) == p["reps"]))
        out.append((f"the {other} hand stays below the shoulder", m[f"hand_up_{other}"] < -0.2))
        heels = j[:, [7, 8], 1] - j[:3, [7, 8], 1].mean(0)
        t = int(np.argmax(up))
        out.append(("rising on the toes: both heels up > 3 cm", heels[t].min() > 0.03))
        out.append(("the toes stay on the floor", j[:, [10, 11], 1].max() < 0.03))
        out.append(("the pelvis rises > 3 cm", m["rise"] > 0.03))
        out.append(("in place: moves < 0.1 m", m["dist"] < 0.1))
    if name == "climb_ladder":
        out.append(("in place: moves < 0.15 m", m["dist"] < 0.15))
        for s in ("left", "right"):
            above = (y[:, SIDE[s]["wrist"]] - y[:, HEAD]).max()
            out.append((f"the {s} hand reaches > 0.2 m above the head", above > 0.2))
        knee_up = {s: y[:, KNEE[s]] - y[:, PELVIS] for s in ("left", "right")}  # 0: the thigh level
        lifts = sum(rises(k, -0.15, -0.3) for k in knee_up.values())
        out.append((f"the knees lift high (thigh near level) {lifts} times for {p['reps']} rungs", lifts == p["reps"]))
        # alternating: at each knee's highest (within 5 cm) the opposite hand is the higher one
        for s in ("left", "right"):
            o = "left" if s == "right" else "right"
            lifted = knee_up[s] > knee_up[s].max() - 0.05
            out.append((f"the {o} hand up while the {s} knee lifts",
                        (y[lifted, SIDE[o]["wrist"]] > y[lifted, SIDE[s]["wrist"]]).mean() > 0.8))
    if name == "open_door":
        side = p["side"]
        w, a = SIDE[side]["wrist"], SIDE[side]["ankle"]
        reach = fwd[:, w] - fwd[:, SIDE[side]["shoulder"]]
        t = int(np.argmax(reach[: len(j) // 2]))
        out.append((f"the {side} hand reaches forward > 0.3 m", reach[t] > 0.3))
        out.append((f"to a handle at waist height (0.8-1.2 m: {y[t, w]:.2f})", 0.8 < y[t, w] < 1.2))
        out.append(("the other hand stays down", m["hand_up_" + ("left" if side == "right" else "right")] < -0.3))
        # pulling the door open: the hand comes back toward the body and out to its side
        after = slice(t, len(j))
        out_side = SIGN[side] * (j[after, w, 0] - j[after, PELVIS, 0])
        out.append(("the hand draws back toward the body", reach[after].min() < reach[t] - 0.25))
        out.append((f"and out to the {side}", out_side.max() > 0.3))
        out.append((f"stepping back with the {side} foot > 0.15 m", j[:, a, 2].min() < j[0, a, 2] - 0.15))
        out.append((f"then walks through: forward 0.3-0.9 m a step ({m['fwd']:.2f})",
                    0.3 * p["steps"] < m["fwd"] + 0.25 < 0.9 * p["steps"] + 0.25))
        out.append(("in a straight line", abs(m["left"]) < 0.15 + 0.1 * abs(m["fwd"])))
    return out


def test_every_mimed_family_does_what_its_captions_say(clips):
    table, broken = {}, []
    for name in NAMES:
        rows = []
        for s, (p, j, caps) in enumerate(clips[name]):
            broken += [f"{name} seed {s} {p}: not {what}" for what, ok in promises(name, p, j) if not ok]
            m = motion_facts(j)
            lo = np.maximum(j[:, 20, 1], j[:, 21, 1]).min()
            rows.append([m[k] for k in ("dist", "fwd", "left", "turn", "rise", "drop")]
                        + [max(m["hand_up_left"], m["hand_up_right"]), lo,
                           np.linalg.norm(np.diff(j[:, [20, 21]], axis=0), axis=-1).max() * FPS])
        table[name] = np.median(rows, axis=0)
    print("\nfamily             dist    fwd   left   turn   rise   drop handup lowhnd wristv  (medians of 8 clips)")
    for name, med in table.items():
        print(f"{name:16s}" + "".join(f"{v:7.2f}" for v in med))
    assert not broken, "\n".join(broken)


def test_every_parameter_value_is_drawn(clips):
    """The 8 clips a family show what its captions vary: both sides, both ways of doing it."""
    for name, key in (("pick_up", "how"), ("pull", "mode"), ("reach_up", "side"), ("throw_overhand", "side"),
                      ("throw_underhand", "side"), ("open_door", "side")):
        seen = {p[key] for p, _, _ in clips[name]}
        assert len(seen) == 2, (name, seen)


def test_captions_name_the_side_and_the_way(clips):
    for name in NAMES:
        for p, _, caps in clips[name]:
            for c in caps:
                if "side" in p:
                    assert p["side"] in c, (name, c)
                if name == "pick_up":
                    assert bool(re.search(r"\bknees\b|\blow\b|\bhips\b", c)) == (p["how"] == "knees"), c
                if name == "pull":
                    assert ("step" in c or "backing" in c) == (p["mode"] == "backward"), c


def test_the_standing_start(clips):
    """Every mimed family starts standing on the floor (so it follows any other action)."""
    for name in NAMES:
        for p, j, _ in clips[name]:
            assert abs(j[0, PELVIS, 1] - STAND_Y) < 0.03, name
