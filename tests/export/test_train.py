"""Training runs, lowers the loss, checkpoints atomically, resumes exactly; the verifier passes on a tiny bundle."""
import dataclasses

import numpy as np
import pytest
import torch

import mogo_export.examples as examples
import mogo_export.train as train
from mogo_export.checkpoint import CheckpointError, build_from_checkpoint, read_checkpoint, save_checkpoint
from mogo_export.data.dataset import MotionDataset, read_control_only
from mogo_export.models.transformer import RQHCTransformer, TransformerConfig
from mogo_export.models import vq as V
from mogo_export.presets import get_preset
from mogo_export.verify import verify

SHORT = train.Schedule(steps=24, batch_size=8, lr=1e-3, warmup=2, val_every=12, ckpt_every=8, window=16)


@pytest.fixture(scope="module")
def data(tiny_checkpoints):
    return tiny_checkpoints.parent / "data"


def test_vq_training_lowers_reconstruction_error(data, tmp_path):
    ds = MotionDataset.load(data, "val")
    clips = [ds.normalize(it.features) for it in ds.items]
    torch.manual_seed(0)
    before = train.evaluate_vq(V.MoSAVQ(get_preset("tiny").vq_config()), clips, ds.mean, ds.std)
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
    cfg = get_preset("tiny").vq_config()
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
    # the portable variant and the ORT-format variants are checked like the others
    assert any(n.startswith("portable step graph") for n in names) and any("torch vs ORT portable" in n for n in names)
    assert any("int8_ort vs int8" in n for n in names) and any("portable_ort vs portable" in n for n in names)
    assert any(n.startswith("compact vs fp32 argmax") for n in names) and any("compact greedy tokens" in n for n in names)


def test_teacher_forced_agreement_counts_argmax_changes(tiny_bundle):
    from mogo_runtime.bundle.folder import Bundle
    from mogo_runtime.engine import OrtBackend
    from mogo_export.verify import PROMPTS, _ort_tokens, _teacher_forced

    fp32 = OrtBackend(Bundle.load(tiny_bundle), "fp32", threads=1)
    prompts = list(PROMPTS[:3])
    seqs = _ort_tokens(fp32, prompts, [0, 1, 2], 12)
    assert _teacher_forced(fp32, fp32, prompts, seqs) == (1.0, 0.0)

    class Flipped:  # the same backend with level 0's logits negated: its argmax almost never agrees
        dims = fp32.dims

        def __getattr__(self, name):
            return getattr(fp32, name)

        def step(self, emb, tokens, past, control=None):
            logits, past = fp32.step(emb, tokens, past, control)
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


# -----------------------------------------------------------------------------
# presets, the trained-folder loader, atomic checkpoints

def test_presets_are_one_consistent_frozen_table():
    import dataclasses
    import subprocess
    import sys

    from mogo_export.presets import CPU_NAMES, DEFAULT, NAMES, PRESETS

    assert NAMES == ("tiny", "base", "paper") and DEFAULT in NAMES and CPU_NAMES == ("tiny", "base")
    for name, p in PRESETS.items():
        assert p.name == name
        v, t = p.vq_config(), p.transformer_config()
        assert (v.num_levels, v.codebook_size) == (t.num_levels, t.codebook_size)
        with pytest.raises(dataclasses.FrozenInstanceError):
            p.text_encoder = "x"
        with pytest.raises(TypeError):
            p.vq["width"] = 1        # the table cannot be changed through a preset handed out
    base = get_preset("base")
    cfg = base.vq_config(input_dim=251)
    assert cfg.input_dim == 251 and base.vq_config().input_dim == 263 and cfg.width == base.vq["width"]
    assert base.vq_config() is not base.vq_config()
    # the demo lists and checks names without torch, so a run that only generates never loads it
    code = "import sys, mogo_export.presets; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)
    # the values the README measures (a first make demo about 50 min on 2 cores; whole clips 0.893 to 0.905)
    assert (base.vq_schedule.steps, base.vq_schedule.lr, base.vq["mse_loss"], base.vq["root_loss"]) == \
        (6000, 2e-3, 0.1, 5.0)
    tsched = base.transformer_schedule
    assert (tsched.steps, tsched.lr, base.transformer["dropout"]) == (2600, 1e-3, 0.0)
    assert get_preset("tiny").text_encoder == "tiny-random-bert" and base.text_encoder == "all-MiniLM-L6-v2"
    with pytest.raises(ValueError, match="unknown preset 'huge'; the presets are tiny, base, paper"):
        get_preset("huge")


def test_load_trained_reads_what_training_writes(tiny_checkpoints):
    from mogo_export.checkpoint import load_trained

    m = load_trained(tiny_checkpoints)
    assert m.preset == "tiny" and m.text_encoder_name == get_preset("tiny").text_encoder
    assert m.fps == 20.0 and m.skeleton == "humanml3d" and isinstance(m.max_tokens, int) and m.max_tokens > 1
    assert m.mean.shape == m.std.shape == (m.vq_config.input_dim,) and m.mean.dtype == np.float32
    assert m.vq_step == get_preset("tiny").vq_schedule.steps
    assert m.transformer_step == get_preset("tiny").transformer_schedule.steps
    assert m.transformer_config.num_levels == m.vq_config.num_levels and not m.vq.training
    assert m.dataset is not None and "optimizer" not in m.vq_payload["train"] and "model" not in m.vq_payload
    assert m.transformer_payload["meta"]["val"]["acc"] > 0


def _copy_with(src, dst, file, edit):
    import shutil

    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("*.npz"))
    payload = torch.load(dst / file, weights_only=True)
    edit(payload)
    torch.save(payload, dst / file)
    return dst


@pytest.mark.parametrize("file,edit,message", [
    ("vq.pt", lambda p: p["meta"].pop("fps"),
     r"vq\.pt: meta field 'fps' is missing \(mogo_export\.train writes it"),
    ("transformer.pt", lambda p: p["meta"].pop("text_encoder"),
     r"transformer\.pt: meta field 'text_encoder' is missing"),
    ("transformer.pt", lambda p: p["meta"].update(max_tokens="50"),
     r"transformer\.pt: meta field 'max_tokens' must be int, got str '50'"),
    ("vq.pt", lambda p: p["meta"].update(skeleton=None), r"vq\.pt: meta field 'skeleton' must be str, got NoneType"),
    ("vq.pt", lambda p: p["meta"].update(mean=p["meta"]["mean"][:-1]),
     r"vq\.pt: meta field 'mean' has shape \(262,\), the VQ's input_dim is 263"),
    ("vq.pt", lambda p: p["meta"].update(dataset=3), r"vq\.pt: meta field 'dataset' must be str, got int"),
    ("vq.pt", lambda p: p["train"].pop("step"), r"vq\.pt: train field 'step' is missing"),
])
def test_load_trained_names_the_file_and_the_field(tiny_checkpoints, tmp_path, file, edit, message):
    from mogo_export.checkpoint import load_trained

    folder = _copy_with(tiny_checkpoints, tmp_path / "ck", file, edit)
    with pytest.raises(CheckpointError, match=message):
        load_trained(folder)


def test_load_trained_needs_both_files(tmp_path, tiny_checkpoints):
    import shutil

    from mogo_export.checkpoint import load_trained

    with pytest.raises(CheckpointError, match="checkpoint folder not found"):
        load_trained(tmp_path / "nothing")
    (tmp_path / "ck").mkdir()
    shutil.copy(tiny_checkpoints / "vq.pt", tmp_path / "ck")
    with pytest.raises(CheckpointError, match=r"transformer\.pt: checkpoint not found"):
        load_trained(tmp_path / "ck")


def test_a_failed_checkpoint_write_keeps_the_previous_file(tmp_path, monkeypatch):
    cfg = get_preset("tiny").vq_config()
    path = save_checkpoint(tmp_path / "vq.pt", "vq", cfg, V.MoSAVQ(cfg), {"step": 1})
    before = path.read_bytes()
    assert path.stat().st_mode & 0o777 != 0o600      # an ordinary file, not mkstemp's private one

    def torch_save_then_crash(obj, f):
        f.write(b"half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", torch_save_then_crash)
    with pytest.raises(OSError, match="disk full"):
        save_checkpoint(path, "vq", cfg, V.MoSAVQ(cfg), {"step": 2})
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["vq.pt"]


def test_streaming_windows_stay_inside_one_timed_segment():
    from mogo_export.presets import Streaming

    cfg = get_preset("tiny").transformer_config()
    L, streaming = cfg.num_levels, Streaming(window=5, refresh=3, windows=4)
    # one 30-token sequence in three timed segments; token t's codes are t, so a window says where it came from
    seq = np.arange(30)[:, None].repeat(L, axis=1)
    segments = [(0, 10, ["a"]), (10, 20, ["b"]), (20, 30, ["c"])]
    emb = {c: np.full(4, i, np.float32) for i, c in enumerate("abc")}
    # the control of token t reads t in every field, so a window's controls say which tokens they belong to
    controls = np.arange(31, dtype=np.float32)[:, None].repeat(cfg.control_dim, axis=1)
    windows = examples.window_examples([(seq, segments)], emb, np.random.default_rng(0), 400, cfg, streaming,
                                     [controls])
    for text, tin, tgt, control in windows:
        segment = int(text[0])
        assert (tin[0] == cfg.bos_id).all() and len(tin) == len(tgt) and 1 <= len(tgt) <= 8
        assert (tgt[:, 0] // 10 == segment).all()                          # the prompt's own segment only
        assert np.array_equal(tin[1:], tgt[:-1])                            # inputs are the targets shifted by one
        assert np.array_equal(control[:, 0], tgt[:, 0])                     # each step reads its target's control
    assert {len(t) for _, _, t, _ in windows} == set(range(1, 9))           # every context length is trained
    first = [int(t[0, 0]) % 10 for _, _, t, _ in windows]
    assert first.count(0) > 20 and sum(f > 0 for f in first) > 200          # at segment starts and mid-action
    # only window + refresh is trained: the runtime's split of it (when a context is rebuilt, from how many tokens)
    # can change without training again (presets.BASE)
    split = examples.window_examples([(seq, segments)], emb, np.random.default_rng(0), 400, cfg,
                                     Streaming(window=3, refresh=5, windows=4), [controls])
    assert all(np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2]) for a, b in zip(windows, split))


def test_a_bf16_schedule_trains_in_bf16_only_where_the_cpu_computes_it(tiny_checkpoints, tmp_path, one_torch_thread):
    """Schedule(bf16=True): the transformer's forward passes run under bf16 autocast where the device computes bf16
    natively (the checkpoint says which ran), and give other weights than float32 from the same seed."""
    import shutil

    from mogo_export.distributed import native_bf16

    data = tiny_checkpoints.parent / "data"
    weights = {}
    for bf16 in (False, True):
        out = tmp_path / str(bf16)
        out.mkdir()
        for name in ("vq.pt", "tokens.npz", "captions.npz"):
            shutil.copy(tiny_checkpoints / name, out / name)
        schedule = train.Schedule(steps=6, batch_size=4, lr=1e-3, warmup=2, val_every=6, ckpt_every=6, bf16=bf16)
        payload = read_checkpoint(train.train_transformer(data, out, "tiny", progress=False, schedule=schedule),
                                  "transformer")
        native = bf16 and native_bf16(torch.device("cpu"))
        assert payload["meta"]["train_precision"] == ("bf16" if native else "fp32")
        assert all(torch.isfinite(w).all() for w in payload["model"].values())
        weights[bf16] = payload["model"]
    same = all(torch.equal(weights[False][k], weights[True][k]) for k in weights[False])
    assert same != native_bf16(torch.device("cpu"))


# -----------------------------------------------------------------------------
# the control adapter (adapter.py)

def test_the_control_sequences_train_only_the_adapter(tiny_checkpoints, data):
    """load_token_data leaves the dataset's control sequences out unless asked (the adapter's data), before anything
    is drawn from it: the transformer and its distillation train on the data as it was without them."""
    _, cfg, payload = build_from_checkpoint(tiny_checkpoints / "transformer.pt", "transformer", TransformerConfig,
                                            RQHCTransformer)
    table, emb, _ = examples.caption_table(data, tiny_checkpoints, payload["meta"]["text_encoder"], write=False)
    control_only = read_control_only(data)
    assert len(control_only) == 6  # 60 clips: one control sequence per 10, the last ids
    with np.load(tiny_checkpoints / "tokens.npz") as z:
        keys = [k for k in z.files if k.startswith("train/")]
    n_control = sum(k.split("/")[1].split(":")[0] in control_only for k in keys)
    assert n_control > 0
    plain = examples.load_token_data(data, tiny_checkpoints / "tokens.npz", table, emb, cfg, 2)
    every = examples.load_token_data(data, tiny_checkpoints / "tokens.npz", table, emb, cfg, 2,
                                     control_sequences=True)
    assert len(plain.seqs) == len(keys) - n_control and len(every.seqs) == len(keys)
    assert len(plain.timelines) < len(every.timelines)
    for a, b in ((plain.seqs, every.seqs), (plain.caps, every.caps), (plain.controls, every.controls),
                 ([t[0] for t in plain.timelines], [t[0] for t in every.timelines])):
        assert all(np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y for x, y in zip(a, b))


def test_the_control_adapter_trains_itself_only_and_again_the_same(tiny_checkpoints, data, tmp_path,
                                                                    one_torch_thread):
    """The tiny training's adapter, trained again from the distilled model it started from, is the same weights
    (to float rounding: the tiny bundle trained with other threads); nothing but the adapters changed, and without
    control the model gives the distilled model's logits exactly."""
    import shutil

    from mogo_export.adapter import train_adapter

    trained, cfg, payload = build_from_checkpoint(tiny_checkpoints / "transformer.pt", "transformer",
                                                  TransformerConfig, RQHCTransformer)
    assert cfg.adapter_dim == 8 and payload["meta"]["adapter"]["steps"] == 10
    out = tmp_path / "ck"
    shutil.copytree(tiny_checkpoints, out)
    base = RQHCTransformer(dataclasses.replace(cfg, adapter_dim=0))
    base.load_state_dict({k: v for k, v in trained.state_dict().items() if not k.startswith("adapters.")})
    base.eval()
    meta = {k: v for k, v in payload["meta"].items() if k != "adapter"}
    save_checkpoint(out / "transformer.pt", "transformer", base.cfg, base, payload["train"], meta)
    train_adapter(data, out, "tiny", progress=False)
    again = build_from_checkpoint(out / "transformer.pt", "transformer", TransformerConfig, RQHCTransformer)[0]
    for (name, a), b in zip(trained.state_dict().items(), again.state_dict().values()):
        assert torch.equal(a, b) if not name.startswith("adapters.") else torch.allclose(a, b, atol=1e-5), name
    assert all(torch.count_nonzero(a.up.weight) > 0 for a in again.adapters)
    g = torch.Generator().manual_seed(0)
    text = torch.randn(2, cfg.text_dim, generator=g)
    tok = torch.randint(0, cfg.codebook_size, (2, 5, cfg.num_levels), generator=g)
    tok[:, 0] = cfg.bos_id
    control = torch.randn(2, 5, cfg.control_dim, generator=g)
    control[..., 0] = 1.0
    control[1] = 0.0
    with torch.no_grad():
        got, want = again(text, tok, control), base(text, tok, control)
    assert torch.equal(got[1], want[1]) and (got[0] - want[0]).abs().amax() > 0
    assert train_adapter(data, out, "tiny", progress=False) == out / "transformer.pt"  # done: skipped
