"""The locomotion styles (mogo_export/data/procedural/styles.py) do what their captions say: measured on 8 clips
of each family through the features, with bounds taken from each family's definition, not fitted to what the
generator happens to output."""
import numpy as np
import pytest

from mogo_export.data.procedural import clips as C, families, styles
from mogo_export.data.procedural.pose import FPS

from family_facts import SIDE, STAND_Y, motion_facts, through_features

FAMILIES = list(families.FAMILIES)
NAMES = [f.__name__ for f in styles.FAMILIES]
SPINE_AND_HEAD = [0, 3, 6, 9, 12, 15]
L_ANKLE, R_ANKLE, L_TOE, R_TOE, L_KNEE, R_KNEE = 7, 8, 10, 11, 4, 5
ANKLE_UP = {"left": L_ANKLE, "right": R_ANKLE}
TOE = {"left": L_TOE, "right": R_TOE}
KNEE = {"left": L_KNEE, "right": R_KNEE}


def _axes(j):
    """Per frame: the body's forward and left unit vectors on the floor (x, z), from the hips and shoulders."""
    across = (j[:, 2] - j[:, 1]) + (j[:, 17] - j[:, 16])
    heading = np.unwrap(np.arctan2(across[:, 2], -across[:, 0]))
    fwd = np.stack([np.sin(heading), np.cos(heading)], -1)
    left = np.stack([np.cos(heading), -np.sin(heading)], -1)
    return fwd, left


def _ahead(j, a, b, axis):
    """How far joint a is from joint b along a per-frame floor axis (m)."""
    return ((j[:, a][:, [0, 2]] - j[:, b][:, [0, 2]]) * axis).sum(-1)


def _runs(mask):
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _planted(j, side):
    """Frames a foot carries weight: its toe on the floor and still (HumanML3D's contact test, tightened)."""
    toe = j[:, TOE[side]]
    v = np.linalg.norm(np.diff(toe, axis=0), axis=-1) * FPS
    return (toe[1:, 1] < 0.02) & (v < 0.4)


def _airborne(j):
    """Frames with every foot joint more than 8 mm off the floor."""
    return j[:, [7, 8, 10, 11], 1].min(axis=1) > 0.008


def _middle(j, lo=0.3, hi=0.7):
    n = len(j)
    return slice(int(lo * n), max(int(hi * n), int(lo * n) + 1))


def measure(family, p, j, raw):
    """(promise, kept) pairs and the facts measured, for clip joints j (through the features) and raw (as built)."""
    m = motion_facts(j)
    fwd_ax, left_ax = _axes(j)
    out = [("keeps its heading within 15 deg", abs(m["turn"]) < 15)]
    # people-like: wrists under 15 m/s, pelvis under 8 m/s (a sprint is ~10 m/s for the fastest humans)
    v = np.linalg.norm(np.diff(raw, axis=0), axis=-1) * FPS
    out.append((f"wrist speed < 15 m/s ({v[:, [20, 21]].max():.1f})", v[:, [20, 21]].max() < 15))
    out.append((f"pelvis speed < 8 m/s ({v[:, 0].max():.1f})", v[:, 0].max() < 8))
    # no hand through the trunk or head: each wrist stays > 8 cm from the spine, neck and head joints
    gap = min(np.linalg.norm(raw[:, w, None] - raw[:, SPINE_AND_HEAD], axis=-1).min() for w in (20, 21))
    out.append((f"hands clear the trunk and head: {gap:.3f} m", gap > 0.08))
    pelvis = j[:, 0, 1] - STAND_Y
    lean = _ahead(j, 12, 0, fwd_ax)          # neck ahead of the pelvis: the trunk's forward lean, m
    steps = p.get("steps", 1)
    facts = dict(fwd=m["fwd"], left=m["left"], drop=float(-np.median(pelvis[_middle(j)])), rise=m["rise"],
                 lean=float(np.median(lean[_middle(j)])), air=m["airborne"])
    if family != "hop_on_one_foot" and not (family == "march" and p["in_place"]):
        out.append(("in a straight line", abs(m["left"]) < 0.15 + 0.1 * abs(m["fwd"])))
    if family == "sneak":
        # a crouch walk of `steps` steps: careful steps (0.15-0.6 m), the pelvis 15-25 cm low (+-3 cm for the
        # gait's bob), the trunk pitched forward 18-26 degrees (the neck ~0.5 m above the pelvis: > 0.1 m ahead),
        # back up to standing at the end
        out.append((f"moves forward 0.15-0.6 m a step ({m['fwd'] / steps:.2f})", 0.15 * steps < m["fwd"] < 0.6 * steps))
        out.append((f"crouched: pelvis 12-28 cm low mid-walk ({facts['drop']:.3f})", 0.12 < facts["drop"] < 0.28))
        out.append((f"trunk leans forward mid-walk ({facts['lean']:.2f} m)", facts["lean"] > 0.1))
        out.append(("stands up at the end", abs(m["end_drop"]) < 0.04))
        speed = m["fwd"] / (len(j) / FPS)
        out.append((f"slow: < 0.7 m/s over the clip ({speed:.2f})", speed < 0.7))
        # hands up in front: the wrists above the hips and ahead of the pelvis mid-walk
        mid = _middle(j)
        for side, k in SIDE.items():
            ahead = np.median(_ahead(j, k["wrist"], 0, fwd_ax)[mid])
            up = np.median(j[mid, k["wrist"], 1] - j[mid, 0, 1])
            out.append((f"{side} hand held up in front ({ahead:.2f} ahead, {up:.2f} up)", ahead > 0.15 and up > 0.0))
        facts["fact"] = facts["drop"]
    if family == "limp":
        # an uneven walk: the bad leg's stance is hurried (shorter than the sound one's), the trunk leans over it
        out.append((f"moves forward 0.2-0.7 m a step ({m['fwd'] / steps:.2f})", 0.2 * steps < m["fwd"] < 0.7 * steps))
        bad, good = p["side"], "left" if p["side"] == "right" else "right"
        walk = slice(int(0.25 * len(j)), int(0.8 * len(j)))
        on_bad, on_good = _planted(j[walk], bad).sum(), _planted(j[walk], good).sum()
        out.append((f"stands shorter on the {bad} foot ({on_bad} vs {on_good} frames)", on_bad < 0.85 * on_good))
        sign = 1.0 if bad == "left" else -1.0
        tilt = sign * _ahead(j, 12, 0, left_ax)  # neck toward the bad side of the pelvis, m
        # (13-18 degrees of lean put the neck ~8-12 cm over; it leans the other way far less)
        out.append((f"the trunk dips toward the {bad} leg ({tilt.max():.3f} m)",
                    tilt.max() > 0.06 and tilt.max() > -tilt.min() + 0.03))
        facts["fact"] = on_bad / max(on_good, 1)
    if family == "tiptoe":
        # on the toes: through the walk even the lower ankle stays above a flat foot's (~5-6 cm; a 28-36 degree
        # heel raise lifts it to ~10 cm), the pelvis rises; short steps (0.1-0.4 m), quick (> 1.6 steps/s)
        mid = _middle(j, 0.25, 0.75)
        low_ankle = j[mid][:, [L_ANKLE, R_ANKLE], 1].min(axis=1)
        out.append((f"heels up: lower ankle > 8 cm in 95% of mid frames ({np.percentile(low_ankle, 5):.3f})",
                    np.percentile(low_ankle, 5) > 0.08))
        out.append((f"the pelvis rises onto the toes ({np.median(pelvis[mid]):.3f})", np.median(pelvis[mid]) > 0.03))
        out.append((f"short steps: 0.1-0.4 m ({m['fwd'] / steps:.2f})", 0.1 * steps < m["fwd"] < 0.4 * steps))
        # the arms held a little out from the sides
        spread = np.median(np.linalg.norm(j[mid, 20, [0, 2]] - j[mid, 21, [0, 2]], axis=-1))
        out.append((f"arms a little out: wrists > 0.5 m apart ({spread:.2f})", spread > 0.5))
        facts["fact"] = float(np.percentile(low_ankle, 5))
    if family == "skip":
        # step-hops: a small flight in each (counted as runs of airborne frames), the free knee up high (the foot
        # > 25 cm up), arms swung high (the wrist above the shoulder), forward > 0.3 m a skip
        flights = len([r for r in _runs(_airborne(j)) if r[1] - r[0] >= 1])
        # (the first skip ramps in from standing without leaving the floor)
        out.append((f"a small flight each skip ({flights} for {steps})", steps - 1 <= flights <= 2 * steps + 1))
        out.append((f"the flights are small: < 20 cm ({m['airborne']:.3f})", 0.008 < m["airborne"] < 0.2))
        for side in SIDE:
            out.append((f"the {side} knee comes up ({m[f'foot_up_{side}']:.2f})", m[f"foot_up_{side}"] > 0.25))
            out.append((f"the {side} arm swings high ({m[f'hand_up_{side}']:.2f})", m[f"hand_up_{side}"] > 0.0))
        out.append((f"moves forward 0.3-1.2 m a skip ({m['fwd'] / steps:.2f})", 0.3 * steps < m["fwd"] < 1.2 * steps))
        facts["fact"] = flights
    if family == "march":
        # knees to a level thigh (the knee within 12 cm of the hip's height), arms to about shoulder height
        # (the wrist within 20 cm below the shoulder), in place or forward
        for side, k in SIDE.items():
            knee = (j[:, KNEE[side], 1] - j[:, 0, 1]).max()
            out.append((f"the {side} knee comes up to the hip ({knee:.2f})", knee > -0.12))
            up = m[f"hand_up_{side}"]
            out.append((f"the {side} arm swings to shoulder height ({up:.2f})", up > -0.2))
        if p["in_place"]:
            out.append((f"in place: moves < 0.3 m ({m['dist']:.2f})", m["dist"] < 0.3))
        else:
            out.append((f"moves forward 0.2-0.7 m a step ({m['fwd'] / steps:.2f})",
                        0.2 * steps < m["fwd"] < 0.7 * steps))
        facts["fact"] = min((j[:, KNEE[s], 1] - j[:, 0, 1]).max() for s in SIDE)
    if family == "stumble":
        # a walk with a lurch: the trunk pitches 22-32 degrees at the trip (the neck > 0.15 m ahead of the pelvis;
        # walking it is ~0.05), the arms thrown out (wrists > 0.25 m out from the shoulders, sideways or forward),
        # the catch steps faster than the walk, and upright again at the end
        out.append((f"moves forward 0.3-1.2 m a step ({m['fwd'] / steps:.2f})", 0.3 * steps < m["fwd"] < 1.2 * steps))
        out.append((f"lurches forward ({lean.max():.2f} m)", lean.max() > 0.15))
        out.append((f"upright again at the end ({np.abs(lean[-5:]).max():.2f})", np.abs(lean[-5:]).max() < 0.1))
        for side, k in SIDE.items():
            reach = np.linalg.norm(j[:, k["wrist"], [0, 2]] - j[:, k["shoulder"], [0, 2]], axis=-1).max()
            out.append((f"the {side} arm is thrown out ({reach:.2f})", reach > 0.25))
        speed = np.linalg.norm(np.diff(j[:, 0, [0, 2]], axis=0), axis=-1) * FPS
        trip = int(p["trip_at"] * FPS)
        burst = speed[trip:trip + int(0.8 * FPS)].max()
        walking = np.median(speed[max(0, trip - int(1.0 * FPS)):trip])
        out.append((f"the catch steps are faster ({burst:.2f} vs {walking:.2f} m/s)", burst > 1.3 * walking))
        if not p["walks_on"]:
            tail = np.linalg.norm(j[-1, 0, [0, 2]] - j[-10, 0, [0, 2]])
            out.append((f"stands still at the end ({tail:.3f} m in 0.45 s)", tail < 0.1))
        facts["fact"] = float(lean.max())
    if family == "hop_on_one_foot":
        # on the spot; the other foot held up behind (its ankle > 15 cm up and behind the hopping one) while
        # each of `reps` hops leaves the floor (a 6-12 cm flight)
        side, other = p["side"], "left" if p["side"] == "right" else "right"
        out.append((f"in place: moves < 0.4 m ({m['dist']:.2f})", m["dist"] < 0.4))
        held = j[:, ANKLE_UP[other], 1] > 0.15
        behind = _ahead(j, ANKLE_UP[side], ANKLE_UP[other], fwd_ax)[held]
        out.append((f"the {other} foot is held up ({held.mean():.2f} of the clip)", held.mean() > 0.4))
        out.append((f"... behind ({np.median(behind):.2f} m)", np.median(behind) > 0.1))
        out.append((f"the {side} foot stays low ({m[f'foot_up_{side}']:.2f})", m[f"foot_up_{side}"] < 0.3))
        hops = len([r for r in _runs(_airborne(j)) if r[1] - r[0] >= 2])
        out.append((f"hops {p['reps']} times ({hops})", hops == p["reps"]))
        out.append((f"each hop leaves the floor > 3 cm ({m['airborne']:.3f})", m["airborne"] > 0.03))
        facts["fact"] = hops
    return out, facts


def test_the_module_registers_its_families():
    assert NAMES == ["sneak", "limp", "tiptoe", "skip", "march", "stumble", "hop_on_one_foot"]
    assert all(n in FAMILIES for n in NAMES) and not styles.LAST_ONLY


@pytest.mark.parametrize("family", NAMES)
def test_each_style_does_what_its_captions_say(family):
    index = FAMILIES.index(family)
    broken, rows = [], []
    for seed in range(8):
        clip = C.generate_clip((family,), np.random.default_rng([31, index, seed]))
        p = clip.segments[0].params
        out, facts = measure(family, p, through_features(clip.joints), clip.joints)
        broken += [f"seed [31, {index}, {seed}] {family} {p}: not {what}" for what, ok in out if not ok]
        rows.append([facts[k] for k in ("fwd", "left", "drop", "rise", "lean", "air", "fact")])
    med = np.median(rows, axis=0)
    print(f"\n{'family':16s}    fwd   left   drop   rise   lean    air   fact   (medians of 8 clips)")
    print(f"{family:16s}" + "".join(f"{v:7.2f}" for v in med))
    assert not broken, "\n".join(broken)
