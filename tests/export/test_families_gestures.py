"""The gesture families (mogo_export/data/procedural/gestures.py) do what their captions say, measured on the
joints a model learns from (through the features: frame 0 faces +z, the person's left is +x, y is up).

Every bound below comes from the family's definition (the joint angles gestures.py keys), with room for the
body's sway; none is fitted to what the generator happens to output. Joint indices are HumanML3D's."""
import numpy as np
import pytest

from mogo_export.data.procedural import clips as C, families, gestures as G
from mogo_export.data.procedural.pose import FPS

from family_facts import SIDE, motion_facts, rises, through_features

PELVIS, SPINE3, NECK, HEAD = 0, 9, 12, 15
HIP = {"left": 1, "right": 2}
SHOULDER = {s: k["shoulder"] for s, k in SIDE.items()}
ELBOW = {"left": 18, "right": 19}
WRIST = {s: k["wrist"] for s, k in SIDE.items()}
OTHER = {"left": "right", "right": "left"}
NAMES = [f.__name__ for f in G.FAMILIES]
SEEDS = range(8)


def _clips(family):
    # a gesture's index in this module's FAMILIES (stable whatever the other groups register), an original's
    # in the registry
    index = NAMES.index(family) if family in NAMES else list(families.FAMILIES).index(family)
    out = []
    for seed in SEEDS:
        clip = C.generate_clip((family,), np.random.default_rng([31, index, seed]))
        out.append((clip.segments[0].params, through_features(clip.joints), clip.joints))
    return out


@pytest.fixture(scope="module")
def generated():
    return {f: _clips(f) for f in NAMES}


def runs(mask, min_frames=2):
    """Number of runs of True at least `min_frames` long (each a repetition of a held pose)."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    starts, stops = np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1)
    return int(((stops - starts) >= min_frames).sum()), (stops - starts)




def head_pitch(j):
    """Degrees the neck -> head bone leans forward (> 0: chin down) in the sagittal plane."""
    d = j[:, HEAD] - j[:, NECK]
    return np.degrees(np.arctan2(d[:, 2], d[:, 1]))


def seg_dist(p, a, b):
    """Distance of points p (T, 3) from segments a -> b (T, 3)."""
    ab = b - a
    s = np.clip(((p - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    return np.linalg.norm(a + s[:, None] * ab - p, axis=-1)


def shoulder_yaw(j):
    """Degrees the shoulder line is turned from the hip line (> 0: the shoulders face left)."""
    def ang(l, r):
        d = j[:, r] - j[:, l]  # left -> right points -x when facing +z
        return np.arctan2(d[:, 2], -d[:, 0])
    return np.degrees(np.unwrap(ang(SHOULDER["left"], SHOULDER["right"]) - ang(HIP["left"], HIP["right"])))


def speeds(j):
    v = np.linalg.norm(np.diff(j, axis=0), axis=-1) * FPS
    return v[:, [WRIST["left"], WRIST["right"]]].max(), v[:, PELVIS].max()


def general(family, p, j, world):
    """What every gesture keeps: on the spot, facing where it started, standing, feet planted, human speeds."""
    m = motion_facts(j)
    wrist_v, pelvis_v = speeds(j)
    feet = world[:, [7, 8, 10, 11]]
    foot_move = np.linalg.norm(feet[:, :, [0, 2]] - feet[:1, :, [0, 2]], axis=-1).max()
    bounce = 0.12 if family == "cheer" else 0.05  # cheering bends the knees 30 degrees at most
    # no hand through the head or trunk: each wrist > 8 cm from the head, neck and spine joints
    clear = min(np.linalg.norm(j[:, WRIST[s]] - j[:, k], axis=-1).min() for s in SIDE for k in (HEAD, NECK, SPINE3, 6, 3))
    return [(f"the hands stay clear of the head and trunk ({clear:.3f} m)", clear > 0.08),
            ("stays on the spot: the pelvis moves < 10 cm", m["dist"] < 0.10),
            ("keeps its heading within 15 deg", abs(m["turn"]) < 15),
            ("stands: the pelvis within a few cm of standing height", m["drop"] < bounce and m["rise"] < 0.03),
            ("the feet stay planted (< 3 cm)", foot_move < 0.03),
            # a fast arm (a baseball pitch) reaches ~15 m/s at the wrist; the body over the floor < 8 m/s
            (f"human speeds: wrist {wrist_v:.1f} < 15 m/s, pelvis {pelvis_v:.1f} < 8 m/s", wrist_v < 15 and pelvis_v < 8)]


def rel(j, k):
    return j[:, k] - j[:, PELVIS]


def point_promises(family, p, j):
    side, other = p["side"], OTHER[p["side"]]
    w, s = j[:, WRIST[side]], j[:, SHOULDER[side]]
    arm = w - s
    sign = 1.0 if side == "left" else -1.0
    if family == "point_forward":  # the straight arm (~0.53 m) points ahead at shoulder height
        out_mask = (arm[:, 2] > 0.42) & (np.abs(arm[:, 0]) < 0.15) & (np.abs(arm[:, 1]) < 0.12)
    else:  # ... or out to its own side
        toward = 1.0 if family == "point_left" else -1.0
        out_mask = (toward * arm[:, 0] > 0.42) & (np.abs(arm[:, 1]) < 0.12)
    n, lengths = runs(out_mask, 3)
    held = lengths.max() / FPS if len(lengths) else 0.0
    out = [(f"the {side} arm points {family[6:]} {p['reps']} times (got {n})", n == p["reps"]),
           # held 1-2.5 s (a short budget holds 1 s): at least 0.8 s at full extension
           (f"the point is held ({held:.2f} s)", held > 0.8),
           (f"the {other} hand stays down", (j[:, WRIST[other], 1] - j[:, SHOULDER[other], 1]).max() < -0.25)]
    if family != "point_forward":  # the head turns 35-55 deg toward it: the head joint moves 5 cm that way
        head_x = sign * (j[:, HEAD, 0] - j[:, NECK, 0])
        out.append((f"the head turns {side} ({head_x.max():.3f} m)", head_x.max() > 0.04))
    return out


def salute_promises(p, j):
    w, e, s, head = j[:, WRIST["right"]], j[:, ELBOW["right"]], j[:, SHOULDER["right"]], j[:, HEAD]
    d = np.linalg.norm(w - head, axis=-1)
    at_brow = (d < 0.25) & (w[:, 1] > head[:, 1] - 0.08)
    n, lengths = runs(at_brow, 3)
    held = lengths.max() / FPS if len(lengths) else 0.0
    top = np.argmin(d)
    return [(f"the right hand comes to the brow {p['reps']} times (got {n})", n == p["reps"]),
            (f"and is held there ({held:.2f} s)", held > 0.6),
            # near the head but not inside it: wrist > 8 cm from the head joint, forearm > 6 cm
            (f"the wrist stays > 8 cm from the head ({d.min():.3f})", d.min() > 0.08),
            ("the forearm does not pass through the head", seg_dist(head, e, w).min() > 0.06),
            # the elbow out sideways: > 15 cm out beyond the shoulder, near shoulder height
            ("the elbow out to the side", s[top, 0] - e[top, 0] > 0.15 and e[top, 1] > s[top, 1] - 0.1),
            ("the left hand stays down", (j[:, WRIST["left"], 1] - j[:, SHOULDER["left"], 1]).max() < -0.3),
            # snapped down: from the brow to below the shoulder within 0.4 s of leaving it
            ("snaps down", np.any((w[:, 1] - s[:, 1])[top:top + int(held * FPS) + 9] < -0.1))]


def shrug_promises(p, j):
    lw, rw = j[:, WRIST["left"]], j[:, WRIST["right"]]
    spread = lw[:, 0] - rw[:, 0]
    width = j[:, SHOULDER["left"], 0] - j[:, SHOULDER["right"], 0]
    # forearms out: the wrists 25+ cm wider apart than the shoulders, in front of the body, above the elbows
    out = (spread - width > 0.25) & (lw[:, 2] - j[:, PELVIS, 2] > 0.08) & (rw[:, 2] - j[:, PELVIS, 2] > 0.08)
    n, _ = runs(out, 2)
    up = (rel(j, SHOULDER["left"])[:, 1] + rel(j, SHOULDER["right"])[:, 1]) / 2
    peak = spread - width > 0.95 * (spread - width).max()  # the held shrug
    lift = np.minimum(lw[:, 1] - j[:, ELBOW["left"], 1], rw[:, 1] - j[:, ELBOW["right"], 1])
    return [(f"shrugs {p['reps']} times (got {n})", n == p["reps"]),
            # the collars' 20 deg pull the shoulders in ~4 cm each and up
            ("the shoulders draw in and up", width[0] - width.min() > 0.05 and up.max() - up[0] > 0.003),
            # at the shrug the elbows are bent 90 deg and the forearms rise out and forward: palms up
            (f"the forearms go out from bent elbows ({np.median(lift[peak]):.3f})", np.median(lift[peak]) > 0.05)]


def nod_promises(p, j):
    pitch = head_pitch(j)
    pitch = pitch - pitch[:3].mean()
    n = rises(pitch, 12, 5)
    lateral = np.ptp(j[:, HEAD, 0] - j[:, NECK, 0])
    # nods keyed +20-25 deg down, 14-18 up: peak to peak over 30 deg even after smoothing by the features
    return [(f"nods {p['reps']} times (got {n})", n == p["reps"]),
            (f"large nods: {np.ptp(pitch):.0f} deg peak to peak", np.ptp(pitch) > 30),
            (f"yes, not no: the head stays centred ({lateral:.3f} m)", lateral < 0.02)]


def shake_promises(p, j):
    x = j[:, HEAD, 0] - j[:, NECK, 0]
    # +-30-40 deg of yaw move the head joint (6 cm in front of the neck) 3.5-4.5 cm to each side
    n = min(rises(x, 0.025, 0.005), rises(-x, 0.025, 0.005))
    pitch = head_pitch(j)
    return [(f"shakes {p['reps']} times each way (got {n})", n == p["reps"]),
            (f"wide: the head moves {np.ptp(x):.3f} m side to side", np.ptp(x) > 0.06),
            (f"no, not yes: the head pitch stays within 15 deg ({np.ptp(pitch):.0f})", np.ptp(pitch) < 15)]


def beckon_promises(p, j):
    side, other = p["side"], OTHER[p["side"]]
    w, s = j[:, WRIST[side]], j[:, SHOULDER[side]]
    up = w[:, 1] - s[:, 1]
    fwd = w[:, 2] - s[:, 2]
    # the forearm from ~horizontal in front (wrist ~10 cm below the shoulder) to upright (~10 cm above)
    n = rises(up, 0.04, -0.06)
    d = min(np.linalg.norm(w - j[:, k], axis=-1).min() for k in (HEAD, NECK, SPINE3))
    return [(f"curls the {side} forearm {p['reps']} times (got {n})", n == p["reps"]),
            ("the hand held out in front", fwd.max() > 0.35),
            (f"the hand stays clear of the body ({d:.3f} m)", d > 0.12),
            (f"the {other} hand stays down", (j[:, WRIST[other], 1] - j[:, SHOULDER[other], 1]).max() < -0.25)]


def cheer_promises(p, j):
    above = np.minimum(j[:, WRIST["left"], 1], j[:, WRIST["right"], 1]) - j[:, HEAD, 1]
    n = rises(above, 0.23, 0.18)  # the fists pumped from ~14 cm to ~27 cm above the head joint
    bounce = -(j[:, PELVIS, 1] - j[:3, PELVIS, 1].mean())
    return [(f"pumps both fists {p['reps']} times (got {n})", n == p["reps"]),
            ("both fists above the head", above.max() > 0.25),
            # the knees bend 18-30 deg between pumps: the pelvis drops 1-3 cm with each, and rises again
            (f"bounces ({np.ptp(bounce):.3f} m)", 0.008 < np.ptp(bounce) < 0.08 and rises(bounce, 0.006, 0.003) >= 2)]


def facepalm_promises(p, j):
    side, other = p["side"], OTHER[p["side"]]
    w, e, head = j[:, WRIST[side]], j[:, ELBOW[side]], j[:, HEAD]
    d = np.linalg.norm(w - head, axis=-1)
    on_face = (d < 0.2) & (w[:, 2] > head[:, 2])
    n, lengths = runs(on_face, 3)
    held = lengths.max() / FPS if len(lengths) else 0.0
    clear = min(np.linalg.norm(w - j[:, k], axis=-1).min() for k in (HEAD, NECK, SPINE3))
    bowed = head_pitch(j) - head_pitch(j)[:3].mean()
    return [(f"the {side} hand comes to the face once (got {n})", n == 1),
            (f"and is held there ({held:.2f} s)", held > 0.7),
            # the hand must not pass through the head: wrist > 8 cm from head, neck and chest; forearm > 6 cm
            (f"the wrist stays clear of the head and body ({clear:.3f} m)", clear > 0.08),
            ("the forearm does not pass through the head", seg_dist(head, e, w).min() > 0.06),
            (f"the head bows ({bowed.max():.0f} deg)", bowed.max() > 12),
            (f"the {other} hand stays down", (j[:, WRIST[other], 1] - j[:, SHOULDER[other], 1]).max() < -0.25)]


def look_promises(p, j):
    yaw = shoulder_yaw(j)
    head_x = j[:, HEAD, 0] - j[:, NECK, 0]
    sign = 1.0 if p["first"] == "left" else -1.0
    # 30-40 deg of spine twist and as much again of the head: the shoulders turn > 20 deg each way
    first_peak = np.argmax(sign * yaw)
    other_peak = np.argmax(-sign * yaw)
    n = min(rises(sign * yaw, 20, 8), rises(-sign * yaw, 20, 8))
    return [(f"twists {p['reps']} times each way (got {n}, {yaw.min():.0f}..{yaw.max():.0f} deg)", n == p["reps"]),
            (f"looks {p['first']} first", first_peak < other_peak if p["reps"] == 1 else
             np.argmax(sign * yaw > 20) < np.argmax(-sign * yaw > 20)),
            ("the head turns with the shoulders", sign * head_x[first_peak] > 0.03 and -sign * head_x[other_peak] > 0.03),
            ("ends facing the front", abs(yaw[-1]) < 5)]


def stretch_promises(p, j):
    lw, rw = j[:, WRIST["left"]], j[:, WRIST["right"]]
    if p["kind"] == "back":  # both arms 40 deg back: the wrists ~15 cm behind the pelvis
        behind = np.maximum(lw[:, 2], rw[:, 2]) - j[:, PELVIS, 2]
        n, lengths = runs(behind < -0.12, 3)
        return [(f"stretches the arms back {p['reps']} times (got {n})", n == p["reps"]),
                ("held > 0.6 s", lengths.max() / FPS > 0.6 if len(lengths) else False)]
    above = np.minimum(lw[:, 1], rw[:, 1]) - j[:, HEAD, 1]
    together = np.linalg.norm(lw - rw, axis=-1)
    up = (above > 0.2) & (together < 0.15)  # interlaced hands overhead: wrists ~6-8 cm apart
    n, lengths = runs(up, 3)
    out = [(f"hands together above the head (min {together.min():.3f} m)", n >= 1),
           ("held > 0.6 s", lengths.max() / FPS > 0.6 if len(lengths) else False)]
    if p["kind"] == "overhead":
        out.append((f"stretches up {p['reps']} times (got {n})", n == p["reps"]))
    else:  # side bends of 20-28 deg: the shoulder line tilts > 10 deg each way, the first side first
        d = j[:, SHOULDER["left"]] - j[:, SHOULDER["right"]]
        tilt = np.degrees(np.arctan2(-d[:, 1], d[:, 0]))  # > 0: the left shoulder lower (leaning left)
        sign = 1.0 if p["first"] == "left" else -1.0
        bends = min(rises(sign * tilt, 10, 4), rises(-sign * tilt, 10, 4))
        out.append((f"bends to each side {p['reps']} times (got {bends})", bends == p["reps"]))
        out.append((f"to the {p['first']} first", np.argmax(sign * tilt > 10) < np.argmax(-sign * tilt > 10)))
    return out


def promises(family, p, j):
    if family.startswith("point_"):
        return point_promises(family, p, j)
    return {"salute": salute_promises, "shrug": shrug_promises, "nod": nod_promises, "shake_head": shake_promises,
            "beckon": beckon_promises, "cheer": cheer_promises, "facepalm": facepalm_promises,
            "look_around": look_promises, "stretch": stretch_promises}[family](p, j)


def test_registered_in_order():
    names = list(families.FAMILIES)
    assert names[names.index(NAMES[0]):names.index(NAMES[0]) + len(NAMES)] == NAMES
    assert G.LAST_ONLY == ()


def test_every_gesture_does_what_its_captions_say(generated):
    broken, table = [], {}
    for family, clips in generated.items():
        rows = []
        for seed, (p, j, world) in zip(SEEDS, clips):
            for what, ok in general(family, p, j, world) + promises(family, p, j):
                if not ok:
                    broken.append(f"seed [31, {family}, {seed}] {p}: not {what}")
            m = motion_facts(j)
            wrist_v, _ = speeds(j)
            head_v = (np.linalg.norm(np.diff(j[:, HEAD] - j[:, NECK], axis=0), axis=-1) * FPS).max()
            rows.append([m["dist"], m["turn"], m["drop"], m["hand_up_left"], m["hand_up_right"], m["reach_left"],
                         m["reach_right"], np.ptp(head_pitch(j)), np.ptp(shoulder_yaw(j)), head_v, wrist_v])
        table[family] = np.median(rows, axis=0)
    print("\nfamily          dist   turn   drop  hupL  hupR  reachL reachR pitch  s-yaw  headv  wristv  (medians of 8)")
    for family, med in table.items():
        print(f"{family:14s}" + "".join(f"{v:7.2f}" for v in med))
    assert not broken, "\n".join(broken)


def test_nod_and_shake_are_unmistakable_from_standing_idle(generated):
    """stand_idle turns its head by up to 15 deg every 1.2-2.5 s; nods and shakes move it ~2 Hz, widely."""
    idle = _clips("stand_idle")
    def head_speed(j):
        return np.percentile(np.linalg.norm(np.diff(j[:, HEAD] - j[:, NECK], axis=0), axis=-1) * FPS, 90)
    idle_v = max(head_speed(j) for _, j, _ in idle)
    for family in ("nod", "shake_head"):
        v = min(head_speed(j) for _, j, _ in generated[family])
        assert v > 2.5 * idle_v, (family, v, idle_v)


def _summary(j):
    """A clip as a vector: per-joint means and spreads of the body-relative positions, and mean speeds."""
    r = j - j[:, :1] * np.array([1, 0, 1])
    v = np.linalg.norm(np.diff(j, axis=0), axis=-1) * FPS
    head = j[:, HEAD] - j[:, NECK]
    return np.concatenate([r.mean(0).ravel(), r.std(0).ravel(), v.mean(0), np.percentile(v, 90, axis=0),
                           head.std(0) * 10, np.abs(np.diff(head, axis=0)).mean(0) * FPS * 10])


def test_gestures_are_told_apart(generated):
    """Leave-one-out nearest neighbour on clip summaries: each gesture against the others and against the
    originals a gesture could be mistaken for. A crude stand-in for the dataset's classifier bar (98%);
    nearest neighbour rather than centroid because a sided family (point_forward, beckon, facepalm) has a
    left and a right mode."""
    others = ["raise_both_arms", "wave_right_hand", "wave_left_hand", "clap", "stand_idle", "bow", "punch"]
    data = {f: [_summary(j) for _, j, _ in clips] for f, clips in generated.items()}
    data.update({f: [_summary(j) for _, j, _ in _clips(f)] for f in others})
    labels = [f for f in data for _ in data[f]]
    X = np.array([x for f in data for x in data[f]])
    X = (X - X.mean(0)) / (X.std(0) + 1e-6)
    d = np.linalg.norm(X[:, None] - X[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    wrong = [(labels[i], labels[k]) for i, k in enumerate(d.argmin(1)) if labels[k] != labels[i]]
    assert len(wrong) <= 0.02 * len(X), wrong
