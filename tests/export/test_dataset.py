"""MotionDataset: the HumanML3D / KIT-ML folder layout, sub-clip captions, long sequences' segments, and errors
that name the file."""
import json

import numpy as np
import pytest

from mogo_export.data import procedural as P
from mogo_export.data.dataset import (MotionDataset, Segment, denormalize, load_mean_std, normalize,
                                      parse_caption_line)

LINE = "a person walks forward.#a/DET person/NOUN walk/VERB forward/ADV#0.0#0.0"


def write_dataset(root, clips, dim=263, splits=None, stats=True):
    """clips: {id: (features or None, caption lines or None, label or None)}; splits: {name: [ids]}."""
    for sub in ("new_joint_vecs", "texts", "labels"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    for cid, (feat, lines, label) in clips.items():
        if feat is not None:
            np.save(root / "new_joint_vecs" / f"{cid}.npy", feat)
        if lines is not None:
            (root / "texts" / f"{cid}.txt").write_text("\n".join(lines) + "\n")
        if label is not None:
            (root / "labels" / f"{cid}.txt").write_text(label + "\n")
    for name, ids in (splits or {"train": list(clips)}).items():
        (root / f"{name}.txt").write_text("\n".join(ids) + "\n")
    if stats:
        np.save(root / "Mean.npy", np.zeros(dim, np.float32))
        np.save(root / "Std.npy", np.full(dim, 2.0, np.float32))
    return root


def feats(t, dim=263, seed=0):
    return np.random.default_rng(seed).standard_normal((t, dim)).astype(np.float32)


def test_loads_the_procedural_dataset(tmp_path):
    root = P.build_dataset(tmp_path / "proc", num_clips=12, seed=2, progress=False, workers=1, long_sequences=0,
                           path_sequences=0, control_sequences=0)
    sizes = {}
    for split in ("train", "val", "test"):
        ds = MotionDataset.load(root, split)
        ids = (root / f"{split}.txt").read_text().split()
        assert [it.clip_id for it in ds] == ids  # every procedural clip has 40..199 feature frames
        sizes[split] = len(ds)
        for clip_id, x, caps, label in ds:
            assert x.dtype == np.float32 and x.shape[1] == 263
            np.testing.assert_array_equal(x, np.load(root / "new_joint_vecs" / f"{clip_id}.npy"))
            assert len(caps) >= 3 and all(c.endswith(".") for c in caps)
            assert label == (root / "labels" / f"{clip_id}.txt").read_text().strip()
    assert sizes == {"train": 9, "val": 2, "test": 1}  # 80/15/5, but no split left empty
    ds = MotionDataset.load(root, "train")
    np.testing.assert_array_equal(ds.mean, np.load(root / "Mean.npy"))
    x = ds[0].features
    np.testing.assert_allclose(ds.normalize(x), (x - ds.mean) / ds.std, rtol=1e-6)
    np.testing.assert_allclose(ds.denormalize(ds.normalize(x)), x, atol=1e-5)


def test_long_sequences_load_as_their_segments(tmp_path):
    root = P.build_dataset(tmp_path / "proc", num_clips=10, seed=5, progress=False, workers=1, long_sequences=2,
                           path_sequences=1, control_sequences=0)
    table = json.loads((root / "dataset.json").read_text())["segments"]
    assert sorted(table) == ["000010", "000011", "000012"]  # two long sequences, then a path sequence
    seen = []
    for split in ("train", "val", "test"):
        ds = MotionDataset.load(root, split)
        whole = {it.clip_id: it for it in MotionDataset.load(root, split, max_frames=1300)}
        for cid in sorted(set((root / f"{split}.txt").read_text().split()) & set(table)):
            seen.append(cid)
            segs = [Segment(s["family"], s["start"], s["end"]) for s in table[cid]]
            assert ds.segments[cid] == segs
            x = np.load(root / "new_joint_vecs" / f"{cid}.npy")
            # the whole sequence (20-60 s) is past T2M's 200 frames; each action is an item, in order, with
            # its own caption and its family as its label
            items = [it for it in ds if it.clip_id.split(":")[0] == cid]
            assert [it.clip_id for it in items] == [f"{cid}:{s.start}-{s.end}" for s in segs]
            for it, s in zip(items, segs):
                assert it.label == s.family and len(it.captions) == 1
                np.testing.assert_array_equal(it.features, x[s.start:s.end])
            label = (root / "labels" / f"{cid}.txt").read_text().strip()
            assert label == "seq:" + "+".join(s.family for s in segs)
            assert whole[cid].label == label and 1 <= len(whole[cid].captions) <= 2
            assert len(whole[cid].features) == len(x) >= 399
    assert sorted(seen) == ["000010", "000011", "000012"]  # one in each split
    assert MotionDataset.load(root, "train").segments.keys() <= set(table)


def test_span_labels_from_segments(tmp_path):
    x = feats(150)
    lines = [LINE, "a person jumps.#x/X#0.0#3.0", "a person waves.#x/X#2.5#7.45", "a person bows.#x/X#1.0#5.0"]
    root = write_dataset(tmp_path, {"s": (x, lines, "seq:jump_in_place+wave_right_hand")})
    (root / "dataset.json").write_text(json.dumps({"segments": {"s": [
        {"family": "jump_in_place", "start": 0, "end": 60}, {"family": "wave_right_hand", "start": 60, "end": 150}]}}))
    ds = MotionDataset.load(root)
    # a span takes the family of the segment covering at least half of it (1.0-5.0 s: half each, the first)
    assert [(it.clip_id, it.label) for it in ds] == [
        ("s", "seq:jump_in_place+wave_right_hand"), ("s:0-60", "jump_in_place"), ("s:50-149", "wave_right_hand"),
        ("s:20-100", "jump_in_place")]
    (root / "dataset.json").write_text('{"segments": {"s": [{"family": "x"}]}}')
    with pytest.raises(ValueError, match=r"dataset\.json: unreadable segments"):
        MotionDataset.load(root)


def test_subclip_captions_become_their_own_items(tmp_path):
    x = feats(120)
    lines = [LINE, "a person jumps.#a/DET person/NOUN jump/VERB#1.0#4.5", "someone hops.#x/X#1.0#4.5",
             "a person stops.#x/X#5.0#5.5", "a person waves.#x/X#nan#nan"]
    root = write_dataset(tmp_path, {"000001": (x, lines, "walk")})
    ds = MotionDataset.load(root)
    assert [it.clip_id for it in ds] == ["000001", "000001:20-90"]  # 5.0-5.5 s is 10 frames: too short
    whole, part = ds
    assert whole.captions == ["a person walks forward.", "a person waves."]  # NaN tags read as the whole clip
    assert part.captions == ["a person jumps.", "someone hops."] and part.label == "walk"
    np.testing.assert_array_equal(part.features, x[20:90])  # [start * fps, end * fps) at 20 fps


def test_length_filter_and_kit(tmp_path):
    root = write_dataset(tmp_path / "h", {"a": (feats(39), [LINE], None), "b": (feats(40), [LINE], None),
                                          "c": (feats(199), [LINE], None), "d": (feats(200), [LINE], None)})
    assert [it.clip_id for it in MotionDataset.load(root)] == ["b", "c"]  # T2M: 40 <= T < 200
    assert [it.clip_id for it in MotionDataset.load(root, min_frames=10, max_frames=201)] == ["a", "b", "c", "d"]
    assert MotionDataset.load(root)[0].label is None
    kit = write_dataset(tmp_path / "k", {"k1": (feats(30, 251), [LINE, "x.#x/X#0.0#2.0"], None)}, dim=251)
    ds = MotionDataset.load(kit, skeleton="kit")
    assert ds.fps == 12.5 and [it.clip_id for it in ds] == ["k1", "k1:0-25"]  # KIT: min 24 frames, 12.5 fps
    assert ds[0].features.shape == (30, 251)


def test_nan_features_name_the_file(tmp_path):
    x = feats(60)
    x[7, 3] = np.nan
    root = write_dataset(tmp_path, {"bad": (x, [LINE], None)})
    with pytest.raises(ValueError, match=r"new_joint_vecs/bad\.npy: contains NaN or inf \(first at frame 7\)"):
        MotionDataset.load(root)


def test_wrong_width_names_the_file(tmp_path):
    root = write_dataset(tmp_path / "h", {"w": (feats(60, 251), [LINE], None)})
    with pytest.raises(ValueError, match=r"w\.npy: expected \(T, 263\) features for humanml3d, got shape \(60, 251\)"):
        MotionDataset.load(root)
    kit = write_dataset(tmp_path / "k", {"w": (feats(60, 263), [LINE], None)}, dim=251)
    with pytest.raises(ValueError, match=r"w\.npy: expected \(T, 251\) features for kit"):
        MotionDataset.load(kit, skeleton="kit")
    flat = write_dataset(tmp_path / "f", {"w": (np.zeros(263, np.float32), [LINE], None)})
    with pytest.raises(ValueError, match="got shape"):
        MotionDataset.load(flat)


def test_missing_caption_file_names_it(tmp_path):
    root = write_dataset(tmp_path, {"ok": (feats(60), [LINE], None), "nocap": (feats(60), None, None)})
    with pytest.raises(FileNotFoundError, match=r"caption file missing: .*texts/nocap\.txt"):
        MotionDataset.load(root)


def test_unknown_split_entry_names_the_split_file(tmp_path):
    root = write_dataset(tmp_path, {"ok": (feats(60), [LINE], None)}, splits={"train": ["ok", "ghost"]})
    with pytest.raises(FileNotFoundError, match=r"train\.txt lists 'ghost' but .*new_joint_vecs/ghost\.npy"):
        MotionDataset.load(root)


def test_other_bad_inputs(tmp_path):
    root = write_dataset(tmp_path / "a", {"c": (feats(60), ["no hashes here"], None)})
    with pytest.raises(ValueError, match=r"texts/c\.txt:1: expected 'caption#tokens#start#end'"):
        MotionDataset.load(root)
    root = write_dataset(tmp_path / "b", {"c": (feats(60), ["x.#x/X#soon#later"], None)})
    with pytest.raises(ValueError, match=r"c\.txt:1: start/end must be numbers"):
        MotionDataset.load(root)
    root = write_dataset(tmp_path / "c", {"c": (feats(60), [LINE], None)}, stats=False)
    with pytest.raises(FileNotFoundError, match=r"Mean\.npy"):
        MotionDataset.load(root)
    root = write_dataset(tmp_path / "d", {"c": (feats(60), [LINE], None)})
    with pytest.raises(FileNotFoundError, match=r"split file missing: .*val\.txt"):
        MotionDataset.load(root, "val")
    with pytest.raises(ValueError, match="unknown split 'dev'"):
        MotionDataset.load(root, "dev")
    with pytest.raises(ValueError, match="unknown skeleton 'smpl'"):
        MotionDataset.load(root, skeleton="smpl")
    with pytest.raises(FileNotFoundError, match="dataset folder not found"):
        MotionDataset.load(tmp_path / "nowhere")
    short = write_dataset(tmp_path / "e", {"c": (feats(10), [LINE], None)})
    with pytest.raises(ValueError, match=r"train\.txt: no clip of 1 has 40 <= frames < 200"):
        MotionDataset.load(short)


def test_parse_caption_line():
    c = parse_caption_line(LINE, "f:1")
    assert c.text == "a person walks forward." and c.tokens[:2] == ["a/DET", "person/NOUN"]
    assert (c.start, c.end) == (0.0, 0.0)
    with pytest.raises(ValueError, match="f:2: empty caption"):
        parse_caption_line("#a/DET#0.0#0.0", "f:2")


def test_normalize_round_trip_and_dataset_stats(humanml3d_fixture):
    feats = np.load(humanml3d_fixture / "new_joint_vecs" / "012314.npy")
    mean, std = load_mean_std(humanml3d_fixture, dim=263)
    assert mean.shape == std.shape == (263,) and mean.dtype == np.float32
    z = normalize(feats, mean, std)
    # the clip is one sample of the dataset: its normalised values are of order one, not raw scale
    assert 0.1 < np.abs(z).mean() < 3
    np.testing.assert_allclose(denormalize(z, mean, std), feats, atol=1e-5)
    with pytest.raises(ValueError, match=r"\(263,\)"):
        normalize(feats, mean[:-1], std[:-1])


def test_load_mean_std_names_the_bad_file(tmp_path):
    np.save(tmp_path / "Mean.npy", np.zeros(263, np.float32))
    with pytest.raises(FileNotFoundError, match="Std.npy"):
        load_mean_std(tmp_path)
    np.save(tmp_path / "Std.npy", np.ones(251, np.float32))
    with pytest.raises(ValueError, match=r"Std\.npy: expected shape \(263,\)"):
        load_mean_std(tmp_path, dim=263)
    np.save(tmp_path / "Std.npy", np.zeros(263, np.float32))
    with pytest.raises(ValueError, match="Std.npy.*<= 0"):
        load_mean_std(tmp_path)
