"""Guo et al.'s text-to-motion metrics: the formulas on synthetic embeddings, the evaluators, the CLI end to end."""
import json
import math
import pickle
import shutil

import numpy as np
import pytest
import torch

from mogo_eval import protocol as E
from mogo_runtime.bundle import Bundle
from mogo_eval.cli import main
from mogo_eval.judges import evaluator as M

D = 16


@pytest.fixture(scope="module", autouse=True)
def one_torch_thread():
    """These tests are small: one thread is as fast, and on a busy 2-core machine far faster than two."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


class LookupEvaluator(M.Evaluator):
    """A perfect evaluator: a caption's embedding is a fixed vector, a motion's is its first frame."""
    name, dim, unit_length, max_frames = "lookup", D, 1, 10 ** 6

    def __init__(self, table):
        self.table = table

    def embed_texts(self, texts, tokens=None):
        return np.stack([self.table[t] for t in texts])

    def embed_motions(self, features, batch_size=64):
        return np.stack([f[0, :D] for f in features])


@pytest.fixture(scope="module")
def synthetic():
    rng = np.random.default_rng(0)
    table = {f"caption {i}": rng.normal(size=D) for i in range(96)}
    cases = [E.EvalCase(f"c{i}", np.tile(v, (12, 1)).astype(np.float32), [t], [[]])
             for i, (t, v) in enumerate(table.items())]
    return LookupEvaluator(table), cases


def test_r_precision_is_one_for_a_perfect_evaluator_and_chance_for_random_motion(synthetic):
    evaluator, cases = synthetic
    noise = np.random.default_rng(1)
    random_motion = E.MotionSource("random", lambda texts, real, seeds: [
        np.tile(noise.normal(size=D), (12, 1)) for _ in texts])
    cfg = E.ProtocolConfig(repeats=20, mm_captions=0)
    res = E.run_protocol(cases, evaluator, [E.real_source(), random_motion], cfg, progress=False)
    real, rand = res["rows"]["Real motion"], res["rows"]["random"]
    assert res["info"]["batch_size"] == 32 and res["info"]["r_precision_items"] == 96
    assert real["top1"]["mean"] == real["top3"]["mean"] == 1.0 and real["top1"]["conf"] == 0.0
    assert real["mm_dist"]["mean"] < 1e-6 and abs(real["fid"]["mean"]) < 1e-6
    assert 0.015 < rand["top1"]["mean"] < 0.05            # 1/32 = 0.031
    assert 0.06 < rand["top3"]["mean"] < 0.13             # 3/32 = 0.094
    assert rand["fid"]["mean"] > 1 and rand["multimodality"] is None
    assert len(rand["top1"]["values"]) == 20


def test_multimodality_is_zero_for_a_deterministic_generator_and_positive_for_a_random_one(synthetic):
    evaluator, cases = synthetic
    fixed = E.MotionSource("fixed", lambda texts, real, seeds: list(real), stochastic=True)
    noisy = E.MotionSource("noisy", lambda texts, real, seeds: [
        r + np.random.default_rng(s).normal(size=r.shape[1]) for r, s in zip(real, seeds)], stochastic=True)
    cfg = E.ProtocolConfig(repeats=2, mm_captions=8, mm_generations=5, mm_pairs=5)
    rows = E.run_protocol(cases, evaluator, [fixed, noisy], cfg, progress=False)["rows"]
    assert rows["fixed"]["multimodality"]["mean"] == 0.0
    # two independent N(0, I) perturbations in 16 dims: distance ~ sqrt(2 * 16); a pair may repeat a generation
    assert 3.0 < rows["noisy"]["multimodality"]["mean"] < 6.0


def test_r_precision_counts_ranks_within_the_batch():
    t = np.eye(4)
    m = np.eye(4)[[1, 0, 2, 3]]                 # captions 0 and 1 see each other's motion first
    hits, match = E.r_precision(t, m, top_k=3)
    assert hits.tolist() == [2, 4, 4] and math.isclose(match, 2 * math.sqrt(2))


def test_fid_zero_for_a_set_with_itself_and_closed_form_for_gaussians():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 8))
    assert abs(E.fid(x, x)) < 1e-8
    shift = np.arange(8) / 4
    assert math.isclose(E.fid(x, x + shift), float(shift @ shift), rel_tol=1e-8)   # same covariance
    # N(mu1, diag(s1^2)) vs N(mu2, diag(s2^2)): |mu1 - mu2|^2 + sum (s1 - s2)^2
    mu1, mu2, s1, s2 = np.zeros(4), np.array([1.0, 0, -2, 0.5]), np.array([1.0, 2, 0.5, 1]), np.array([2.0, 1, 0.5, 3])
    a = mu1 + s1 * rng.normal(size=(200_000, 4))
    b = mu2 + s2 * rng.normal(size=(200_000, 4))
    exact = float((mu1 - mu2) @ (mu1 - mu2) + ((s1 - s2) ** 2).sum())
    assert abs(E.fid(a, b) - exact) < 0.03 * exact
    # full, non-commuting covariances: against tr((S1 S2)^1/2) from the eigenvalues of the product itself
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    S1, S2 = A @ A.T + 0.1 * np.eye(6), B @ B.T + 0.1 * np.eye(6)
    tr_sqrt = np.sqrt(np.linalg.eigvals(S1 @ S2).real).sum()
    assert math.isclose(E.frechet_distance(np.zeros(6), S1, np.ones(6), S2),
                        6 + np.trace(S1) + np.trace(S2) - 2 * tr_sqrt, rel_tol=1e-8)
    # fewer samples than dimensions (singular covariances): the sample-space route agrees with the D x D one
    few, other = rng.normal(size=(20, 64)), 0.5 + 2 * rng.normal(size=(30, 64))
    assert abs(E.fid(few, few)) < 1e-9
    stats = E.activation_statistics
    assert math.isclose(E.fid(few, other), E.frechet_distance(*stats(few), *stats(other)), rel_tol=1e-6)


def test_confidence_interval_and_diversity():
    mean, conf = E.mean_confidence([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5 and math.isclose(conf, 1.96 * np.std([1, 2, 3, 4]) / 2)
    emb = np.random.default_rng(0).normal(size=(1000, 32))
    value, pairs = E.diversity(emb, 300, np.random.default_rng(0))
    assert pairs == 300 and abs(value - 8.0) < 0.4               # E|x - y| ~ sqrt(2 * 32) = 8
    assert E.diversity(emb[:50], 300, np.random.default_rng(0))[1] == 50


def test_guo_crop_keeps_whole_units():
    rng = np.random.default_rng(0)
    x = np.arange(103)[:, None].astype(np.float32)
    lengths = {len(E.guo_crop(x, rng, 4)) for _ in range(200)}
    assert lengths == {100, 96}


def test_contrastive_evaluator_trains_and_round_trips(tiny_checkpoints, tmp_path):
    data = tiny_checkpoints.parent / "data"
    cfg = M.EvaluatorConfig(motion_width=32, hidden=64, embed_dim=32)
    sched = E.EvaluatorSchedule(steps=40, batch_size=16, lr=3e-3, warmup=5)
    path = E.train_evaluator(data, tmp_path / "ev.pt", sched, cfg=cfg, progress=False)
    payload = torch.load(path, weights_only=True)
    assert payload["meta"]["loss_last"] < 0.7 * payload["meta"]["loss_first"]
    ev = E.load_evaluator(path)
    cases = E.load_cases(data, "val")
    feats = [c.features for c in cases]
    batched = ev.embed_motions(feats)
    alone = np.concatenate([ev.embed_motions([f]) for f in feats])
    assert batched.shape == (len(cases), 32) and np.allclose(batched, alone, atol=1e-5)
    assert np.allclose(np.linalg.norm(batched, axis=1), 1, atol=1e-5)
    texts = [c.captions[0] for c in cases]
    assert ev.embed_texts(texts).shape == (len(cases), 32)
    assert ev.embed_motions([feats[0][:1]]).shape == (1, 32)     # shorter than one unit: padded, not an error


def _fake_guo_files(root, dim_pose=263):
    """Guo et al.'s file layout with random weights of the right shapes (the real ones cannot be fetched here)."""
    movement, motion, text = M.T2MEvaluator.build(dim_pose=dim_pose)
    ckpt = root / "t2m" / "text_mot_match" / "model"
    ckpt.mkdir(parents=True)
    torch.save({"movement_encoder": movement.state_dict(), "motion_encoder": motion.state_dict(),
                "text_encoder": text.state_dict(), "epoch": 1}, ckpt / "finest.tar")
    glove = root / "glove"
    glove.mkdir()
    words = ["unk", "sos", "eos", "a", "person", "walk", "forward", "jump"]
    np.save(glove / "our_vab_data.npy", np.random.default_rng(0).normal(size=(len(words), 300)).astype(np.float32))
    (glove / "our_vab_words.pkl").write_bytes(pickle.dumps(words))
    (glove / "our_vab_idx.pkl").write_bytes(pickle.dumps({w: i for i, w in enumerate(words)}))
    meta = root / "meta"
    meta.mkdir()
    np.save(meta / "mean.npy", np.zeros(dim_pose, np.float32))
    np.save(meta / "std.npy", np.ones(dim_pose, np.float32))
    return root / "t2m", glove, meta


def test_t2m_evaluator_has_the_original_checkpoint_layout_and_loads_it(tmp_path):
    movement, motion, text = M.T2MEvaluator.build()
    gru = [f"gru.{k}_l0{r}" for r in ("", "_reverse") for k in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")]
    head = [f"output_net.{i}.{p}" for i in (0, 1, 3) for p in ("weight", "bias")]
    assert set(movement.state_dict()) == {"main.0.weight", "main.0.bias", "main.3.weight", "main.3.bias",
                                          "out_net.weight", "out_net.bias"}
    assert set(motion.state_dict()) == {"hidden", "input_emb.weight", "input_emb.bias", *gru, *head}
    assert set(text.state_dict()) == {"hidden", "pos_emb.weight", "pos_emb.bias", "input_emb.weight",
                                      "input_emb.bias", *gru, *head}
    assert movement.state_dict()["main.0.weight"].shape == (512, 259, 4)
    assert motion.state_dict()["gru.weight_ih_l0"].shape == (3 * 1024, 1024)
    assert text.state_dict()["pos_emb.weight"].shape == (300, 15)

    ckpt, glove, meta = _fake_guo_files(tmp_path)
    ev = E.load_evaluator(ckpt, glove=glove, t2m_meta=meta)
    assert isinstance(ev, M.T2MEvaluator)
    word, pos = ev.words["walk/VERB"]
    assert pos.argmax() == M.POS_ENUMERATOR["Act_VIP"]
    assert ev.words["zebra/NOUN"][1].argmax() == M.POS_ENUMERATOR["OTHER"]
    rng = np.random.default_rng(0)
    motions = [rng.normal(size=(n, 263)).astype(np.float32) for n in (40, 77, 196, 230)]
    emb = ev.embed_motions(motions)
    assert emb.shape == (4, 512) and np.allclose(emb[1], ev.embed_motions([motions[1]])[0], atol=1e-5)
    t = ev.embed_texts(["a person walks forward", "a person jumps"],
                       [["a/DET", "person/NOUN", "walk/VERB", "forward/ADV"], ["a/DET", "person/NOUN", "jump/VERB"]])
    assert t.shape == (2, 512) and np.isfinite(t).all()
    with pytest.raises(ValueError, match="tokens"):
        ev.embed_texts(["a person walks"])


def test_cli_trains_an_evaluator(tiny_checkpoints, tmp_path):
    data = tiny_checkpoints.parent / "data"
    assert main(["train-evaluator", "--data", str(data), "--out", str(tmp_path / "ev.pt"), "--steps", "5",
                 "--text-encoder", "tiny-random-bert"]) == 0
    payload = torch.load(tmp_path / "ev.pt", weights_only=True)
    assert payload["kind"] == "evaluator" and payload["train"]["step"] == 5
    assert payload["config"]["text_encoder"] == "tiny-random-bert" and len(payload["meta"]["mean"]) == 263
    assert set(payload["meta"]["val_real"]) >= {"top1", "top2", "top3", "mm_dist"}


@pytest.fixture(scope="module")
def small_evaluator(tiny_checkpoints, tmp_path_factory):
    cfg = M.EvaluatorConfig(motion_width=32, hidden=64, text_encoder="tiny-random-bert")
    return E.train_evaluator(tiny_checkpoints.parent / "data", tmp_path_factory.mktemp("ev") / "ev.pt",
                             E.EvaluatorSchedule(steps=5, batch_size=16), cfg=cfg, progress=False)


def test_cli_evaluates_the_tiny_bundle_and_writes_every_field(tiny_checkpoints, tiny_bundle, small_evaluator,
                                                              tmp_path, capsys):
    data = tiny_checkpoints.parent / "data"
    out = tmp_path / "eval.json"
    assert main(["evaluate", "--data", str(data), "--checkpoints", str(tiny_checkpoints), "--bundle",
                 str(tiny_bundle), "--evaluator", str(small_evaluator), "--repeats", "2", "--split", "val",
                 "--length", "gt", "--mm-captions", "2", "--mm-generations", "3", "--threads", "1", "--tca",
                 "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Top 1" in printed and "MultiModality" in printed and "MOGO bundle int8" in printed
    report = json.loads(out.read_text())
    rows = report["table2"]
    assert list(rows) == ["Real motion", "VQ reconstruction", "MOGO (torch)", "MOGO bundle fp32",
                          "MOGO bundle fp32 + TCA", "MOGO bundle int8", "MOGO bundle int8 + TCA"]
    for name, row in rows.items():
        assert set(row) == set(E.METRICS)
        for metric, cell in row.items():
            if metric == "multimodality" and name in ("Real motion", "VQ reconstruction"):
                assert cell is None
                continue
            assert len(cell["values"]) == 2 and np.isfinite([cell["mean"], cell["conf"]]).all()
            assert math.isclose(cell["conf"], E.mean_confidence(cell["values"])[1], abs_tol=1e-12)
    # the same seeds through torch and the fp32 bundle: the same motions, but for a sampled draw that lands within
    # their logits' float difference (~5e-7) of a CDF boundary and parts one motion (on the tiny model of data
    # version 4 one did: FIDs 0.1595 and 0.1588)
    assert math.isclose(rows["MOGO (torch)"]["fid"]["mean"], rows["MOGO bundle fp32"]["fid"]["mean"], rel_tol=1e-2)
    assert report["table3"] is None
    p = report["protocol"]
    assert p["repeats"] == 2 and p["items"] >= 2 and p["length"] == "gt"
    assert p["sampling"] == Bundle.load(tiny_bundle).manifest.sampling_defaults.to_dict()   # what the bundle ships
    assert report["evaluator"]["dim"] == 512 and report["evaluator"]["train"]["step"] == 5


def test_cli_prints_the_learnable_scaling_ablation(tiny_checkpoints, small_evaluator, tmp_path, capsys):
    for name in ("scaling", "no-scaling"):
        (tmp_path / name).mkdir()
        shutil.copy(tiny_checkpoints / "vq.pt", tmp_path / name / "vq.pt")
    out = tmp_path / "ablation.json"
    assert main(["evaluate", "--data", str(tiny_checkpoints.parent / "data"), "--evaluator", str(small_evaluator),
                 "--repeats", "2", "--split", "val", "--json", str(out), "--vq-ablation",
                 str(tmp_path / "scaling" / "vq.pt"), str(tmp_path / "no-scaling" / "vq.pt")]) == 0
    assert "Learnable-scaling ablation" in capsys.readouterr().out
    report = json.loads(out.read_text())
    assert list(report["table2"]) == ["Real motion"]
    assert len(report["table3"]) == 2 and len(report["protocol"]["vq_ablation"]) == 2
    for row in report["table3"].values():
        assert all(np.isfinite(row[m]["mean"]) for m in ("fid", "top1", "mm_dist"))
