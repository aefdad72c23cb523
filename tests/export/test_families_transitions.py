"""The getting-down families (mogo_export/data/procedural/transitions.py, falls.py) do what their captions say: measured
on 8 clips of each family (through the features, and as built for heights above the floor and speeds), with
bounds taken from each family's definition, not fitted to what the generator happens to output. Also the
grounding they rely on: a body resting on knees, seat or hands stays on the floor and does not slide."""
import numpy as np
import pytest

from mogo_export.data.procedural import clips as C, falls, families, transitions
from mogo_export.data.procedural.grounding import pose_to_joints
from mogo_export.data.procedural.pose import FPS, Pose

from family_facts import STAND_Y, motion_facts, through_features

FAMILIES = list(families.FAMILIES)
NAMES = [f.__name__ for f in transitions.FAMILIES + falls.FAMILIES]
SPINE_AND_HEAD = [0, 3, 6, 9, 12, 15]
KNEE = {"left": 4, "right": 5}
ANKLE = {"left": 7, "right": 8}
TOE = {"left": 10, "right": 11}
WRIST = {"left": 20, "right": 21}
OTHER = {"left": "right", "right": "left"}


def _axes(j):
    """The body's forward and left unit vectors on the floor (x, z) at frame 0, from the hips and shoulders."""
    across = (j[0, 2] - j[0, 1]) + (j[0, 17] - j[0, 16])
    h = np.arctan2(across[2], -across[0])
    return np.array([np.sin(h), np.cos(h)]), np.array([np.cos(h), -np.sin(h)])


def _head_yaw(j):
    """Per frame, degrees the head points left of the pelvis's facing (from the neck -> head bone and the hips)."""
    across = j[:, 2] - j[:, 1]
    face = np.arctan2(across[:, 2], -across[:, 0])
    look = j[:, 15] - j[:, 12]
    return np.degrees(np.unwrap(np.arctan2(look[:, 0], look[:, 2]) - face))


def _runs(mask):
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _still(raw, joint, frames):
    """How far (m, on the floor) a joint moves over `frames` of the built clip."""
    xz = raw[frames, joint][:, [0, 2]]
    return float(np.linalg.norm(xz - xz[0], axis=-1).max())


def _to_segment(p, a, b):
    """Distance from point p to the segment a-b."""
    u = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return float(np.linalg.norm(p - a - u * (b - a)))


def measure(family, p, j, raw):
    """(promise, kept) pairs and the facts measured, for clip joints j (through the features) and raw (as built)."""
    m = motion_facts(j)
    fwd_ax, _ = _axes(raw)
    out = [("keeps its heading within 15 deg", abs(m["turn"]) < 15)]
    # people-like: wrists under 15 m/s, pelvis under 8 m/s; nothing below the floor (the generic -1 cm)
    v = np.linalg.norm(np.diff(raw, axis=0), axis=-1) * FPS
    out.append((f"wrist speed < 15 m/s ({v[:, [20, 21]].max():.1f})", v[:, [20, 21]].max() < 15))
    out.append((f"pelvis speed < 8 m/s ({v[:, 0].max():.1f})", v[:, 0].max() < 8))
    out.append((f"no joint below the floor ({raw[..., 1].min():.3f})", raw[..., 1].min() > -0.01))
    # no hand through the trunk or head: each wrist stays > 8 cm from the spine, neck and head joints
    gap = min(np.linalg.norm(raw[:, w, None] - raw[:, SPINE_AND_HEAD], axis=-1).min() for w in (20, 21))
    out.append((f"hands clear the trunk and head: {gap:.3f} m", gap > 0.08))
    pelvis = raw[:, 0, 1] - STAND_Y
    low = -pelvis > 0.3
    T = len(raw)
    end = slice(T - 10, T)                      # the last half second: what the clip ends in
    neck_up = float(raw[-1, 12, 1] - raw[-1, 0, 1])
    facts = dict(dist=m["dist"], turn=m["turn"], drop=m["drop"], end_drop=m["end_drop"],
                 low_s=low.sum() / FPS, end_pelvis=float(raw[-1, 0, 1]))
    if family == "crouch":
        # one drop into a low crouch (knees bent 125-140 degrees: the pelvis 0.45-0.55 m down), held for the
        # sampled hold (the descent and rise add ~0.3 s above the 0.3 m line), then standing again, in place
        runs = _runs(low)
        out.append(("goes low once: the pelvis > 0.35 m down, one spell", m["drop"] > 0.35 and len(runs) == 1))
        out.append((f"holds it ~{p['hold']} s", low.sum() / FPS > 0.8 * p["hold"]))
        out.append(("and stands back up", abs(m["end_drop"]) < 0.05))
        out.append(("in place: moves < 0.3 m", m["dist"] < 0.3))
        # the feet stay where they are (crouching is not a sneak)
        out.append(("the feet stay put", max(_still(raw, TOE[s], slice(0, T)) for s in TOE) < 0.05))
        # looking around: the head turns 45-65 deg (with the shoulders) each look: > 30 deg off the hips
        yaw = _head_yaw(raw)[low]
        facts["look"] = float(np.abs(yaw).max())
        out.append((f"looks around: head turns > 30 deg ({facts['look']:.0f})", facts["look"] > 30))
        # heels up: on the balls of the feet the ankle rises > 9 cm (5-6 cm standing); flat: it stays < 8 cm
        ankle = float(np.median(raw[low][:, [7, 8], 1]))
        facts["ankle"] = ankle
        out.append(("heels up" if p["heels_up"] else "heels down", ankle > 0.09 if p["heels_up"] else ankle < 0.08))
        if "side" in p:  # the fingertips near the floor: the wrist (a hand's length above them) < 25 cm up
            s = p["side"]
            wr = raw[low][:, [WRIST[s], WRIST[OTHER[s]]], 1].min(axis=0)
            facts["hand"] = float(wr[0])
            out.append((f"the {s} hand reaches the floor", wr[0] < 0.25 and wr[1] - wr[0] > 0.1))
    if family == "kneel_down":
        s = p["side"]
        # a knee on the floor: the knee joint is ~5 cm above it (its thickness); the pelvis a thigh above that
        knee_end = raw[end, KNEE[s], 1].max()
        facts["knee"] = float(knee_end)
        out.append((f"kneels on the {s} knee: it ends on the floor", knee_end < 0.08))
        out.append(("stays kneeling: the pelvis ends 0.3-0.55 m down", 0.3 < m["end_drop"] < 0.55))
        out.append(("kneels upright: the neck > 0.4 m above the pelvis", neck_up > 0.4))
        other = raw[end, KNEE[OTHER[s]], 1].max()
        if p["both"]:
            out.append(("both knees end on the floor", other < 0.08))
        else:  # on one knee: the other foot flat on the floor in front, its knee up about hip height
            out.append(("the other knee up", other > 0.3))
            out.append(("the other foot flat in front", raw[end, ANKLE[OTHER[s]], 1].max() < 0.08 and
                        (raw[-1, TOE[OTHER[s]], [0, 2]] - raw[-1, KNEE[s], [0, 2]]) @ fwd_ax > 0.3))
        # the kneeling leg steps back: its toes end > 0.3 m behind where they stood
        back = (raw[-1, TOE[s], [0, 2]] - raw[0, TOE[s], [0, 2]]) @ fwd_ax
        facts["step_back"] = float(back)
        out.append((f"the {s} leg steps back ({back:.2f} m)", back < -0.3))
        # what rests on the floor stays where it landed (no sliding knee)
        down = np.flatnonzero(raw[:, KNEE[s], 1] < 0.06)
        slide = _still(raw, KNEE[s], slice(down[0], T)) if len(down) else np.inf
        facts["knee_slide"] = slide
        out.append((f"the knee on the floor does not slide ({slide:.3f} m)", slide < 0.03))
    if family == "sit_on_ground":
        # sitting on the floor: the pelvis joint ~9-10 cm above it, trunk up (not lying), staying there
        out.append(("sits on the floor: the pelvis ends < 0.15 m up", raw[-1, 0, 1] < 0.15))
        out.append(("seated, not lying: the neck > 0.35 m above the pelvis", neck_up > 0.35))
        sat = np.flatnonzero(raw[:, 0, 1] < 0.12)
        slide = _still(raw, 0, slice(sat[0], T)) if len(sat) else np.inf
        facts["seat_slide"] = slide
        out.append((f"the seat does not slide once down ({slide:.3f} m)", slide < 0.03))
        ahead = min((raw[-1, ANKLE[s], [0, 2]] - raw[-1, 0, [0, 2]]) @ fwd_ax for s in ANKLE)
        if p["legs"] == "straight":
            # legs stretched out: ankles a leg's length (~0.8 m) ahead, knees low; the hands on the floor behind
            out.append((f"legs stretched out: ankles > 0.6 m ahead ({ahead:.2f})", ahead > 0.6))
            out.append(("knees low", raw[-1, [4, 5], 1].max() < 0.3))
            behind = max((raw[-1, WRIST[s], [0, 2]] - raw[-1, 0, [0, 2]]) @ fwd_ax for s in WRIST)
            out.append(("leaning back on both hands on the floor behind",
                        raw[end][:, [20, 21], 1].max() < 0.08 and behind < -0.1))
        else:
            # knees drawn up (above 0.3 m), the feet flat on the floor well short of a leg's length ahead
            out.append((f"knees drawn up, feet near the seat ({ahead:.2f} m)", raw[-1, [4, 5], 1].min() > 0.3
                        and ahead < 0.65 and raw[-1, [7, 8], 1].max() < 0.08))
            # the arms around the shins: each wrist within 15 cm of a shin (knee -> ankle), in front of them
            hug = max(min(_to_segment(raw[-1, WRIST[s]], raw[-1, KNEE[k]], raw[-1, ANKLE[k]]) for k in KNEE)
                      for s in WRIST)
            facts["hug"] = hug
            out.append((f"hugs the knees: each wrist < 0.15 m from a shin ({hug:.2f})", hug < 0.15))
    if family == "collapse_holding_leg":
        s, o = p["side"], OTHER[p["side"]]
        shin = lambda f, w: _to_segment(raw[f, w], raw[f, KNEE[s]], raw[f, ANKLE[s]])  # noqa: E731
        # first it stands on the good leg holding the hurt one up (its ankle ~0.3 m up), hands on that shin
        up = np.flatnonzero((raw[:, ANKLE[s], 1] > 0.2) & (raw[:, 0, 1] > STAND_Y - 0.1))
        facts["held_up_s"] = len(up) / FPS
        out.append((f"holds the {s} leg up standing on the other (> 0.3 s)", len(up) / FPS > 0.3
                    and raw[up][:, ANKLE[o], 1].max() < 0.08))
        grip = max(min(shin(f, w) for f in up) for w in WRIST.values()) if len(up) else np.inf
        facts["grip"] = grip
        out.append((f"both hands on the {s} shin while it is up ({grip:.2f} m)", grip < 0.15))
        # collapses: ends lying on the back on the floor (the pelvis and upper back ~10 cm up: their thickness),
        # the head raised a little (the neck < 0.25 m up), not standing again
        out.append(("ends on the ground: the pelvis < 0.13 m up", raw[-1, 0, 1] < 0.13))
        out.append(("lying on the back: the upper back < 0.15 m, the neck < 0.25 m up",
                    raw[-1, 9, 1] < 0.15 and raw[-1, 12, 1] < 0.25))
        # ... the hurt leg held up off the floor, the hands still on its shin; the other foot flat on the floor
        hold = max(shin(-1, w) for w in WRIST.values())
        facts["end_grip"] = hold
        out.append((f"still holding the {s} leg, off the floor ({hold:.2f} m)", hold < 0.15
                    and raw[-1, ANKLE[s], 1] > 0.25 and raw[-1, ANKLE[o], 1] < 0.08))
        # what carries the body stays put: the good foot never moves, the seat does not slide once down
        facts["foot_slide"] = _still(raw, TOE[o], slice(0, T))
        out.append((f"the {o} foot stays where it stands ({facts['foot_slide']:.3f} m)", facts["foot_slide"] < 0.05))
        sat = np.flatnonzero(raw[:, 0, 1] < 0.1)
        slide = _still(raw, 0, slice(sat[0], T)) if len(sat) else np.inf
        facts["seat_slide"] = slide
        out.append((f"the seat does not slide once down ({slide:.3f} m)", slide < 0.03))
    if family in ("fall_and_get_up", "lie_down_and_get_up"):
        # both end standing where they stood up, at standing height (STAND_Y: the neutral pose's pelvis)
        facts["end_pelvis_err"] = abs(float(raw[-1, 0, 1]) - STAND_Y)
        out.append((f"ends standing at standing height ({raw[-1, 0, 1]:.2f} m)", facts["end_pelvis_err"] < 0.03
                    and neck_up > 0.45 and raw[-1, [7, 8], 1].max() < 0.08))
        out.append(("goes down low once (one spell > 0.3 m down)", len(_runs(low)) == 1))
        # how fast the body gets down: from 0.1 m below standing to the seat on the floor (pelvis < 0.13 m)
        start = np.flatnonzero(raw[:, 0, 1] < STAND_Y - 0.1)[0]
        floor = np.flatnonzero(raw[:, 0, 1] < 0.13)
        facts["down_s"] = (floor[0] - start) / FPS if len(floor) else np.inf
        fwd = (raw[:, 0, [0, 2]] - raw[0, 0, [0, 2]]) @ fwd_ax     # the pelvis along the start facing
        # smooth: no joint accelerates past 200 m/s^2 (kicks and landings reach ~160), the pelvis past 100
        # (the generic bounds for families that land hard: a seat or knees hitting the floor)
        acc = np.linalg.norm(np.diff(raw, 2, axis=0), axis=-1) * FPS * FPS
        facts["acc"] = float(acc.max())
        out.append((f"smooth: joint acc {acc.max():.0f}, pelvis {acc[:, 0].max():.0f} m/s^2",
                    acc.max() < 200 and acc[:, 0].max() < 100))
    if family == "fall_and_get_up" and p["way"] == "backward":
        # a fall, not a sit: from a buckle to the seat on the floor in < 1 s (buckle + drop: 0.75-0.9 s)
        out.append((f"falls fast: standing to the floor in < 1 s ({facts['down_s']:.2f})", facts["down_s"] < 1.0))
        # lands behind the feet: the seat comes down > 0.4 m behind where the pelvis stood (a thigh and shin)
        out.append((f"falls backward ({fwd.min():.2f} m)", fwd.min() < -0.4))
        # lies on the back: the pelvis and upper back on the floor (joints ~10 cm up: their thickness), the head
        # down too, for the sampled lie (plus part of the roll onto the back and of the sit-up: < 1 s more)
        lying = (raw[:, 0, 1] < 0.13) & (raw[:, 9, 1] < 0.15) & (raw[:, 15, 1] < 0.15)
        facts["lie_s"] = lying.sum() / FPS
        out.append((f"lies on the back ~{p['lie']} s ({facts['lie_s']:.2f})",
                    0.9 * p["lie"] < facts["lie_s"] < p["lie"] + 1.0 and len(_runs(lying)) == 1))
        # ... knees up, both feet flat on the floor; the hands down on the floor beside the body
        mid = np.flatnonzero(lying)[len(np.flatnonzero(lying)) // 2]
        out.append(("lying with the knees up, feet flat", raw[mid, [4, 5], 1].min() > 0.25
                    and raw[mid, [7, 8], 1].max() < 0.08))
        out.append(("hands on the floor beside the body", raw[mid, [20, 21], 1].max() < 0.08))
        # the feet never move (they carry the fall and the getting up); the seat does not slide once down
        facts["foot_slide"] = max(_still(raw, TOE[s], slice(0, T)) for s in TOE)
        out.append((f"the feet stay put ({facts['foot_slide']:.3f} m)", facts["foot_slide"] < 0.05))
        sat = np.flatnonzero(raw[:, 0, 1] < 0.12)
        facts["seat_slide"] = _still(raw, 0, slice(sat[0], sat[-1] + 1)) if len(sat) else np.inf
        out.append((f"the seat does not slide ({facts['seat_slide']:.3f} m)", facts["seat_slide"] < 0.03))
        out.append(("gets up where it fell: ends < 0.15 m from the start", m["dist"] < 0.15))
    if family == "fall_and_get_up" and p["way"] == "forward":
        # onto the knees: both knee joints ~5 cm up (their thickness) ...
        knees = raw[:, [4, 5], 1].max(axis=1) < 0.08
        # ... and the hands: the wrists (a hand's thickness up) on the floor, > 0.2 m ahead of the knees, the
        # trunk near level (the neck < 0.25 m above the pelvis), for the sampled stay (and the catch / push)
        ahead = np.min([(raw[:, WRIST[s], [0, 2]] - raw[:, KNEE[s], [0, 2]]) @ fwd_ax for s in WRIST], axis=0)
        fours = knees & (raw[:, [20, 21], 1].max(axis=1) < 0.08) & (ahead > 0.2) & (raw[:, 12, 1] - raw[:, 0, 1] < 0.25)
        facts["fours_s"] = fours.sum() / FPS
        out.append((f"on the hands and knees ~{p['stay']} s ({facts['fours_s']:.2f})",
                    0.8 * p["stay"] < facts["fours_s"] < p["stay"] + 0.6 and len(_runs(fours)) == 1))
        # it falls: standing to both knees on the floor in < 0.8 s (buckle + drop: 0.44-0.56 s)
        first = np.flatnonzero(knees)[0]
        facts["down_s"] = (first - start) / FPS
        out.append((f"falls fast: onto the knees in < 0.8 s ({facts['down_s']:.2f})", facts["down_s"] < 0.8))
        # what carries the body stays put: the hands while down; the knee that stays down to the end (the one
        # it rises from) all the while it is down; the other knee until the hands lift (bringing that foot
        # forward, the knee swings up along an arc that starts level with the floor: it drags ~5 cm then)
        runs = {j: max(_runs(raw[:, j, 1] < 0.06), key=lambda r: r[1] - r[0]) for j in (4, 5)}
        last, other = sorted(runs, key=lambda j: runs[j][1], reverse=True)
        hands_up = np.flatnonzero(fours)[-1] + 1 if fours.any() else T
        facts["knee_slide"] = max(_still(raw, last, slice(*runs[last])),
                                  _still(raw, other, slice(runs[other][0], min(runs[other][1], hands_up))))
        # (on the floor: within 1 cm of it, where grounding pins a part: the knee joint 5 cm, the wrist 3 cm up)
        facts["hand_slide"] = max(_still(raw, j, slice(a, b)) for j in (20, 21) for a, b in
                                  _runs(raw[:, j, 1] < 0.04))
        out.append((f"knees and hands do not slide ({facts['knee_slide']:.3f}, {facts['hand_slide']:.3f} m)",
                    facts["knee_slide"] < 0.03 and facts["hand_slide"] < 0.03))
        # it falls forward and gets up there: the knees land a shin ahead of the feet (~0.4 m), and the feet
        # step up to the front foot, which comes down ahead of the knees: 0.6-1.0 m ahead in all
        out.append((f"falls forward and stands up ahead ({m['fwd']:.2f} m)", 0.5 < m["fwd"] < 1.1
                    and abs(m["left"]) < 0.15))
    if family == "lie_down_and_get_up":
        # lying down, not falling: from standing to the seat on the floor takes > 1 s (a controlled squat and
        # sit: down + sit 1.26-1.9 s)
        out.append((f"gets down slowly: > 1 s to the floor ({facts['down_s']:.2f})", facts["down_s"] > 1.0))
        # lies flat on the back: pelvis, upper back and head on the floor, both legs stretched out along it
        # (ankles > 0.6 m ahead of the pelvis, knees < 0.2 m up), for the sampled stay
        legs_out = np.stack([((raw[:, ANKLE[s], [0, 2]] - raw[:, 0, [0, 2]]) @ fwd_ax) for s in ANKLE]).min(axis=0)
        flat = ((raw[:, 0, 1] < 0.13) & (raw[:, 9, 1] < 0.15) & (raw[:, 15, 1] < 0.15) & (legs_out > 0.6)
                & (raw[:, [4, 5], 1].max(axis=1) < 0.2))
        facts["flat_s"] = flat.sum() / FPS
        out.append((f"lies flat, legs out, ~{p['stay']} s ({facts['flat_s']:.2f})",
                    0.9 * p["stay"] < facts["flat_s"] < p["stay"] + 0.8 and len(_runs(flat)) == 1))
        mid = np.flatnonzero(flat)[len(np.flatnonzero(flat)) // 2] if flat.any() else 0
        out.append(("arms at the sides, hands on the floor", raw[mid, [20, 21], 1].max() < 0.08))
        # nothing slides: the seat while it is down, and the feet end where they stood (it stands up in place)
        sat = np.flatnonzero(raw[:, 0, 1] < 0.12)
        facts["seat_slide"] = _still(raw, 0, slice(sat[0], sat[-1] + 1)) if len(sat) else np.inf
        out.append((f"the seat does not slide ({facts['seat_slide']:.3f} m)", facts["seat_slide"] < 0.03))
        facts["foot_moved"] = max(float(np.linalg.norm(raw[-1, TOE[s], [0, 2]] - raw[0, TOE[s], [0, 2]])) for s in TOE)
        out.append((f"stands up where it stood ({facts['foot_moved']:.3f} m)", facts["foot_moved"] < 0.05))
        out.append(("lies down behind its feet (> 0.4 m back)", fwd.min() < -0.4))
    return out, facts


def test_every_transition_does_what_its_captions_say():
    table, broken = {}, []
    for name in NAMES:
        fi = FAMILIES.index(name)
        rows = []
        for s in range(8):
            clip = C.generate_clip((name,), np.random.default_rng([31, fi, s]))
            p = clip.segments[0].params
            out, facts = measure(name, p, through_features(clip.joints), clip.joints)
            broken += [f"{name} seed {s} {p}: not {what}" for what, ok in out if not ok]
            rows.append(facts)
        keys = list(dict.fromkeys(k for r in rows for k in r))
        table[name] = {k: float(np.median([r[k] for r in rows if k in r])) for k in keys}
    print("\nfamily          " + " ".join(f"{k:>10s}" for k in ("dist", "turn", "drop", "end_drop", "low_s",
                                                                    "end_pelvis")) + "   (medians of 8 clips)")
    for name, med in table.items():
        print(f"{name:16s}" + " ".join(f"{med[k]:10.2f}" for k in ("dist", "turn", "drop", "end_drop", "low_s",
                                                                     "end_pelvis"))
              + "   " + ", ".join(f"{k} {v:.2f}" for k, v in med.items() if k not in
                                   ("dist", "turn", "drop", "end_drop", "low_s", "end_pelvis")))
    assert not broken, "\n".join(broken)


def test_registered_and_last_only():
    assert NAMES == ["crouch", "kneel_down", "sit_on_ground", "collapse_holding_leg", "fall_and_get_up",
                     "lie_down_and_get_up"]
    last = set(transitions.LAST_ONLY + falls.LAST_ONLY)
    assert last == {"kneel_down", "sit_on_ground", "collapse_holding_leg"} and last <= families.LAST_ONLY
    # the families that end on the floor never start a sequence: what ends a clip ends it low
    for name in sorted(last):
        a = families.FAMILIES[name](np.random.default_rng(0))
        assert pose_to_joints(a.pose)[-1, 0, 1] < 0.5, name


def test_falls_both_ways_and_what_ends_standing_starts_a_sequence():
    """fall_and_get_up samples both ways among the 8 clips its test measures; the families that end standing
    (not LAST_ONLY) may start a two-action clip, and the next action goes on from their feet."""
    fi = FAMILIES.index("fall_and_get_up")
    ways = {C.generate_clip(("fall_and_get_up",), np.random.default_rng([31, fi, s])).segments[0].params["way"]
            for s in range(8)}
    assert ways == {"backward", "forward"}
    for name in ("fall_and_get_up", "lie_down_and_get_up"):
        assert name not in families.LAST_ONLY
        for s in range(3):
            clip = C.generate_clip((name, "walk_forward"), np.random.default_rng([33, s]))
            j = clip.joints
            assert j[..., 1].min() > -0.01 and clip.segments[0].family == name
            assert abs(j[clip.segments[1].start:, 0, 1] - STAND_Y).max() < 0.1   # walking on from standing


@pytest.mark.parametrize("name", ["kneel_down", "sit_on_ground", "collapse_holding_leg"])
def test_a_body_at_rest_on_the_floor_through_a_sequence(name):
    """The parts allowed to rest on the floor (Pose.resting) travel with the pose through a cross-fade
    (clips.blend ORs them like the feet's support) and a hold (sequences.hold), so a sequence into a kneel
    or a seat keeps the body on the floor and nothing sinks through it."""
    for s in range(3):
        clip = C.generate_clip(("walk_forward", name), np.random.default_rng([32, s]))
        j = clip.joints
        assert j[..., 1].min() > -0.01
        assert j[-1, 0, 1] < 0.5                      # ends down on the floor


def test_resting_is_opt_in():
    """A pose that allows no body part on the floor is grounded on its feet alone, as every original family
    is; allowing the back lifts a body lying down onto it (the joints ~10 cm up: the back's thickness)."""
    pose = Pose(30)
    pose.root(pitch=np.linspace(0, -90, 30))          # tipping over backward, stiff as a board
    free = pose_to_joints(pose)
    assert not pose.resting.any()
    assert free[-1, [0, 3, 6, 9], 1].max() < 0.06     # the back 4.5 cm up: lying on the heels, flesh in the floor
    pose.rest_on(["pelvis", "lower_back", "mid_back", "upper_back", "head"])
    assert pose.resting[:, :5].all() and pose.resting.sum() == 5 * 30
    held = pose_to_joints(pose)
    assert held[-1, [0, 3, 6, 9], 1].min() > 0.099   # lying on the back
    np.testing.assert_array_equal(held[0], free[0])  # standing: the feet carry, as before


def test_resting_is_a_field_of_the_pose_that_blend_and_hold_carry():
    """Pose.resting (T, len(CONTACTS)) is its own field: rest_on touches no joint angle; clips.blend ORs it
    through the cross-fade as it does the feet's support, and sequences.hold indexes it like the other tracks."""
    from mogo_export.data.procedural.pose import CONTACTS
    from mogo_export.data.procedural.sequences import hold
    a, b = Pose(20), Pose(30)
    assert a.resting.shape == (20, len(CONTACTS)) and not a.resting.any()
    b.rest_on("left_knee", np.arange(30) >= 5)
    b.rest_on(["pelvis", "head"], 0.7)
    assert not b.angles.any()                          # nothing moved by allowing a part on the floor
    k, p, h = (list(CONTACTS).index(n) for n in ("left_knee", "pelvis", "head"))
    out = C.blend(a, b, 10)
    assert out.resting.shape == (40, len(CONTACTS))
    np.testing.assert_array_equal(out.resting[:10], False)
    np.testing.assert_array_equal(out.resting[10:, p], True)   # b's from the fade's first frame (OR)
    np.testing.assert_array_equal(out.resting[:, k], np.arange(40) >= 15)
    held = hold(b, 3, 4)
    np.testing.assert_array_equal(held.resting, b.resting[np.r_[[0] * 3, np.arange(30), [29] * 4]])
    assert held.resting[:, h].all() and not held.resting[:8, k].any()
