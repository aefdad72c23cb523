"""The quality report: action accuracy of generated motion as the classifier judges it, torch and bundle rows."""
import json
import shutil

import numpy as np
import pytest

from mogo_eval.cli import main
from mogo_eval.features import FeatureGenerator
from mogo_eval.quality import (classify, generation_quality, held_out_cases, held_out_items, load_classifier,
                               train_classifier, vq_reconstruction)
from mogo_export.models.vq import MoSAVQ
from mogo_export.data.dataset import MotionDataset


@pytest.fixture(scope="module")
def data(tiny_checkpoints):
    return tiny_checkpoints.parent / "data"


@pytest.fixture(scope="module")
def classifier(data, tmp_path_factory):
    return train_classifier(data, tmp_path_factory.mktemp("clf"), steps=30, progress=False)


@pytest.fixture(scope="module")
def clips_by_caption(data):
    """De-normalised features (what generators return) of the first held-out clip with each first caption."""
    out = {}
    for split in ("test", "val"):
        for it in MotionDataset.load(data, split).items:
            out.setdefault(it.captions[0], it.features)
    return out


def test_accuracy_is_the_classifier_verdict_on_what_the_generator_returns(data, classifier, clips_by_caption):
    """A generator that returns each caption's own real clip scores what the classifier says of those clips."""
    oracle = FeatureGenerator(lambda texts, seeds, n: [clips_by_caption[t] for t in texts], downsample=4)
    report = generation_quality(oracle, data, classifier, progress=False)

    model, families = load_classifier(classifier)
    cases = held_out_cases(data, families)
    ds = MotionDataset.load(data, "test")
    preds, _ = classify(model, families, [ds.normalize(clips_by_caption[c]) for c, _ in cases])
    expected = np.mean([p == f for p, (_, f) in zip(preds, cases)])
    assert report["cases"] == len(cases) > 0
    assert report["overall_accuracy"] == pytest.approx(expected)
    for fam in {f for _, f in cases}:
        mine = [p == f for p, (_, f) in zip(preds, cases) if f == fam]
        assert report["per_family"][fam] == pytest.approx(np.mean(mine))


def test_the_vq_ceiling_is_the_classifier_verdict_on_the_round_trip(data, classifier, tiny_checkpoints,
                                                                     monkeypatch):
    """A lossless VQ keeps every clip the classifier's: its ceiling is the classifier's accuracy on the real
    whole clips (cut to whole tokens). The tiny VQ loses some, and the report says how many."""
    model, families = load_classifier(classifier)
    whole = [(it, f) for it, f in held_out_items(data, families) if not it.is_span]
    ds = MotionDataset.load(data, "test")
    real = [ds.normalize(it.features)[:len(it.features) // 4 * 4] for it, _ in whole]
    expected = np.mean([p == f for p, (_, f) in zip(classify(model, families, real)[0], whole)])
    tiny = vq_reconstruction(data, tiny_checkpoints / "vq.pt", classifier_path=classifier)
    assert tiny["action_clips"] == len(whole) > 0 and 0.0 <= tiny["action_accuracy"] <= 1.0

    monkeypatch.setattr(MoSAVQ, "encode", lambda self, x: x)
    monkeypatch.setattr(MoSAVQ, "decode_indices", lambda self, x: x)
    lossless = vq_reconstruction(data, tiny_checkpoints / "vq.pt", classifier_path=classifier)
    assert lossless["action_accuracy"] == pytest.approx(expected)
    assert lossless["mpjpe_mm"] == 0.0
    assert "action_accuracy" not in vq_reconstruction(data, tiny_checkpoints / "vq.pt")


def test_a_generator_that_ignores_the_text_scores_only_its_one_family(data, classifier, clips_by_caption):
    model, families = load_classifier(classifier)
    clip = next(iter(clips_by_caption.values()))
    judged = classify(model, families, [MotionDataset.load(data, "test").normalize(clip)])[0][0]
    constant = FeatureGenerator(lambda texts, seeds, n: [clip] * len(texts), downsample=4)
    report = generation_quality(constant, data, classifier, progress=False)

    truth = [f for _, f in held_out_cases(data, families)]
    assert report["overall_accuracy"] == pytest.approx(np.mean([f == judged for f in truth]))
    items = held_out_items(data, families)
    whole = [f == judged for (it, _), f in zip(items, truth) if not it.is_span]
    assert 0 < report["whole_clips"] == len(whole) < len(items)           # the data has timed spans too
    assert report["whole_clip_accuracy"] == pytest.approx(np.mean(whole))
    assert all(acc == (1.0 if fam == judged else 0.0) for fam, acc in report["per_family"].items())
    assert report["diversity"] == pytest.approx(0.0, abs=1e-5)        # one motion, no spread


def test_each_draw_gives_every_caption_its_own_seed(data, classifier, clips_by_caption):
    seen = []

    def generate(texts, seeds, num_tokens):
        assert num_tokens is None                                  # the model chooses each motion's length
        seen.extend(seeds)
        return [clips_by_caption[t] for t in texts]

    report = generation_quality(FeatureGenerator(generate, 4), data, classifier, seeds=3, batch=5, progress=False)
    n = report["cases"]
    assert seen == list(range(n)) + [1000 + i for i in range(n)] + [2000 + i for i in range(n)]
    assert report["seeds"] == 3 and len(report["accuracy_per_seed"]) == 3
    # the oracle is deterministic, so every draw scores alike and the mean is that score
    assert report["accuracy_per_seed"] == [report["overall_accuracy"]] * 3


def test_cli_judges_torch_and_every_bundle_variant_with_the_same_seeds(tiny_checkpoints, tiny_bundle, data,
                                                                       classifier, tmp_path, capsys):
    ckpt = tmp_path / "checkpoints"                 # the report and classifier are written beside the checkpoints
    shutil.copytree(tiny_checkpoints, ckpt)
    shutil.copy(classifier, ckpt / "classifier.pt")
    gif = tmp_path / "families.gif"
    assert main(["quality", "--data", str(data), "--checkpoints", str(ckpt), "--bundle", str(tiny_bundle),
                 "--seeds", "2", "--threads", "1", "--gif", str(gif)]) == 0
    printed = json.loads(capsys.readouterr().out)
    report = json.loads((ckpt / "quality.json").read_text())
    assert printed == report
    assert set(report["bundle"]) == {"path", "fp32", "int8"}
    torch_row, fp32_row = report["generation"], report["bundle"]["fp32"]
    for row in (torch_row, fp32_row, report["bundle"]["int8"]):
        assert row["seeds"] == 2 and len(row["accuracy_per_seed"]) == 2 and row["cases"] == torch_row["cases"]
        assert 0.0 <= row["overall_accuracy"] <= 1.0 and row["diversity"] > 0
    # same captions, seeds and sampling through torch and the fp32 bundle: the same motions, the same verdicts
    assert fp32_row["accuracy_per_seed"] == torch_row["accuracy_per_seed"]
    assert fp32_row["per_family"] == torch_row["per_family"]
    # every row samples as the bundle would for its users, and the report says how
    assert report["sampling"] == json.loads((tiny_bundle / "manifest.json").read_text())["sampling_defaults"]
    assert gif.stat().st_size > 0 and report["gif"] == str(gif)
    assert report["vq_test"]["mpjpe_mm"] > 0 and 0.0 <= report["vq_test"]["action_accuracy"] <= 1.0


def test_cli_refuses_bad_arguments_before_any_work(tiny_checkpoints, data, tmp_path, capsys):
    ckpt = tmp_path / "checkpoints"
    shutil.copytree(tiny_checkpoints, ckpt)
    assert main(["quality", "--data", str(data), "--checkpoints", str(ckpt), "--seeds", "0"]) == 2
    assert "seeds must be 1 or more" in capsys.readouterr().err
    missing = tmp_path / "no-bundle"
    assert main(["quality", "--data", str(data), "--checkpoints", str(ckpt), "--bundle", str(missing)]) == 2
    assert f"{missing}: bundle folder not found" in capsys.readouterr().err
    assert not (ckpt / "classifier.pt").exists() and not (ckpt / "quality.json").exists()
