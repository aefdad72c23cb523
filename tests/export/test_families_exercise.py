"""The exercise and acrobatics families (mogo_export/data/procedural/exercise.py, acrobatics.py) do what their
captions say: measured on the joints a model learns from (the writer's features, recovered: frame 0 faces +z, +x
is the person's left), for 8 clips of each family. Bounds come from each family's definition in its module, with
room for the body's sway; each states why it is what it is."""
import numpy as np
import pytest

from mogo_export.data.procedural import acrobatics as A, clips as C, exercise as X, families
from mogo_export.data.procedural.pose import FPS

from family_facts import STAND_Y, motion_facts, through_features

NAMES = [f.__name__ for f in X.FAMILIES + A.FAMILIES]
HEAD, NECK = 15, 12
L_SH, R_SH, L_EL, R_EL, L_WR, R_WR = 16, 17, 18, 19, 20, 21
L_HIP, R_HIP, L_KNEE, R_KNEE, L_ANK, R_ANK, L_TOE, R_TOE = 1, 2, 4, 5, 7, 8, 10, 11
BODY = [0, 3, 6, 9, 12, 15]  # pelvis, spine, neck, head: a hand must not pass through them
ANKLE = {"left": L_ANK, "right": R_ANK}
KNEE = {"left": L_KNEE, "right": R_KNEE}


def _angle(j, a, b, c):
    """Bend at b between bones a->b and b->c, degrees (0 = straight)."""
    u, v = j[:, b] - j[:, a], j[:, c] - j[:, b]
    cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def _runs(mask):
    """Number of runs of True."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    return int((np.diff(m) == 1).sum())


def _winding(x, y):
    """Signed turns of the path (x, y) about its centre: > 0 counter-clockwise (x right, y up)."""
    a = np.unwrap(np.arctan2(y - y.mean(), x - x.mean()))
    return (a[-1] - a[0]) / (2 * np.pi)


def measure(j):
    """motion_facts plus what the exercise captions promise, on joints through the features."""
    m = motion_facts(j)
    v = np.diff(j, axis=0) * FPS
    m["wrist_speed"] = np.linalg.norm(v[:, [L_WR, R_WR]], axis=-1).max()
    m["pelvis_speed"] = np.linalg.norm(v[:, 0], axis=-1).max()
    m["hand_body"] = np.linalg.norm(j[:, [L_WR, R_WR], None] - j[:, None, BODY], axis=-1).min()
    m["lowest"] = j[..., 1].min()
    m["feet_apart"] = np.abs(j[:, L_ANK, 0] - j[:, R_ANK, 0]).max()
    m["feet_apart_0"] = np.abs(j[0, L_ANK, 0] - j[0, R_ANK, 0])
    m["over_head"] = (np.minimum(j[:, L_WR, 1], j[:, R_WR, 1]) - j[:, HEAD, 1]).max()  # both hands above the head
    toes = j[:, [L_TOE, R_TOE], 1].min(axis=1)
    m["hops"] = _runs(toes > 0.025)  # both toes off the floor
    m["one_foot_down"] = (toes < 0.03).mean()
    return m


def family_promises(name, p, j, m):
    """(promise, kept) for what `name`'s captions say, drawn with parameters p, measured on joints j."""
    out = [("keeps its heading within 15 deg", abs(m["turn"]) < 15),
           # a thrown ball's wrist reaches ~20 m/s; exercise arms stay well under 15, the pelvis under 8
           ("human speeds: wrist < 15 m/s, pelvis < 8 m/s", m["wrist_speed"] < 15 and m["pelvis_speed"] < 8),
           ("no hand through the trunk or head (> 8 cm)", m["hand_body"] > 0.08),
           ("no joint below the floor", m["lowest"] > -0.01)]
    reps = p.get("reps", 1)
    if name == "jumping_jacks":
        out += [("stays in place: moves < 0.3 m", m["dist"] < 0.3),
                # two hops per jack (out and back in), each a flight of 5-8 cm
                (f"hops {2 * reps} times (out and in per jack)", m["hops"] == 2 * reps),
                ("leaves the floor 4+ cm", m["airborne"] > 0.04),
                # each leg abducts 11-15 deg: ankles ~0.5-0.6 m apart from ~0.2 m
                ("feet jump apart (> 0.4 m) from together (< 0.3 m)",
                 m["feet_apart"] > 0.4 and m["feet_apart_0"] < 0.3),
                ("both hands go over the head", m["over_head"] > 0.1),
                ("and come back down to the sides", max(j[-1, L_WR, 1], j[-1, R_WR, 1]) < j[-1, L_SH, 1] - 0.3)]
    if name == "lunges":
        fronts = ["left", "right"] if p["side"] == "alternating" else [p["side"]]
        ahead = {s: (j[:, ANKLE[s], 2] - j[0, ANKLE[s], 2]).max() for s in ("left", "right")}
        dips = _runs(j[:, 0, 1] < STAND_Y - 0.15)
        out += [("ends where it started: moves < 0.15 m", m["dist"] < 0.15),
                # the hips drop to ~0.53-0.6 m: the front thigh near horizontal
                ("deep: the pelvis drops > 0.2 m", m["drop"] > 0.2),
                ("stands back up", abs(m["end_drop"]) < 0.05),
                (f"lunges {reps} times", dips == reps),
                ("one foot always on the floor", m["one_foot_down"] == 1.0)]
        for s in ("left", "right"):
            if s in fronts:  # a stride of 0.82-0.95 m
                out.append((f"the {s} foot steps 0.6-1.1 m forward", 0.6 < ahead[s] < 1.1))
            else:  # the back foot pivots on its toes: its ankle moves ~0.1 m
                out.append((f"the {s} foot stays back (< 0.25 m)", ahead[s] < 0.25))
        bottom = int(np.argmin(j[:, 0, 1]))
        front = max(fronts, key=lambda s: j[bottom, ANKLE[s], 2])
        back = "left" if front == "right" else "right"
        fk = _angle(j, *((L_HIP, L_KNEE, L_ANK) if front == "left" else (R_HIP, R_KNEE, R_ANK)))[bottom]
        bk = j[bottom, KNEE[back], 1]
        out += [(f"front knee ~90 deg at the bottom ({fk:.0f})", 70 < fk < 110),
                (f"back knee toward the floor but above it ({bk:.2f} m)", 0.06 < bk < 0.3)]
    if name == "arm_circles":
        out += [("stands still: feet stay, moves < 5 cm", m["dist"] < 0.05)]
        for wr, sh, side in ((L_WR, L_SH, "left"), (R_WR, R_SH, "right")):
            rel = j[:, wr] - j[:, sh]
            held = np.abs(rel[:, 0]) > 0.35                         # arm held out to the side (arm ~0.55 m)
            fwd, up = rel[held, 2], rel[held, 1]
            turns = _winding(fwd, up)                               # forward circles: over the top toward the front
            want = -1 if p["direction"] == "forward" else 1        # clockwise in (forward, up)
            n = len(fwd)
            size = np.ptp(fwd[n // 4:3 * n // 4])                  # the circles' width, not the arm rising into them
            out += [(f"{side} arm held out sideways > 1 s", held.sum() > FPS),
                    (f"{side} arm circles {p['direction']} {reps} times ({turns:+.1f})",
                     want * turns > reps - 0.6 and want * turns < reps + 0.6),
                    # radius 20-27 deg (small) or 38-48 deg (big) on a 0.55 m arm: the hand's circle spans ~0.4 / 0.7 m
                    (f"{'big' if p['big'] else 'small'} circles ({size:.2f} m)",
                     0.5 < size < 0.95 if p["big"] else 0.25 < size < 0.55)]
    if name == "swim_strokes":
        lw, rw = j[:, L_WR, 1] - j[:, HEAD, 1], j[:, R_WR, 1] - j[:, HEAD, 1]
        mid = slice(len(j) // 4, 3 * len(j) // 4)  # the strokes, not the arms rising into them and resting after
        corr = np.corrcoef(lw[mid], rw[mid])[0, 1]
        out += [("stands in place: moves < 5 cm", m["dist"] < 0.05),
                ("feet stay planted: pelvis within 8 cm of standing", m["drop"] < 0.08 and m["rise"] < 0.03)]
        if p["style"] == "freestyle":
            overhead = _runs(lw > 0.1) + _runs(rw > 0.1)            # each stroke enters above the head
            out += [("overhead strokes: each hand goes over the head", min(lw.max(), rw.max()) > 0.15),
                    ("alternating arms", corr < -0.2),
                    (f"{reps} strokes ({overhead} hands over the head)", abs(overhead - reps) <= 1)]
        else:
            gap = np.linalg.norm(j[:, L_WR] - j[:, R_WR], axis=-1)
            reach = np.maximum(m["reach_left"], m["reach_right"])
            out += [("both arms together", corr > 0.5),
                    ("hands stay below the top of the head", max(lw.max(), rw.max()) < 0.1),
                    ("reach straight ahead (> 0.4 m)", reach > 0.4),
                    ("sweep wide (> 0.6 m) and back together (< 0.3 m)", gap.max() > 0.6 and gap.min() < 0.3),
                    # the hands meet at the glide before each stroke and after the last
                    (f"{reps} strokes (hands meet {_runs(gap < 0.35)} times)", abs(_runs(gap < 0.35) - (reps + 1)) <= 1)]
    if name == "dance":
        # the knees bounce on every beat: the less bent knee (the one carrying the body) dips on each
        knee = np.minimum(_angle(j, L_HIP, L_KNEE, L_ANK), _angle(j, R_HIP, R_KNEE, R_ANK))
        knee = knee[len(knee) // 4:3 * len(knee) // 4]  # the dance, not the steps into and out of it
        spec = np.abs(np.fft.rfft(knee - knee.mean(), 256))
        freq = np.fft.rfftfreq(256, 1 / FPS)[1 + np.argmax(spec[1:])]
        out += [("stays around its spot: ends < 0.2 m from its start", m["dist"] < 0.2),
                # 105-130 beats a minute: the knees dip 1.75-2.2 times a second
                (f"bounces at ~2 beats a second ({freq:.2f} Hz)", 1.4 < freq < 2.6),
                ("bounces: the pelvis dips 1.5+ cm", m["drop"] > 0.015)]
        if p["style"] == "step_touch":
            x = j[:, 0, 0] - j[0, 0, 0]
            vx = np.diff(x)
            moving = np.abs(vx) > 0.004
            flips = int((np.diff(np.sign(vx[moving])) != 0).sum())
            # each bar: out, close (same way), out, close back: the pelvis reverses twice a bar
            out += [("steps side to side (pelvis sways > 0.12 m)", np.ptp(x) > 0.12),
                    (f"keeps changing direction ({flips} reversals)", flips >= p["beats"] // 2 - 1)]
        else:
            heels = j[:, [L_ANK, R_ANK], 1]
            pops = _runs(heels[:, 0] > heels[0, 0] + 0.03) + _runs(heels[:, 1] > heels[0, 1] + 0.03)
            out += [("feet stay planted: moves < 5 cm", m["dist"] < 0.05),
                    (f"knee pops on the beats ({pops} of {p['beats']})", abs(pops - p["beats"]) <= 2)]
    if name == "backflip":
        trunk = j[:, NECK] - j[:, 0]
        pitch = np.degrees(np.unwrap(np.arctan2(trunk[:, 2], trunk[:, 1])))  # > 0 leaning forward
        turned = pitch.min() - pitch[0]
        air = j[:, [L_TOE, R_TOE], 1].min(axis=1) > 0.1
        tuck = np.minimum(_angle(j, L_HIP, L_KNEE, L_ANK), _angle(j, R_HIP, R_KNEE, R_ANK))[air]
        # the trunk turns backward (over the back) through 300-400 deg and ends one full turn from where it began
        out += [(f"rotates backward a full turn ({turned:.0f} deg)",
                 -400 < turned < -300 and abs(pitch[-1] - pitch[0] + 360) < 30),
                ("goes upside down: the head 0.3+ m below the pelvis", (j[:, 0, 1] - j[:, HEAD, 1]).max() > 0.3),
                # a flight of 0.7-0.77 s: the pelvis rises 0.6-0.72 m over its take-off height
                ("flies: the pelvis rises > 0.45 m over standing", m["rise"] > 0.45),
                ("tucks the knees in the air (> 90 deg)", tuck.size > 0 and tuck.max() > 90),
                ("lands on its feet and stands", abs(m["end_drop"]) < 0.05 and j[-1, [L_TOE, R_TOE], 1].max() < 0.03),
                ("lands near where it took off, not ahead (0.6 m)", m["dist"] < 0.6 and m["fwd"] < 0.05)]
    return out


def _clip(name, seed):
    return C.generate_clip((name,), np.random.default_rng([31, NAMES.index(name), seed]))


def test_exercise_families_are_registered():
    assert list(families.FAMILIES)[-len(NAMES):] == NAMES or set(NAMES) <= set(families.FAMILIES)
    assert not set(X.LAST_ONLY + A.LAST_ONLY) & set(NAMES) - set(families.LAST_ONLY)


def test_exercise_families_do_what_their_captions_say():
    table, broken = {}, []
    for name in NAMES:
        rows = []
        for s in range(8):
            clip = _clip(name, s)
            j = through_features(clip.joints)
            m = measure(j)
            p = clip.segments[0].params
            broken += [f"[31, {NAMES.index(name)}, {s}] {name} {p}: not {what}"
                       for what, ok in family_promises(name, p, j, m) if not ok]
            rows.append([m[k] for k in ("dist", "turn", "rise", "drop", "airborne", "feet_apart", "over_head",
                                        "hops", "wrist_speed", "hand_body")])
        table[name] = np.median(rows, axis=0)
    print("\nfamily           dist   turn   rise   drop    air  feetx  ovrhd   hops  wrist  handb  (medians of 8)")
    for name, med in table.items():
        print(f"{name:15s}" + "".join(f"{v:7.2f}" for v in med))
    assert not broken, "\n".join(broken)


@pytest.mark.parametrize("name", ["jumping_jacks", "lunges", "backflip"])
def test_the_promises_can_fail(name):
    """The measurements see a wrong motion: another family's clip breaks this family's promises."""
    other = {"jumping_jacks": "squat", "lunges": "jump_in_place", "backflip": "jump_in_place"}[name]
    clip = C.generate_clip((other,), np.random.default_rng([31, 99, 0]))
    j = through_features(clip.joints)
    p = dict(_clip(name, 0).segments[0].params)
    assert any(not ok for _, ok in family_promises(name, p, j, measure(j)))
