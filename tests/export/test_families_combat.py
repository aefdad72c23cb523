"""The combat families (mogo_export/data/procedural/combat.py) do what their captions say: blocks raise both
forearms in front of the face (or across the body) and flinch back, dodges throw the pelvis 0.3-0.6 m to the
named side in one quick move, hit reactions snap the upper body and stagger the named number of steps back or
forward, roundhouse kicks swing the named foot up and around while the hips pivot, uppercuts drive the named
fist up from the hip to above the shoulder, close to the body."""
import numpy as np
import pytest

from mogo_export.data.procedural import clips as C, combat
from mogo_export.data.procedural.pose import FPS

from family_facts import SIDE, STAND_Y, motion_facts, rises, through_features

FAMILIES = [f.__name__ for f in combat.FAMILIES]
SIGN = {"left": 1.0, "right": -1.0}
BODY = [0, 3, 6, 9, 12, 15]  # pelvis, spine, neck, head: what a hand must not pass through




def measure(j):
    """What the promises below read, on joints through the features: motion_facts, plus per frame the
    heading (deg, hips and shoulders as motion_facts, from frame 0's), the pelvis path along the initial
    facing and to its left, every joint's offset from the pelvis along those two axes, peak speeds, and
    foot lift-offs."""
    m = motion_facts(j)
    across = (j[:, 2] - j[:, 1]) + (j[:, 17] - j[:, 16])
    heading = np.unwrap(np.arctan2(across[:, 2], -across[:, 0]))
    h0 = heading[:3].mean()
    axes = np.array([[np.sin(h0), np.cos(h0)], [np.cos(h0), -np.sin(h0)]]).T  # (x, z) -> (fwd, left)
    root = (j[:, 0, [0, 2]] - j[0, 0, [0, 2]]) @ axes
    m["path_fwd"], m["path_left"] = root[:, 0], root[:, 1]
    m["heading"] = np.degrees(heading - h0)
    m["off"] = (j[..., [0, 2]] - j[:, :1, [0, 2]]) @ axes
    m["pelvis_y"] = j[:, 0, 1]
    v = np.linalg.norm(np.diff(j, axis=0), axis=-1) * FPS
    m["v_wrist"], m["v_pelvis"], m["v_ankle"] = v[:, [20, 21]].max(), v[:, 0].max(), v[:, [7, 8]].max()
    m["hand_body"] = min(np.linalg.norm(j[:, w, None] - j[:, BODY], axis=-1).min() for w in (20, 21))
    # feet: lift-offs of each ankle 4 cm above where it stands
    m["liftoffs"] = sum(rises(j[:, a, 1] - j[0, a, 1], 0.04, 0.015) for a in (7, 8))
    return m


def promises(family, p, m):
    """(promise, kept) for what `family`'s captions say, with bounds from combat.py's definitions."""
    out = [("wrists < 15 m/s, pelvis < 8 m/s, ankles < 20 m/s (human ranges)",
            m["v_wrist"] < 15 and m["v_pelvis"] < 8 and m["v_ankle"] < 20),
           ("no hand through the trunk or head (> 8 cm)", m["hand_body"] > 0.08)]
    off = m["off"]
    if family == "block":
        out.append(("stays in place: moves < 0.15 m, turns < 10 deg", m["dist"] < 0.15 and abs(m["turn"]) < 10))
        out.append(("feet stay planted", m["foot_up_left"] < 0.12 and m["foot_up_right"] < 0.12))
        out.append(("never reaches out like a punch (< 0.42 m)", max(m["reach_left"], m["reach_right"]) < 0.42))
        # the head comes back at least 4 cm from its most forward (the guard) when the block lands
        head = off[:, 15, 0]
        out.append(("flinches back: head 4+ cm back", head.max() - head[len(head) // 4:].min() > 0.04))
        if p["height"] == "high":  # forearms upright before the face: wrists 15+ cm above the shoulders
            up = np.minimum(m["wy_left"], m["wy_right"])
            out.append(("both wrists rise 15+ cm above the shoulders", up.max() > 0.15))
            top = int(np.argmax(up))
            gap = off[top, [20, 21], 0] - off[top, 15, 0]
            out.append(("in front of the face (3-30 cm)", (gap > 0.03).all() and (gap < 0.3).all()))
            out.append((f"blocks {p['reps']} times", rises(up, 0.15, 0.08) == p["reps"]))
        else:  # forearms stacked across the stomach and chest: each wrist past the midline, below the shoulders
            crossed = np.minimum(-off[:, 20, 1], off[:, 21, 1])
            out.append(("forearms cross in front of the body (wrists 3+ cm past the midline)", crossed.max() > 0.03))
            held = crossed > 0.0
            out.append(("below the shoulders", held.any() and np.maximum(m["wy_left"], m["wy_right"])[held].max() < 0))
            out.append(("in front of the trunk (15+ cm)",
                        held.any() and (off[held][:, [20, 21], 0] - off[held][:, [9], 0]).min() > 0.15))
            out.append((f"blocks {p['reps']} times", rises(crossed, 0.03, -0.03) == p["reps"]))
    if family.startswith("dodge_"):
        sg = SIGN[p["side"]]
        shift = sg * m["path_left"]
        out.append(("the pelvis shifts 0.25-0.65 m to the named side", 0.25 < shift.max() < 0.65))
        out.append(("sideways, not forward or back (< 0.12 m)", np.abs(m["path_fwd"]).max() < 0.12))
        start = int(np.argmax(shift > 0.02))
        out.append(("in one quick move: 80% of it within 0.6 s", shift[start:start + int(0.6 * FPS)].max()
                    > 0.8 * shift.max()))
        out.append(("the trunk leans that way: head 8+ cm further out than the pelvis",
                    (sg * off[:, 15, 1]).max() > 0.08))
        out.append(("knees bent: the pelvis drops 4+ cm", m["drop"] > 0.04))
        out.append(("keeps facing ahead (< 10 deg)", np.abs(m["heading"]).max() < 10))
        if p["back"]:
            out.append(("comes back: ends within 0.1 m of the start", abs(m["left"]) < 0.1))
        else:
            out.append(("stays there: ends 0.25-0.65 m aside", 0.25 < sg * m["left"] < 0.65))
    if family.startswith("hit_reaction_"):
        n = p["steps"]
        d = -1.0 if family.endswith("front") else 1.0
        # stagger steps: 0.2-0.32 m (front), 0.25-0.4 m (back), with room for the sway
        lo, hi = (0.15, 0.4) if d < 0 else (0.2, 0.48)
        out.append((f"moves {'back' if d < 0 else 'forward'} {lo}-{hi} m a step", lo * n < d * m["fwd"] < hi * n))
        out.append(("in a straight line", abs(m["left"]) < 0.1))
        out.append((f"{n} steps and a closing step", m["liftoffs"] == n + 1))
        head = off[:, 15, 0]  # the head thrown against the step: 10+ cm from where it stood over the pelvis
        out.append(("the head snaps " + ("back" if d < 0 else "forward"), (d * (head - head[0])).max() > 0.1))
        if d < 0:
            out.append(("arms flung up", min(m["hand_up_left"], m["hand_up_right"]) > -0.15))
        else:
            reach = off[:, [20, 21], 0] - off[:, [16, 17], 0]
            out.append(("arms thrown back: wrists 10+ cm behind the shoulders", reach.min() < -0.1))
            # looking back over a shoulder twists the shoulders 15+ degrees against the hips toward it
            shoulders = np.degrees(np.unwrap(np.arctan2(*(m["shoulder_line"].T))))
            hips = np.degrees(np.unwrap(np.arctan2(*(m["hip_line"].T))))
            twist = SIGN[p["look"]] * (shoulders - hips - (shoulders - hips)[0])
            out.append((f"looks back over the {p['look']} shoulder", twist.max() > 15))
        out.append(("keeps facing ahead (< 15 deg at the end)", abs(m["turn"]) < 15))
    if family == "roundhouse_kick":
        side, other = p["side"], "left" if p["side"] == "right" else "right"
        lo, hi = (0.8, 1.2) if p["height"] == "middle" else (1.15, 1.6)  # ankle height: waist .. head
        out.append((f"the {side} foot kicks up {lo}-{hi} m", lo < m[f"foot_up_{side}"] < hi))
        out.append((f"the {other} foot stays down", m[f"foot_up_{other}"] < 0.12))
        ankle = SIDE[side]["ankle"]
        ankle_y = m["ankle_y"][side]
        top = int(np.argmax(ankle_y))
        out.append(("the foot swings around to the front (0.5+ m ahead)", off[top, ankle, 0] > 0.5))
        # the hips pivot over the standing foot, turning away from the kicking leg, 40+ degrees
        out.append(("the body pivots 40+ deg on the standing foot", (-SIGN[side] * m["heading"]).max() > 40))
        out.append(("and turns back to face ahead (< 15 deg)", abs(m["turn"]) < 15))
        out.append(("stays on the spot (< 0.25 m)", m["dist"] < 0.25))
        out.append((f"kicks {p['reps']} times", rises(ankle_y, 0.5, 0.2) == p["reps"]))
    if family == "uppercut":
        side, other = p["side"], "left" if p["side"] == "right" else "right"
        wy = m[f"wy_{side}"]
        out.append((f"the {side} fist ends 12+ cm above the shoulder", wy.max() > 0.12))
        out.append((f"the {other} fist stays in guard", m[f"wy_{other}"].max() < 0.12))
        w = SIDE[side]["wrist"]
        top = int(np.argmax(wy))
        low = max(0, top - int(0.5 * FPS)) + int(np.argmin(wy[max(0, top - int(0.5 * FPS)):top + 1]))
        up, fwd = wy[top] - wy[low], off[top, w, 0] - off[low, w, 0]
        out.append(("rising from the hip: 35+ cm up", up > 0.35))
        out.append(("mostly upward: forward travel < half the rise", abs(fwd) < 0.5 * up))
        out.append(("close to the body, not a straight punch (< 0.4 m reach)", m[f"reach_{side}"] < 0.4))
        out.append(("the knees dip (pelvis 3+ cm)", m["drop"] > 0.03))
        out.append(("stays in place", m["dist"] < 0.1))
        out.append((f"{p['reps']} uppercuts", rises(wy, 0.12, 0.0) == p["reps"]))
    return out


def _facts(j):
    m = measure(j)
    for side, k in SIDE.items():
        m[f"wy_{side}"] = j[:, k["wrist"], 1] - j[:, k["shoulder"], 1]
    m["ankle_y"] = {side: j[:, k["ankle"], 1] for side, k in SIDE.items()}
    m["shoulder_line"] = (j[:, 17] - j[:, 16])[:, [2, 0]] * [1, -1]
    m["hip_line"] = (j[:, 2] - j[:, 1])[:, [2, 0]] * [1, -1]
    return m


@pytest.fixture(scope="module")
def clips():
    out = {}
    for index, family in enumerate(FAMILIES):
        out[family] = [C.generate_clip((family,), np.random.default_rng([31, index, seed])) for seed in range(8)]
    return out


def test_every_combat_family_does_what_its_captions_say(clips):
    table, broken = {}, []
    for index, family in enumerate(FAMILIES):
        rows = []
        for seed, clip in enumerate(clips[family]):
            j = through_features(clip.joints)
            m = _facts(j)
            p = clip.segments[0].params
            broken += [f"seed [31, {index}, {seed}] {family} {p}: not {what}"
                       for what, ok in promises(family, p, m) if not ok]
            shift = np.abs(m["path_left"]).max()
            rows.append([m["dist"], m["fwd"], m["left"], shift, m["turn"], np.abs(m["heading"]).max(), m["drop"],
                         max(m["foot_up_left"], m["foot_up_right"]), max(m["hand_up_left"], m["hand_up_right"]),
                         max(m["reach_left"], m["reach_right"]), m["v_wrist"], m["v_pelvis"]])
        table[family] = np.median(rows, axis=0)
    print("\nfamily               dist    fwd   left  shift   turn  maxhd   drop  footup handup  reach  vwrist vpelv"
          "   (medians of 8 clips)")
    for family, med in table.items():
        print(f"{family:19s}" + "".join(f"{v:7.2f}" for v in med))
    assert not broken, "\n".join(broken)


def test_sided_families_mirror():
    """dodge_left and dodge_right are one motion mirrored: the same draw moves the pelvis the same distance
    the opposite way."""
    a = C.generate_clip(("dodge_left",), np.random.default_rng(3))
    b = C.generate_clip(("dodge_right",), np.random.default_rng(3))
    ma, mb = _facts(through_features(a.joints)), _facts(through_features(b.joints))
    assert ma["path_left"].max() == pytest.approx(-mb["path_left"].min(), abs=0.03)
    assert ma["path_left"].max() > 0.25
