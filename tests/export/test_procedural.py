"""The procedural HumanML3D-layout dataset: determinism, layout, people-like motion, captions."""
import json
import re

import numpy as np
import pytest

from mogo_export.data import procedural as P
from mogo_export.data.dataset import read_captions
from mogo_export.data.procedural import captions, clips as C, families, locomotion, writer
from mogo_export.data.procedural.action import FULL_BUDGET, TimeBudget
from mogo_export.data.procedural.pose import FPS, MAX_SECONDS
from mogo_runtime.features import FeatureLayout, recover_from_ric
from mogo_runtime.skeleton import HUMANML3D

FAMILIES = list(families.FAMILIES)
FEET = [7, 10, 8, 11]  # left ankle, left toe, right ankle, right toe (HumanML3D's contact joints)
PARENTS = np.array(HUMANML3D.parents)
BONES = np.arange(1, HUMANML3D.num_joints)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    # 27 clips: every 5th is a sequence, so the first 21 singles cover all 21 families
    return P.build_dataset(tmp_path_factory.mktemp("proc") / "ds", num_clips=27, seed=7, progress=False, workers=2)


@pytest.fixture(scope="module")
def clips():
    """World joints for 3 clips of every family and 6 sequences, straight from the generator."""
    out = []
    for f in FAMILIES:
        for s in range(3):
            joints, _ = C.generate_clip((f,), np.random.default_rng([11, s, FAMILIES.index(f)]))
            out.append((f, joints))
    for i, pair in enumerate([("walk_forward", "jump_in_place"), ("run", "sit_down"), ("kick_left", "turn_right"),
                              ("jump_forward", "walk_backward"), ("squat", "wave_left_hand"), ("bow", "clap")]):
        joints, _ = C.generate_clip(pair, np.random.default_rng([12, i]))
        out.append((C.label_for(pair), joints))
    return out


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_whatever_the_workers(tmp_path):
    a = P.build_dataset(tmp_path / "a", num_clips=20, seed=3, progress=False, workers=1)
    b = P.build_dataset(tmp_path / "b", num_clips=20, seed=3, progress=False, workers=2)
    fa, fb = _files(a), _files(b)
    assert len(fa) == 4 * 20 + 3 + 2 + 1
    assert fa.keys() == fb.keys()
    assert [k for k in fa if fa[k] != fb[k]] == []
    c = P.build_dataset(tmp_path / "c", num_clips=20, seed=4, progress=False, workers=1)
    assert _files(c)["new_joint_vecs/000000.npy"] != fa["new_joint_vecs/000000.npy"]


def test_every_family_present_and_labelled(built):
    labels = {p.stem: p.read_text().strip() for p in (built / "labels").glob("*.txt")}
    assert len(labels) == 27
    singles = {v for v in labels.values() if not v.startswith("seq:")}
    assert singles == set(FAMILIES)
    seqs = [v for v in labels.values() if v.startswith("seq:")]
    assert len(seqs) == 5
    for s in seqs:
        first, second = s[4:].split("+")
        assert first in FAMILIES and second in FAMILIES and first != second
    info = json.loads((built / "dataset.json").read_text())
    assert info["label_counts"] == {k: list(labels.values()).count(k) for k in set(labels.values())}
    assert info["families"] == FAMILIES and info["seed"] == 7 and info["num_clips"] == 27
    assert info["fps"] == 20.0 and info["skeleton"]["name"] == "humanml3d" and info["feature_dim"] == 263


def test_layout_shapes_splits_and_stats(built):
    ids = sorted(p.stem for p in (built / "new_joint_vecs").glob("*.npy"))
    assert ids == [f"{i:06d}" for i in range(27)]
    for i in ids:
        f = np.load(built / "new_joint_vecs" / f"{i}.npy")
        j = np.load(built / "new_joints" / f"{i}.npy")
        assert f.dtype == np.float32 and j.dtype == np.float32
        assert f.shape == (len(j) - 1, 263) and j.shape[1:] == (22, 3)
        assert 41 <= len(j) <= 200  # 2..10 s at 20 fps; features keep T2M's 40 <= T < 200
        assert np.isfinite(f).all()
        assert abs(j[..., 1].min()) < 1e-6  # HumanML3D puts the lowest joint of the clip on the floor
    splits = {s: (built / f"{s}.txt").read_text().split() for s in ("train", "val", "test")}
    assert sorted(sum(splits.values(), [])) == ids
    assert [len(v) for v in splits.values()] == [22, 4, 1]  # 80/15/5 of 27, rounded
    mean, std = np.load(built / "Mean.npy"), np.load(built / "Std.npy")
    train = np.concatenate([np.load(built / "new_joint_vecs" / f"{i}.npy") for i in splits["train"]]).astype(np.float64)
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
    assert checked >= 25 and turning >= 2


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
        assert grounded.mean() > (0.5 if re.search("jump|run", name) else 0.97), name


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
        assert acc[:, 0].max() < (100 if re.search("jump|run", name) else 50), name  # take-off, landing
        pelvis.append(acc[:, 0])
    assert np.percentile(np.concatenate(pelvis), 95) < 20


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


def test_captions(built):
    for p in sorted((built / "texts").glob("*.txt")):
        caps = read_captions(p)
        label = (built / "labels" / p.name).read_text().strip()
        assert 3 <= len(caps) <= 4 and len({c.text for c in caps}) == len(caps)
        tags = {"DET", "NOUN", "VERB", "ADV", "ADJ", "ADP", "PRON", "NUM", "CCONJ", "AUX", "INTJ"}
        for c in caps:
            assert len(c.tokens) == len(re.findall(r"[a-z]+", c.text))  # one word/POS per word
            assert " ".join(c.tokens) == captions.pos_tokens(c.text)
            assert {t.split("/")[1] for t in c.tokens} <= tags
            assert c.start == c.end == 0.0
            assert c.text.endswith(".") and c.text == c.text.lower()
        for side in ("left", "right"):  # sided actions name their side in every caption
            if re.fullmatch(rf"(wave_{side}_hand|kick_{side}|sidestep_{side}|turn_{side})", label):
                assert all(side in c.text for c in caps), (label, caps)


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
    joints, caps = C.generate_clip(("walk_forward", "jump_in_place"), np.random.default_rng(5))
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
