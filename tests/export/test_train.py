"""Training runs, lowers the loss, checkpoints atomically, resumes exactly; the verifier passes on a tiny bundle."""
import numpy as np
import pytest
import torch

import mogo_export.train as train
from mogo_export.checkpoint import CheckpointError, build_from_checkpoint, read_checkpoint, save_checkpoint
from mogo_export.data.dataset import MotionDataset
from mogo_export.models import vq as V
from mogo_export.verify import verify

SHORT = train.Schedule(steps=24, batch_size=8, lr=1e-3, warmup=2, val_every=12, ckpt_every=8, window=16)


@pytest.fixture(scope="module")
def data(tiny_checkpoints):
    return tiny_checkpoints.parent / "data"


def test_vq_training_lowers_reconstruction_error(data, tmp_path):
    ds = MotionDataset.load(data, "val")
    clips = [ds.normalize(it.features) for it in ds.items]
    torch.manual_seed(0)
    before = train.evaluate_vq(V.MoSAVQ(V.preset("tiny")), clips, ds.mean, ds.std)
    path = train.train_vq(data, tmp_path, "tiny", progress=False, schedule=SHORT)
    vq, _, payload = build_from_checkpoint(path, "vq", V.VQConfig, V.MoSAVQ)
    after = train.evaluate_vq(vq, clips, ds.mean, ds.std)
    print(f"tiny VQ on val: L1 {before['l1']:.3f} -> {after['l1']:.3f}, MPJPE {before['mpjpe_mm']:.0f} -> "
          f"{after['mpjpe_mm']:.0f} mm")
    assert after["l1"] < before["l1"]
    assert payload["train"]["done"] and payload["train"]["step"] == SHORT.steps


def test_interrupted_training_resumes_to_the_same_weights(data, tmp_path, monkeypatch):
    full = train.train_vq(data, tmp_path / "full", "tiny", progress=False, schedule=SHORT)
    real_crops, calls = train._crops, {"n": 0}

    def crash_at_step_19(*a, **k):
        calls["n"] += 1
        if calls["n"] == 19:
            raise KeyboardInterrupt("power cut")
        return real_crops(*a, **k)

    monkeypatch.setattr(train, "_crops", crash_at_step_19)
    with pytest.raises(KeyboardInterrupt):
        train.train_vq(data, tmp_path / "cut", "tiny", progress=False, schedule=SHORT)
    assert read_checkpoint(tmp_path / "cut" / "vq.pt", "vq")["train"]["step"] == 16   # last checkpoint kept
    monkeypatch.setattr(train, "_crops", real_crops)
    resumed = train.train_vq(data, tmp_path / "cut", "tiny", progress=False, schedule=SHORT)
    a, b = read_checkpoint(full, "vq")["model"], read_checkpoint(resumed, "vq")["model"]
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_checkpoint_loading_says_what_is_wrong(tmp_path):
    cfg = V.preset("tiny")
    path = save_checkpoint(tmp_path / "vq.pt", "vq", cfg, V.MoSAVQ(cfg), {"step": 1})
    build_from_checkpoint(path, "vq", V.VQConfig, V.MoSAVQ)
    with pytest.raises(CheckpointError, match="holds a 'vq' model, expected 'transformer'"):
        read_checkpoint(path, "transformer")
    payload = torch.load(path, weights_only=True)
    payload["config"]["codebook_size"] = 64
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError, match="has shape"):
        build_from_checkpoint(tmp_path / "bad.pt", "vq", V.VQConfig, V.MoSAVQ)
    (tmp_path / "cut.pt").write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        read_checkpoint(tmp_path / "cut.pt", "vq")
    with pytest.raises(CheckpointError, match="not found"):
        read_checkpoint(tmp_path / "missing.pt", "vq")


def test_verifier_passes_on_the_tiny_bundle(tiny_bundle, tiny_checkpoints):
    report = verify(tiny_bundle, tiny_checkpoints)
    print("\n" + report.table())
    assert report.ok
    names = [r[0] for r in report.rows]
    assert any("past=13" in n for n in names)  # beyond the tiny model's clip distance (8)


def test_teacher_forced_agreement_counts_argmax_changes(tiny_bundle):
    from mogo_runtime.bundle import Bundle
    from mogo_runtime.generator import OrtBackend
    from mogo_export.verify import PROMPTS, _ort_tokens, _teacher_forced

    fp32 = OrtBackend(Bundle.load(tiny_bundle), "fp32", threads=1)
    prompts = list(PROMPTS[:3])
    seqs = _ort_tokens(fp32, prompts, [0, 1, 2], 12)
    assert _teacher_forced(fp32, fp32, prompts, seqs) == (1.0, 0.0)

    class Flipped:  # the same backend with level 0's logits negated: its argmax almost never agrees
        dims = fp32.dims

        def __getattr__(self, name):
            return getattr(fp32, name)

        def step(self, emb, tokens, past):
            logits, past = fp32.step(emb, tokens, past)
            logits = logits.copy()
            logits[..., 0, :] *= -1
            return logits, past

    agree, err = _teacher_forced(fp32, Flipped(), prompts, seqs)
    L = fp32.dims.num_levels
    assert (L - 1) / L - 0.05 <= agree < 1.0 - 0.5 / L and err > 0


def test_transformer_trained_on_tokens_predicts_better_than_chance(tiny_checkpoints):
    payload = read_checkpoint(tiny_checkpoints / "transformer.pt", "transformer")
    K = payload["config"]["codebook_size"]
    assert payload["meta"]["val"]["acc"] > 2.0 / (K + 1)
    assert np.isfinite(payload["meta"]["val"]["loss"])
