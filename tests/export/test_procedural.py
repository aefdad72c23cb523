"""The procedural HumanML3D-layout dataset: determinism, layout, people-like motion, captions, long
sequences, path sequences, and every family (and path segment) doing what its captions say."""
import itertools
import json
import re

import numpy as np
import pytest

from mogo_export.data import procedural as P
from mogo_export.data.dataset import MotionDataset, read_captions
from mogo_export.data.timelines import read_timelines
from mogo_export.data.procedural import captions, clips as C, families, locomotion, paths as PT, sequences as S, writer
from mogo_export.data.procedural.action import FULL_BUDGET, TimeBudget
from mogo_export.data.procedural.pose import FPS, MAX_SECONDS, Pose
from mogo_runtime.kinematics.features import FeatureLayout, recover_from_ric
from mogo_runtime.kinematics.skeleton import HUMANML3D

from family_facts import OFF_FEET, motion_facts, through_features

FAMILIES = list(families.FAMILIES)
FEET = [7, 10, 8, 11]  # left ankle, left toe, right ankle, right toe (HumanML3D's contact joints)
PARENTS = np.array(HUMANML3D.parents)
BONES = np.arange(1, HUMANML3D.num_joints)


# The fewest clips whose singles cover every family (every 5th clip is a two-action sequence); then N // 10 long
# sequences and N // 10 path sequences follow them
N = next(n for n in itertools.count(1) if n - n // C.SEQUENCE_EVERY >= len(FAMILIES))
SHORT = [f"{i:06d}" for i in range(N)]
LONG = [f"{i:06d}" for i in range(N, N + N // 10)]
PATH = [f"{i:06d}" for i in range(N + N // 10, N + 2 * (N // 10))]
CONTROL = [f"{i:06d}" for i in range(N + 2 * (N // 10), N + 3 * (N // 10))]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    return P.build_dataset(tmp_path_factory.mktemp("proc") / "ds", num_clips=N, seed=7, progress=False, workers=2)


@pytest.fixture(scope="module")
def clips():
    """World joints for 3 clips of every family, 6 sequences and 2 long sequences, straight from the generator."""
    out = []
    for f in FAMILIES:
        for s in range(3):
            joints = C.generate_clip((f,), np.random.default_rng([11, s, FAMILIES.index(f)])).joints
            out.append((f, joints))
    for i, pair in enumerate([("walk_forward", "jump_in_place"), ("run", "sit_down"), ("kick_left", "turn_right"),
                              ("jump_forward", "walk_backward"), ("squat", "wave_left_hand"), ("bow", "clap")]):
        joints = C.generate_clip(pair, np.random.default_rng([12, i])).joints
        out.append((C.label_for(pair), joints))
    for i in range(2):
        clip = S.generate_long(np.random.default_rng([13, i]))
        out.append((C.label_for(tuple(s.family for s in clip.segments)), clip.joints))
    return out


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_whatever_the_workers(tmp_path):
    a = P.build_dataset(tmp_path / "a", num_clips=20, seed=3, progress=False, workers=1)
    b = P.build_dataset(tmp_path / "b", num_clips=20, seed=3, progress=False, workers=2)
    fa, fb = _files(a), _files(b)
    assert len(fa) == 4 * (20 + 2 + 2 + 2) + 3 + 2 + 1  # 20 clips, 2 long, 2 path and 2 control sequences
    assert fa.keys() == fb.keys()
    assert [k for k in fa if fa[k] != fb[k]] == []
    c = P.build_dataset(tmp_path / "c", num_clips=20, seed=4, progress=False, workers=1)
    assert _files(c)["new_joint_vecs/000000.npy"] != fa["new_joint_vecs/000000.npy"]
    # long, path and control sequences are added: without them the short clips, their split and Mean/Std are
    # the same files
    d = _files(P.build_dataset(tmp_path / "d", num_clips=20, seed=3, progress=False, workers=1, long_sequences=0,
                               path_sequences=0, control_sequences=0))
    splits = ("train.txt", "val.txt", "test.txt")
    assert len(d) == 4 * 20 + 6
    assert [k for k in d if k not in splits + ("dataset.json",) and d[k] != fa[k]] == []
    for name in splits:
        assert set(d[name].split()) == set(fa[name].split()) - {b"%06d" % i for i in range(20, 26)}
    # a path or control sequence depends on its index among its kind only: without the long sequences the same
    # files, two ids earlier
    e = _files(P.build_dataset(tmp_path / "e", num_clips=20, seed=3, progress=False, workers=1, long_sequences=0))
    for sub, ext in (("new_joint_vecs", "npy"), ("new_joints", "npy"), ("texts", "txt"), ("labels", "txt")):
        for i in (0, 1, 2, 3):
            assert e[f"{sub}/{20 + i:06d}.{ext}"] == fa[f"{sub}/{22 + i:06d}.{ext}"]
    # and without the control sequences, every other file is the same, dataset.json but for its list of them
    f = _files(P.build_dataset(tmp_path / "f", num_clips=20, seed=3, progress=False, workers=1, control_sequences=0))
    assert [k for k in f if k not in splits + ("dataset.json",) and f[k] != fa[k]] == []
    assert json.loads(fa["dataset.json"])["control_only"] == ["000024", "000025"]
    assert json.loads(f["dataset.json"])["control_only"] == []


def test_every_family_present_and_labelled(built):
    labels = {p.stem: p.read_text().strip() for p in (built / "labels").glob("*.txt")}
    assert sorted(labels) == SHORT + LONG + PATH + CONTROL
    info = json.loads((built / "dataset.json").read_text())
    assert info["control_only"] == CONTROL
    for i in LONG + PATH + CONTROL:  # seq:<families in order>, those of its segments
        assert labels.pop(i) == "seq:" + "+".join(s["family"] for s in info["segments"][i])
    singles = {v for v in labels.values() if not v.startswith("seq:")}
    assert singles == set(FAMILIES)
    seqs = [v for v in labels.values() if v.startswith("seq:")]
    assert len(seqs) == N // C.SEQUENCE_EVERY
    for s in seqs:
        first, second = s[4:].split("+")
        assert first in FAMILIES and second in FAMILIES and first != second
    assert info["label_counts"] == {k: list(labels.values()).count(k) for k in set(labels.values())}
    assert info["families"] == FAMILIES and info["seed"] == 7 and info["num_clips"] == N
    assert info["num_long_sequences"] == len(LONG) and info["num_path_sequences"] == len(PATH)
    assert sorted(info["segments"]) == LONG + PATH + CONTROL and info["num_control_sequences"] == len(CONTROL)
    assert sum(info["path_family_counts"].values()) == sum(len(info["segments"][i]) for i in PATH)
    assert info["fps"] == 20.0 and info["skeleton"]["name"] == "humanml3d" and info["feature_dim"] == 263


def test_layout_shapes_splits_and_stats(built):
    ids = sorted(p.stem for p in (built / "new_joint_vecs").glob("*.npy"))
    assert ids == SHORT + LONG + PATH + CONTROL
    for i in ids:
        f = np.load(built / "new_joint_vecs" / f"{i}.npy")
        j = np.load(built / "new_joints" / f"{i}.npy")
        assert f.dtype == np.float32 and j.dtype == np.float32
        assert f.shape == (len(j) - 1, 263) and j.shape[1:] == (22, 3)
        if i in LONG + PATH + CONTROL:
            assert 400 <= len(j) <= 1200  # 20..60 s
        else:
            assert 41 <= len(j) <= 200  # 2..10 s at 20 fps; features keep T2M's 40 <= T < 200
        assert np.isfinite(f).all()
        assert abs(j[..., 1].min()) < 1e-6  # HumanML3D puts the lowest joint of the clip on the floor
    splits = {s: (built / f"{s}.txt").read_text().split() for s in ("train", "val", "test")}
    assert sorted(sum(splits.values(), [])) == ids
    # 80/15/5 of the short clips, rounded (val first), and of the long, path and control sequences, each split apart
    val = round(0.15 * N)
    assert [len(set(v) - set(LONG + PATH + CONTROL)) for v in splits.values()] == [
        N - val - (N - round(0.8 * N) - val), val, N - round(0.8 * N) - val]
    for group in (LONG, PATH, CONTROL):
        assert sorted(set(group) & set(sum(splits.values(), []))) == group
        assert len(set(group) & set(splits["train"])) >= len(group) - 2 * (len(group) >= 3)
    mean, std = np.load(built / "Mean.npy"), np.load(built / "Std.npy")
    train = np.concatenate([np.load(built / "new_joint_vecs" / f"{i}.npy") for i in splits["train"]
                            if i in SHORT]).astype(np.float64)  # the statistics leave long and path sequences out
    np.testing.assert_allclose(mean, train.mean(0), rtol=1e-5, atol=1e-6)
    for name, sl in FeatureLayout(22).slices().items():  # HumanML3D: one std per feature group
        np.testing.assert_allclose(std[sl], train.std(0)[sl].mean(), rtol=1e-5, err_msg=name)
    assert not list(built.parent.glob(".ds.*")), "temporary build folder left behind"


def test_joints_file_is_what_the_features_describe(built):
    # new_joints is canonicalised like HumanML3D's, so recovering the features gives it back (minus the
    # last frame), turns past 180 degrees included (see the rot_vel sign note in data/humanml3d.py).
    checked = turning = 0
    for p in sorted((built / "labels").glob("*.txt")):
        turning += bool(re.search(r"turn|circle", p.read_text()))
        f = np.load(built / "new_joint_vecs" / p.name.replace(".txt", ".npy"))
        j = np.load(built / "new_joints" / p.name.replace(".txt", ".npy"))
        np.testing.assert_allclose(recover_from_ric(f, 22), j[:-1], atol=1e-4)
        checked += 1
    assert checked == len(SHORT + LONG + PATH + CONTROL) and turning >= 2


def test_bone_lengths_are_the_skeletons(clips, built):
    want = HUMANML3D.bone_lengths[BONES]
    for name, j in clips:
        got = np.linalg.norm(j[:, BONES] - j[:, PARENTS[BONES]], axis=-1)
        assert np.abs(got - want).max() < 1e-5, name
    j = np.load(built / "new_joints" / "000000.npy")  # and through canonicalisation + float32
    got = np.linalg.norm(j[:, BONES] - j[:, PARENTS[BONES]], axis=-1)
    assert np.abs(got - want).max() < 1e-5


def _slides(joints):
    """Horizontal foot-joint motion per frame (m) where HumanML3D would call the foot in contact
    (squared displacement < 0.002) and it is below 5 cm at both frames; and toe motion while within 1 cm
    of the floor (planted)."""
    p = joints[:, FEET]
    d = p[1:] - p[:-1]
    high = np.maximum(p[1:, :, 1], p[:-1, :, 1])
    horiz = np.linalg.norm(d[..., [0, 2]], axis=-1)
    contact = ((d ** 2).sum(-1) < 0.002) & (high < 0.05)
    planted = horiz[:, [1, 3]][high[:, [1, 3]] < 0.01]
    return horiz[contact], planted


def test_feet_do_not_slide(clips, humanml3d_fixture):
    real, real_planted = _slides(np.load(humanml3d_fixture / "new_joints" / "012314.npy"))
    ours = [_slides(j) for _, j in clips]
    slide = np.concatenate([s for s, _ in ours])
    planted = np.concatenate([p for _, p in ours])
    # Real HumanML3D clip 012314: contact slide p95 1.6 cm/frame, mean 3.9 mm; planted toe max 6 mm.
    assert np.percentile(real, 95) > 0.01 and real_planted.max() > 0.004  # the comparison is meaningful
    assert np.percentile(slide, 95) < 0.02 and slide.mean() < 0.005
    # A toe on the floor moves less than 1 cm per frame (0.2 m/s) but in a few landing and lift-off frames
    # (measured on 420 clips: p99 4 mm, 0.6% of frames over 1 cm, max 6.6 cm).
    assert np.percentile(planted, 99) < 0.01 and (planted > 0.01).mean() < 0.02
    assert planted.size > 5000


def test_feet_on_the_floor_and_no_joint_below_it(clips):
    for name, j in clips:
        assert j[..., 1].min() > -0.01, name
        # a toe within 3 cm of the floor, or an ankle within 7.5 cm (on the heel, toes up, an ankle is
        # 6-7 cm up); frames with neither are airborne, which only jumps and runs have many of
        grounded = (j[:, [10, 11], 1].min(axis=1) < 0.03) | (j[:, [7, 8], 1].min(axis=1) < 0.075)
        assert grounded.mean() > (0.5 if OFF_FEET.search(name) else 0.97), name


def test_no_flips_and_smooth(clips, humanml3d_fixture):
    def rates(j):
        b = j[:, BONES] - j[:, PARENTS[BONES]]
        b /= np.linalg.norm(b, axis=-1, keepdims=True)
        ang = np.degrees(np.arccos(np.clip((b[1:] * b[:-1]).sum(-1), -1, 1)))  # bone turn per frame
        v = (j[1:] - j[:-1]) * FPS
        acc = np.linalg.norm(v[1:] - v[:-1], axis=-1) * FPS  # m/s^2
        return ang, acc
    real_ang, real_acc = rates(np.load(humanml3d_fixture / "new_joints" / "012314.npy"))
    # Real clip 012314: bone turn max 66 deg/frame; acceleration max 129 m/s^2, pelvis p95 12, max 19.
    assert real_ang.max() > 60 and real_acc.max() > 120
    pelvis = []
    for name, j in clips:
        ang, acc = rates(j)
        assert ang.max() < 60, name  # a flip turns a bone ~180 degrees in one frame
        assert acc.max() < 200, name  # kicks and landings reach ~160
        assert acc[:, 0].max() < (100 if OFF_FEET.search(name) else 50), name  # take-off, landing
        pelvis.append(acc[:, 0])
    assert np.percentile(np.concatenate(pelvis), 95) < 20


def test_every_family_moves_as_a_person_can(clips, humanml3d_fixture):
    """Speeds within human ranges, measured beside the real clip's, and no hand through the trunk or head."""
    def facts(j):
        v = np.linalg.norm(np.diff(j, axis=0), axis=-1) * FPS               # m/s per joint
        trunk = [0, 3, 6, 9, 12, 15]                                        # pelvis, spine, neck, head
        clear = np.linalg.norm(j[:, [20, 21], None] - j[:, None, trunk], axis=-1).min()
        return v.max(), v[:, [20, 21]].max(), v[:, 0].max(), clear
    real = facts(np.load(humanml3d_fixture / "new_joints" / "012314.npy"))
    # Real clip 012314: fastest joint and wrist 10.0 m/s, pelvis 2.7 m/s; a wrist 0.24 m from the trunk at the closest.
    assert real[0] > 9 and real[2] > 2.5
    table = {}
    for name, j in clips:
        if name.startswith("seq:"):
            continue
        row = np.array(facts(j))
        table[name] = np.maximum(table.get(name, row), row) if name in table else row
        table[name][3] = min(table[name][3], row[3])
    print("\nfamily                  joint  wrist pelvis  clear   (max speeds m/s, closest wrist to trunk m; 3 clips)")
    print(f"{'HumanML3D 012314':22s}" + "".join(f"{v:7.2f}" for v in real))
    for name, row in table.items():
        print(f"{name:22s}" + "".join(f"{v:7.2f}" for v in row))
    # A sprinter's foot swings at ~20 m/s and a pitcher's wrist at ~20; people walk and run below 8 m/s (the fastest
    # sprint is ~10); a hand passing through the body comes within a few cm of a trunk joint.
    broken = [f"{n}: {what} ({v:.2f})" for n, r in table.items() for what, v, ok in (
        ("joint speed < 15 m/s", r[0], r[0] < 15), ("pelvis speed < 8 m/s", r[2], r[2] < 8),
        ("wrists > 8 cm from the trunk and head", r[3], r[3] > 0.08)) if not ok]
    assert not broken, "\n".join(broken)


def test_ranges_of_motion(clips):
    def joint_angle(j, a, b, c):  # angle between bones a->b and b->c: 0 = straight
        u, v = j[:, b] - j[:, a], j[:, c] - j[:, b]
        cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
        return np.degrees(np.arccos(np.clip(cos, -1, 1)))
    for name, j in clips:
        for hip, knee, ankle in ((1, 4, 7), (2, 5, 8)):
            bend = joint_angle(j, hip, knee, ankle)
            assert bend.max() < 150, name
            # knees bend forward: the ankle never ends up in front of the knee-hip line's forward side
            thigh, shank = j[:, knee] - j[:, hip], j[:, ankle] - j[:, knee]
            side = np.cross(thigh, shank)  # sign along the body's left-right axis
            across = j[:, 1] - j[:, 2]
            assert ((side * across).sum(-1) > -1e-4)[bend > 10].all(), name
        for sh, el, wr in ((16, 18, 20), (17, 19, 21)):
            assert joint_angle(j, sh, el, wr).max() < 150, name


def _sided(family, text):
    """Sided actions name their side."""
    side = re.fullmatch(r"[a-z_]+_(left|right)(?:_hand)?", family)
    return side is None or side.group(1) in text


def test_captions(built):
    info = json.loads((built / "dataset.json").read_text())
    tags = {"DET", "NOUN", "VERB", "ADV", "ADJ", "ADP", "PRON", "NUM", "CCONJ", "AUX", "INTJ"}
    for p in sorted((built / "texts").glob("*.txt")):
        caps = read_captions(p)
        label = (built / "labels" / p.name).read_text().strip()
        for c in caps:
            assert len(c.tokens) == len(re.findall(r"[a-z]+", c.text))  # one word/POS per word
            assert " ".join(c.tokens) == captions.pos_tokens(c.text)
            assert {t.split("/")[1] for t in c.tokens} <= tags
            assert c.text.endswith(".") and c.text == c.text.lower()
        whole = [c for c in caps if c.start == c.end == 0.0]
        assert len({c.text for c in whole}) == len(whole)
        if p.stem in SHORT:
            assert 3 <= len(caps) <= 4 and whole == caps
            assert all(_sided(label, c.text) for c in caps), (label, caps)
            continue
        # a long or path sequence: 1-2 captions of the whole, then one per segment, timed as dataset.json's
        # frames
        segments = info["segments"][p.stem]
        assert 1 <= len(whole) <= 2 and caps[len(whole):] == caps[-len(segments):]
        for c, seg in zip(caps[len(whole):], segments):
            assert (int(c.start * FPS), int(c.end * FPS)) == (seg["start"], seg["end"])  # T2M's reading
            assert _sided(seg["family"], c.text), (seg, c.text)
        assert all(re.search(r"then", c.text) and c.text.count(",") >= len(segments) - 3 for c in whole)


def test_captions_follow_parameters():
    for s in range(40):
        for fam in FAMILIES:
            act = families.FAMILIES[fam](np.random.default_rng(s))
            text = " ".join(act.phrases)
            assert len(act.phrases) >= 4, fam
            for ph in act.phrases:
                captions.pos_tokens(ph.replace("{pos}", "his"))  # every word is in the lexicon
            pr = act.params
            if pr.get("speed") == "slow":
                assert re.search(r"slow|jog|carefully", text), (fam, text)
            if pr.get("speed") == "fast":
                assert re.search(r"quick|fast|sprint", text), (fam, text)
            if "reps" in pr and pr["reps"] > 1:
                words = (captions.COUNT_WORDS[pr["reps"]], captions.NUMBER_WORDS[pr["reps"]])
                assert any(w in text for w in words), (fam, text)
            if "steps" in pr and fam.startswith("walk_") and fam != "walk_circle":
                assert captions.NUMBER_WORDS[pr["steps"]] in text, (fam, text)
            if pr.get("side") in ("left", "right"):
                assert pr["side"] in text, (fam, text)


def test_time_budget_is_an_explicit_value():
    # A family's clip depends on (rng, budget) only: a shorter budget fits fewer steps or repetitions (never
    # a longer clip), and nothing carries over from one call to the next.
    assert TimeBudget.at_most(25.0) == FULL_BUDGET and FULL_BUDGET.seconds == MAX_SECONDS
    short = TimeBudget.at_most(5.0)
    shortened = 0
    for fam, family in families.FAMILIES.items():
        for s in range(5):
            full = family(np.random.default_rng(s))
            cut = family(np.random.default_rng(s), short)
            again = family(np.random.default_rng(s), FULL_BUDGET)
            np.testing.assert_array_equal(again.pose.angles, full.pose.angles)
            assert again.phrases == full.phrases and again.params == full.params, fam
            assert cut.pose.T <= full.pose.T, fam
            # 5 s hold one repetition of every family but these, which have a minimum number of steps
            if not re.fullmatch(r"walk_circle|turn_(left|right)", fam):
                assert cut.pose.T <= round(short.seconds * FPS), (fam, cut.pose.T)
            shortened += cut.pose.T < full.pose.T
    assert shortened >= 40  # of 105


def test_pos_tokens_and_caption_line():
    assert captions.pos_tokens("a person walks forward slowly.") == "a/DET person/NOUN walk/VERB forward/ADV slowly/ADV"
    assert captions.pos_tokens("someone does two deep squats") == "someone/PRON do/VERB two/NUM deep/ADJ squat/NOUN"
    assert captions.pos_tokens("the man squats down") == "the/DET man/NOUN squat/VERB down/ADV"
    line = captions.caption_line("a man kicks with his left leg.")
    assert line == "a man kicks with his left leg.#a/DET man/NOUN kick/VERB with/ADP his/DET left/ADJ leg/NOUN#0.0#0.0"
    with pytest.raises(ValueError, match="'moonwalks'"):
        captions.pos_tokens("a person moonwalks")


def test_sequence_blends_and_keeps_heading():
    rng = np.random.default_rng(5)
    first = locomotion.walk_forward(rng)
    second = locomotion.jump_in_place(rng)
    pose = C.blend(first.pose, second.pose)
    assert pose.T == first.pose.T + second.pose.T - C.BLEND_FRAMES
    # the second action starts facing where the first ended
    assert pose.angles[first.pose.T, 0, 1] == pytest.approx(first.pose.angles[-1, 0, 1], abs=1e-9)
    np.testing.assert_array_equal(pose.flight[first.pose.T:], second.pose.flight[C.BLEND_FRAMES:])
    joints, caps, _ = C.generate_clip(("walk_forward", "jump_in_place"), np.random.default_rng(5))
    assert len(joints) <= 200 and len(caps) >= 3
    assert all(re.search(r"walk|step", c) and re.search(r"jump|hop", c) for c in caps)


def test_build_refuses_to_clobber_and_cli(tmp_path, capsys):
    out = P.build_dataset(tmp_path / "d", num_clips=3, seed=0, progress=False, workers=1)
    with pytest.raises(FileExistsError, match="already exists"):
        P.build_dataset(out, num_clips=3, progress=False)
    P.main([str(out), "--clips", "4", "--seed", "1", "--workers", "1", "--overwrite", "--quiet"])
    assert "wrote 4 clips" in capsys.readouterr().out
    assert len(list((out / "new_joint_vecs").glob("*.npy"))) == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
    with pytest.raises(ValueError, match="num_clips"):
        P.build_dataset(tmp_path / "e", num_clips=0, progress=False)


def test_a_failed_build_leaves_nothing(tmp_path, monkeypatch):
    real = C.generate_clip

    def flaky(families, rng):
        if families == C.family_plan(8, 0)[5]:
            raise RuntimeError("boom")
        return real(families, rng)

    monkeypatch.setattr(writer, "generate_clip", flaky)  # the name the writer calls
    with pytest.raises(RuntimeError, match="boom"):
        P.build_dataset(tmp_path / "d", num_clips=8, seed=0, progress=False, workers=1)
    assert list(tmp_path.iterdir()) == []


# --- every family does what its captions say --------------------------------------------------------------

IN_PLACE = {"wave_right_hand", "wave_left_hand", "clap", "punch", "kick_right", "kick_left", "squat", "bow",
            "raise_both_arms", "stand_idle", "sit_down", "jump_in_place", "turn_left", "turn_right"}
TURNING = {"walk_circle", "turn_left", "turn_right"}


def promises(family, p, m):
    """(promise, kept) for what `family`'s captions say, given the parameters p it was drawn with. The
    bounds come from each family's definition (locomotion.py, in_place.py), with room for the body's
    sway; none is fitted to what the generator happens to output."""
    out = []
    if family in IN_PLACE:  # "in place", "on the spot": the feet end about where they started
        out.append(("stays in place: moves < 0.5 m", m["dist"] < 0.5))
    if family not in TURNING:
        out.append(("keeps its heading within 15 deg", abs(m["turn"]) < 15))
    sign = {"left": 1.0, "right": -1.0}.get(p.get("side"), 0.0)
    steps, reps = p.get("steps", 1), p.get("reps", 1)
    if family in ("walk_forward", "run"):  # a walking step 0.3-0.8 m, a running one 0.6-1.8 m
        lo, hi = (0.2, 0.9) if family == "walk_forward" else (0.4, 2.0)
        out.append((f"moves forward {lo}-{hi} m a step", lo * steps < m["fwd"] < hi * steps))
        out.append(("in a straight line", abs(m["left"]) < 0.1 + 0.1 * m["fwd"]))
    if family == "walk_backward":  # shorter steps than walking forward
        out.append(("moves backward 0.1-0.7 m a step", 0.1 * steps < -m["fwd"] < 0.7 * steps))
        out.append(("in a straight line", abs(m["left"]) < 0.1 + 0.1 * abs(m["fwd"])))
    if family.startswith("sidestep_"):  # each pair of steps moves the body its stance width, 0.25-0.45 m
        out.append((f"moves to the {p['side']} 0.15-0.6 m a pair", 0.15 * steps < sign * m["left"] < 0.6 * steps))
        out.append(("sideways, not forward or back", abs(m["fwd"]) < 0.25))
    if family in ("turn_left", "turn_right"):
        out.append((f"turns {p['side']} {p['angle']} deg (+-20)", abs(m["turn"] - sign * p["angle"]) < 20))
    if family == "walk_circle":  # a full circle: the heading turns 360 degrees and the walk ends near its start
        out.append((f"turns a full circle to the {p['side']}", abs(m["turn"] - sign * 360) < 30))
        out.append(("ends nearer its start than its path is long", m["dist"] < 0.5 * m["path"]))
    if family.startswith("jump_"):  # flights of 0.12-0.45 m (in place), 0.2-0.35 m (forward)
        out.append(("leaves the floor", m["airborne"] > 0.05 and m["rise"] > 0.08))
    if family == "jump_in_place" and p["high"]:
        out.append(("jumps high: the pelvis rises > 0.2 m", m["rise"] > 0.2))
    if family == "jump_forward":  # each jump lands 0.35-0.6 m (short) or 0.8-1.2 m (far) ahead
        lo, hi = (0.8, 1.2) if p["far"] else (0.35, 0.6)
        out.append((f"jumps {lo}-{hi} m forward each time", (lo - 0.15) * reps < m["fwd"] < (hi + 0.15) * reps))
    if family == "squat":  # half squats bend the thighs 50 degrees, deep ones 90
        out.append(("lowers the pelvis", m["drop"] > (0.25 if p["deep"] else 0.1)))
        out.append(("and stands back up", abs(m["end_drop"]) < 0.05))
    if family == "sit_down":  # onto a seat about knee height, and stays there
        out.append(("sits: the pelvis ends > 0.25 m lower", m["end_drop"] > 0.25))
    if family == "stand_idle":
        out.append(("stands: the pelvis stays at standing height", m["drop"] < 0.05 and m["rise"] < 0.05))
    if family == "bow":  # the trunk folds 20-35 (slightly) or 55-75 degrees (deeply)
        out.append(("the head dips", m["head_dip"] > (0.2 if p["deep"] else 0.05)))
    if family.startswith("wave_"):
        other = "left" if p["side"] == "right" else "right"
        out.append((f"the {p['side']} hand rises above the shoulder", m[f"hand_up_{p['side']}"] > 0.1))
        out.append((f"the {other} hand stays down", m[f"hand_up_{other}"] < 0.0))
    if family.startswith("kick_"):
        other = "left" if p["side"] == "right" else "right"
        out.append((f"the {p['side']} foot kicks up", m[f"foot_up_{p['side']}"] > 0.25))
        out.append((f"the {other} foot stays down", m[f"foot_up_{other}"] < 0.15))
    if family == "punch":  # a punch straightens the arm forward (an arm is ~0.55 m long)
        for side in ("left", "right") if p["side"] == "both" else (p["side"],):
            out.append((f"the {side} fist reaches forward", m[f"reach_{side}"] > 0.4))
    if family == "clap":
        out.append(("the hands meet", m["clap"] < 0.12))
    if family == "raise_both_arms":
        low = min(m["hand_up_left"], m["hand_up_right"])
        out.append(("both hands reach shoulder height" + (" and above" if p["high"] else ""),
                    low > (0.3 if p["high"] else -0.1)))
    return out


def _broken(family, params, facts, where):
    return [f"{where} {family} {params}: not {what}" for what, ok in promises(family, params, facts) if not ok]


def test_every_family_does_what_its_captions_say():
    table, broken = {}, []
    for fi, family in enumerate(FAMILIES):
        rows = []
        for s in range(8):
            clip = C.generate_clip((family,), np.random.default_rng([21, fi, s]))
            facts = motion_facts(through_features(clip.joints))
            broken += _broken(family, clip.segments[0].params, facts, f"seed [21, {fi}, {s}]")
            rows.append([facts[k] for k in ("dist", "fwd", "left", "turn", "path", "rise", "drop")])
        table[family] = np.median(rows, axis=0)
    print("\nfamily            dist    fwd   left   turn   path   rise   drop   (medians of 8 clips)")
    for family, med in table.items():
        print(f"{family:16s}" + "".join(f"{v:7.2f}" for v in med))
    assert not broken, "\n".join(broken)


def test_long_sequences_tile_and_each_segment_does_what_its_caption_says():
    broken = []
    for i in range(4):
        clip = S.generate_long(np.random.default_rng([31, i]))
        segs, T = clip.segments, len(clip.joints)
        assert 20 * FPS <= T <= 60 * FPS and 3 <= len(segs) <= 8
        assert segs[0].start == 0 and segs[-1].end == T and all(a.end == b.start for a, b in zip(segs, segs[1:]))
        # every span loads as an item of its own: T2M's 40 <= feature frames < 200
        assert all(S.MIN_SPAN <= s.end - s.start <= 200 for s in segs)
        assert all(a.family != b.family for a, b in zip(segs, segs[1:]))
        assert "sit_down" not in [s.family for s in segs[:-1]]  # it ends seated
        assert 1 <= len(clip.captions) <= 2 and all(s.caption.endswith(".") for s in segs)
        j = through_features(clip.joints)
        for s in segs:
            facts = motion_facts(j[s.start:s.end])
            broken += _broken(s.family, s.params, facts, f"long [31, {i}] frames [{s.start}, {s.end})")
    assert not broken, "\n".join(broken)


# --- path sequences: what a game's locomotion controller asks for ------------------------------------------

PATH_FAMILIES = {"walk": {"walk_forward", "walk_circle"}, "run": {"run"}, "backpedal": {"walk_backward"},
                 "sidestep": {"sidestep_left", "sidestep_right"}, "diagonal": {"walk_forward"},
                 "turn": {"turn_left", "turn_right"}, "stand": {"stand_idle"}, "pause": {"walk_forward", "run"}}


@pytest.fixture(scope="module")
def path_clips():
    """6 path sequences and 4 control sequences straight from the generator, and their joints as the features give
    them back."""
    clips = [PT.generate_path_sequence(np.random.default_rng([41, i])) for i in range(6)]
    clips += [PT.generate_path_sequence(np.random.default_rng([43, i]), PT.CONTROL_KINDS) for i in range(4)]
    return [(clip, through_features(clip.joints)) for clip in clips]


def _facing(j):
    across = (j[:, 2] - j[:, 1]) + (j[:, 17] - j[:, 16])  # as motion_facts: the hips and the shoulders
    return np.unwrap(np.arctan2(across[:, 2], -across[:, 0]))


def gait_motion(j, cadence):
    """Per frame, over the gait cycle (two steps) centred on it: root velocity along the facing and to its
    left (m/s; along the path: on a curve the cycle's chord is scaled up to its arc), and the turning rate
    (deg/s, > 0 left). Entry k is frame k + h, h half a cycle."""
    h = max(1, int(round(FPS / cadence)))
    face = _facing(j)
    turned = face[2 * h:] - face[:-2 * h]
    arc = np.where(np.abs(turned) > 1e-6, (turned / 2) / np.sin(turned / 2 + 1e-12), 1.0)
    v = (j[2 * h:, 0, [0, 2]] - j[:-2 * h, 0, [0, 2]]) * (FPS / (2 * h) * arc)[:, None]
    f = face[h:len(face) - h]
    fwd = v[:, 0] * np.sin(f) + v[:, 1] * np.cos(f)
    left = v[:, 0] * np.cos(f) - v[:, 1] * np.sin(f)
    return fwd, left, np.degrees(turned) * FPS / (2 * h), h


def steady_motion(seg, j, keys=("steady", "walk")):
    """(forward, left, turning rate) over the frames a segment keeps its pace on, or if that is under a
    gait cycle all those it steps on (None if that is too)."""
    fwd, left, turn, h = gait_motion(j, seg.params["cadence"])
    for key in keys:
        a, b = max(0, seg.params[key][0] - h), min(len(fwd), seg.params[key][1] - h)
        if b - a >= 2 * h:
            return fwd[a:b], left[a:b], turn[a:b]
    return None


def path_promises(seg, j):
    """(promise, kept) for what a path segment's caption says, measured on its frames j (through the
    features). The bounds come from paths.py's parameters, with room for the body's sway."""
    p, text, kind = seg.params, seg.caption, seg.params["kind"]
    out = [(f"is a {kind} ({seg.family})", seg.family in PATH_FAMILIES[kind])]
    m = motion_facts(j)
    steady = steady_motion(seg, j) if "steady" in p else None
    if kind in ("walk", "run"):
        speed = float(np.median(np.hypot(steady[0], steady[1]))) if steady else None
        if steady:
            fwd, left = np.median(steady[0]), np.median(steady[1])
            out.append(("moves the way it faces", fwd > 0.25 and abs(left) < 0.15 + 0.2 * fwd))
            out.append((f"a {kind} at a {kind}'s speed", speed < 2.0 if kind == "walk" else speed > 1.5))
            if "then" in text and "turns" not in text:  # "walks slowly, then quickly", "runs fast and then jogs"
                v, third = np.hypot(steady[0], steady[1]), len(steady[0]) // 3
                early, late = np.median(v[:third]), np.median(v[-third:])
                paces = [w for w in re.findall(r"slowly|normal pace|quickly|jogs|runs fast|runs", text)]
                order = ["slowly", "normal pace", "quickly", "jogs", "runs", "runs fast"]
                faster = order.index(paces[-1]) > order.index(paces[0])
                out.append(("speeds up" if faster else "slows down", (late - early) * (1 if faster else -1) > 0.1))
            else:  # speed words are only used when the whole segment keeps to their band
                for word, ok in (("slowly", speed < 1.15), ("quickly", speed > 1.3), ("jogs", speed < 3.0),
                                 ("runs fast", speed > 3.0)):
                    if word in text:
                        out.append((f"{word}: {speed:.2f} m/s", ok))
        sides = [{"counterclockwise": "left", "clockwise": "right"}.get(w, w)
                 for w in re.findall(r"\b(left|right|counterclockwise|clockwise)\b", text)]
        want = ["left" if t[0] > 0 else "right" for t in p["turns"]]
        named = [want[0]] if len(want) == 2 and want[0] == want[1] else want  # "turns left twice"
        out.append(("names its turns in order", sides == named))
        h = np.degrees(_facing(j))
        for deg, a, b in p["turns"]:  # each turn it names happens, that way, over its frames
            turned = h[min(b, len(h)) - 1] - h[a]
            out.append((f"turns {deg:+.0f} deg over frames {a}-{b}", np.sign(turned) == np.sign(deg)
                        and abs(turned) > max(20.0, 0.6 * abs(deg))))
        if "circle" in text:
            out.append(("walks a circle: 280+ deg", max(abs(t[0]) for t in p["turns"]) >= 300 and abs(m["turn"]) > 280))
        if not p["turns"]:
            out.append(("keeps its heading within 45 deg", abs(m["turn"]) < 45))
        if "straight" in text:
            out.append(("keeps its heading within 25 deg", abs(m["turn"]) < 25))
    if kind == "backpedal" and steady:
        fwd, left = np.median(steady[0]), np.median(steady[1])
        out.append(("moves backward", fwd < -0.15 and abs(left) < 0.1))
        if "slowly" in text:
            out.append((f"slowly: {-fwd:.2f} m/s", -fwd < 0.5))
    said = re.search(r"\b(left|right)\b", text)
    sign = {"left": 1, "right": -1}.get(said.group(1) if said else None, 0)
    if kind == "diagonal" and (steady := steady_motion(seg, j, ("steady",))):  # not turning into it
        angle = np.degrees(np.arctan2(np.median(steady[1]), np.median(steady[0])))
        out.append((f"moves forward and to the {said.group(1)}: 25-55 deg off its facing", 25 < sign * angle < 55))
    if kind == "sidestep":
        out.append((f"moves to the {said.group(1)}", 0.15 * p["steps"] < sign * m["left"] < 0.6 * p["steps"]))
        out.append(("sideways, not forward or back", abs(m["fwd"]) < 0.25))
    if kind == "turn":
        out.append((f"turns {said.group(1)} {p['angle']:.0f} deg (+-20)", abs(m["turn"] - sign * p["angle"]) < 20))
        out.append(("on the spot: moves < 0.5 m", m["dist"] < 0.5))
        for words, lo, hi in (("slightly|a little", 20, 70), ("turns around to|other way", 120, 240),
                              ("full circle|all the way|spins", 280, 400)):
            if re.search(words, text):
                out.append((f"{words}: turns {lo}-{hi} deg", lo < abs(m["turn"]) < hi))
    if kind in ("walk", "run"):  # a change of pace is named, unless it turns or is a control sequence's "pace"
        v0, v1 = p["speeds"]
        named = "then" in text and "turns" not in text
        out.append(("names its change of pace unless it turns or is unnamed", named == (
            PT._band(kind, v0) != PT._band(kind, v1) and not p["turns"] and not p["unnamed"])))
        if p["unnamed"]:
            out.append(("changes pace, unnamed", abs(v1 - v0) > 0.1))
    if kind == "pause":  # a walk or run, a stop, the same on, captioned as the walk or run alone
        out.append((f"{p['gait']}s, as its caption says", ("runs" in text) == (p["gait"] == "run")))
        out.append(("its caption does not say it stops", "stop" not in text))
        a, b = p["stop"]
        v = np.linalg.norm(np.diff(j[:, 0, [0, 2]], axis=0), axis=-1) * FPS
        still = np.flatnonzero(np.diff(np.concatenate([[0], v[a:b] < 0.05, [0]]).astype(int)))
        out.append(("stands still 1 s or more between its moves", (still[1::2] - still[::2]).max(initial=0) >= FPS))
        for what, (s0, s1) in (("before", (0, a)), ("after", (b, len(j) - 1))):
            d = j[s1, 0, [0, 2]] - j[s0, 0, [0, 2]]
            face = _facing(j)[s0]
            out.append((f"moves forward 0.6 m or more {what} it stops", d @ [np.sin(face), np.cos(face)] > 0.6))
        out.append(("keeps its heading within 45 deg", abs(m["turn"]) < 45))
    if kind == "stand":
        out.append(("stands: moves < 5 cm, turns < 5 deg", m["dist"] < 0.05 and abs(m["turn"]) < 5))
    if kind != "stand":
        out.append(("names its side", _sided(seg.family, text)))
    return out


def test_path_sequences_tile_and_each_segment_does_what_its_caption_says(path_clips):
    broken, kinds = [], set()
    for i, (clip, j) in enumerate(path_clips):
        segs, T = clip.segments, len(clip.joints)
        assert 20 * FPS <= T <= 60 * FPS
        assert segs[0].start == 0 and segs[-1].end == T and all(a.end == b.start for a, b in zip(segs, segs[1:]))
        # every span loads as an item of its own: T2M's 40 <= feature frames < 200
        assert all(S.MIN_SPAN <= s.end - s.start < 200 for s in segs)
        assert all(s.family in FAMILIES for s in segs)
        assert 1 <= len(clip.captions) <= 2
        for s in segs:
            assert s.caption.endswith(".") and captions.pos_tokens(s.caption)  # every word is in the lexicon
            kinds.add(s.params["kind"])
            broken += [f"path [41, {i}] frames [{s.start}, {s.end}) {s.caption!r}: not {what}"
                       for what, ok in path_promises(s, j[s.start:s.end]) if not ok]
    assert kinds == set(PT.KINDS) | {"pause"}  # a "pace" is a walk or run whose caption leaves its speed out
    assert any(s.params.get("unnamed") for clip, _ in path_clips for s in clip.segments)
    assert not broken, "\n".join(broken)


def test_path_sequences_feet_floor_and_smoothness(path_clips):
    """The thresholds of the families' tests above (test_feet_do_not_slide, test_feet_on_the_floor...,
    test_no_flips_and_smooth), held by each kind of segment."""
    want = HUMANML3D.bone_lengths[BONES]
    slides, planted, pelvis = [], {}, []
    for clip, _ in path_clips:
        j = clip.joints
        assert np.abs(np.linalg.norm(j[:, BONES] - j[:, PARENTS[BONES]], axis=-1) - want).max() < 1e-5
        assert j[..., 1].min() > -0.01
        b = j[:, BONES] - j[:, PARENTS[BONES]]
        b /= np.linalg.norm(b, axis=-1, keepdims=True)
        ang = np.degrees(np.arccos(np.clip((b[1:] * b[:-1]).sum(-1), -1, 1)))
        acc = np.linalg.norm(np.diff(j, 2, axis=0), axis=-1) * FPS * FPS
        assert ang.max() < 60 and acc.max() < 200
        for s in clip.segments:
            kind, seg = s.params.get("gait", s.params["kind"]), j[s.start:s.end]  # a pause walks or runs
            slide, toe = _slides(seg)
            slides.append(slide)
            planted.setdefault(kind, []).append(toe)
            grounded = (seg[:, [10, 11], 1].min(axis=1) < 0.03) | (seg[:, [7, 8], 1].min(axis=1) < 0.075)
            assert grounded.mean() > (0.5 if kind == "run" else 0.97), (kind, s.caption)
            a = acc[max(0, s.start - 1):s.end - 2, 0]
            assert a.max() < (100 if kind == "run" else 50), (kind, s.caption)
            if kind != "run":
                pelvis.append(a)
    slide = np.concatenate(slides)
    assert np.percentile(slide, 95) < 0.02 and slide.mean() < 0.005
    assert np.percentile(np.concatenate(pelvis), 95) < 20
    # Planted toes, per kind: the families' levels. Walks, diagonals, sidesteps and stands hold the clips'
    # thresholds; turns on the spot and backward steps land their feet turning or still moving 1-5 cm in
    # their last frame over the floor, as the families' turn_left and walk_backward do (2% and 1% of their
    # frames); a run's toes leave and reach the floor at running speed (the run family: p99 5 cm, 5%).
    for kinds, p99, over in ((("walk", "diagonal", "sidestep", "stand"), 0.01, 0.02),
                             (("turn", "backpedal"), 0.05, 0.03), (("run",), 0.08, 0.08)):
        toe = np.concatenate([t for k in kinds for t in planted.get(k, [])])
        assert np.percentile(toe, 99) < p99 and (toe > 0.01).mean() < over, (kinds, np.percentile(toe, 99))


def test_path_sequences_cover_speeds_and_turning_rates():
    """What a controller asks for is there: walks from under 0.9 to over 1.6 m/s, runs to over 3.5, at
    speeds that differ continuously (not three paces), and walks that turn faster than 60 deg/s."""
    speeds, turning = {"walk": [], "run": []}, []
    for i in range(16):
        clip = PT.generate_path_sequence(np.random.default_rng([42, i]))
        j = through_features(clip.joints)
        for s in clip.segments:
            if s.params["kind"] in speeds and (steady := steady_motion(s, j[s.start:s.end])):
                speeds[s.params["kind"]].append(float(np.median(np.hypot(steady[0], steady[1]))))
                if s.params["kind"] == "walk":
                    turning.append(np.abs(steady[2]).max())
    walk, run = np.array(speeds["walk"]), np.array(speeds["run"])
    assert len(walk) >= 20 and len(run) >= 12
    assert walk.min() < 0.9 and walk.max() > 1.6 and run.max() > 3.5 and run.min() < 2.4
    assert np.median(run) > 1.5 * np.median(walk)
    # a continuum, not three paces: every quarter m/s of the walks' range is walked, every 0.75 of the runs' run
    assert (np.histogram(walk, np.arange(0.5, 1.8, 0.25))[0] > 0).all()
    assert (np.histogram(run, np.arange(1.75, 4.1, 0.75))[0] > 0).all()
    assert max(turning) > 60


def test_gait_verb_is_how_the_data_names_a_steady_walk_or_run():
    """The control benchmark prompts a path of speed v with `gait_verb(v)`: it must be the verb the data's own
    steady, straight travel segments at v are captioned with, for walks, jogs and runs alike."""
    seen = set()
    for i in range(400):
        action = PT._travel(np.random.default_rng([43, i]), "walk" if i % 2 else "run", 6.0)
        v0, v1 = action.params["speeds"]
        if action.params["turns"] or v0 != v1:
            continue
        verb = PT.gait_verb(v0)
        assert any(p.startswith(f"{verb} forward") for p in action.phrases), (v0, verb, action.phrases)
        seen.add(verb)
    assert seen == {"walks", "jogs", "runs"}, seen


def test_path_sequences_are_timelines(built):
    """timelines.py reads a path sequence as it reads a long one: whole, one segment per move."""
    info = json.loads((built / "dataset.json").read_text())
    lines = {t.clip_id: t for split in ("train", "val", "test") for t in read_timelines(built, split)}
    for i in PATH:
        segments = info["segments"][i]
        assert [(s.first, s.stop) for s in lines[i].segments] == [(g["start"], min(g["end"], len(lines[i].features)))
                                                                   for g in segments]
        assert all(len(s.captions) == 1 for s in lines[i].segments)


def test_control_sequences_load_only_when_asked(built):
    """The VQ, the classifier, the caption index and every evaluation read the dataset without its control
    sequences (as before they existed); the control adapter's tokens and captions with them."""
    control = set(json.loads((built / "dataset.json").read_text())["control_only"])
    assert control == set(CONTROL)
    for split in ("train", "val", "test"):
        ids = set((built / f"{split}.txt").read_text().split()) & control
        plain = {it.clip_id.split(":")[0] for it in MotionDataset.load(built, split).items}
        every = {it.clip_id.split(":")[0] for it in MotionDataset.load(built, split, control_sequences=True).items}
        assert not plain & control and every - plain == ids
        plain = {t.clip_id for t in read_timelines(built, split)}
        every = {t.clip_id for t in read_timelines(built, split, control_sequences=True)}
        assert not plain & control and every - plain == ids
    assert set((built / "train.txt").read_text().split()) & control  # the adapter has some to learn from
