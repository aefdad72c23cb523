"""Export: each ONNX graph computes what its torch module computes, and the bundle describes itself."""
import json
import os
import shutil

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from random_tiny import random_tiny_bundle

from mogo_export.export.bundle import export_bundle
from mogo_export.export.graphs import DecoderGraph, StepGraph
from mogo_runtime.bundle.folder import Bundle
from mogo_runtime.bundle.sections import BundleError

FP32_BAR = 1e-4


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """Random tiny models and their bundle, exported once for the test process (random_tiny.py)."""
    return random_tiny_bundle(tmp_path_factory)


def session(path):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


@pytest.mark.parametrize("batch,steps,past", [(1, 1, 0), (1, 1, 1), (3, 1, 5), (2, 4, 0), (2, 3, 13), (1, 1, 20)])
def test_step_graph_matches_torch(tiny, batch, steps, past):
    tr = tiny["tr"]
    c = tr.cfg
    H, hd = c.n_heads, c.d_model // c.n_heads
    g = torch.Generator().manual_seed(batch * 100 + steps * 10 + past)
    text = torch.randn(batch, c.text_dim, generator=g)
    tokens = torch.randint(0, c.codebook_size, (batch, steps, c.num_levels), generator=g)
    if past == 0:
        tokens[:, 0] = c.bos_id  # the first call carries the PnQ prefix
    pasts = [torch.randn(batch, c.num_levels * H, past, hd, generator=g) for _ in range(2 * c.n_layers)]
    control = torch.randn(batch, steps, c.control_dim, generator=g)          # the tiny preset has control
    with torch.no_grad():
        want = StepGraph(tr)(text, tokens, control, *pasts)
    sess = session(tiny["bundle"] / "step.onnx")
    feed = {"text_embedding": text.numpy(), "tokens": tokens.numpy(), "control": control.numpy()}
    for i in range(c.n_layers):
        feed[f"past_key_values.{i}.key"] = pasts[2 * i].numpy()
        feed[f"past_key_values.{i}.value"] = pasts[2 * i + 1].numpy()
    got = sess.run(None, feed)
    errs = [float(np.abs(g_ - w.numpy()).max()) for g_, w in zip(got, want)]
    print(f"step batch={batch} steps={steps} past={past} (max_rel_dist {c.max_rel_dist}): max abs err "
          f"logits {errs[0]:.2e}, cache {max(errs[1:]):.2e}")
    assert got[1].shape == (batch, c.num_levels * H, past + steps, hd)
    assert max(errs) < FP32_BAR


@pytest.mark.parametrize("batch,tokens", [(1, 1), (2, 7), (3, 16)])
def test_lookup_and_decoder_graphs_match_torch(tiny, batch, tokens):
    vq = tiny["vq"]
    g = torch.Generator().manual_seed(batch * 31 + tokens)
    idx = torch.randint(0, vq.cfg.codebook_size, (batch, tokens, vq.cfg.num_levels), generator=g)
    with torch.no_grad():
        latent = vq.quantizer.lookup(idx)
        feats = DecoderGraph(vq, tiny["mean"], tiny["std"])(latent)
    got_latent = session(tiny["bundle"] / "lookup.onnx").run(None, {"tokens": idx.numpy()})[0]
    got_feats = session(tiny["bundle"] / "decoder.onnx").run(None, {"latent": latent.numpy()})[0]
    e1, e2 = np.abs(got_latent - latent.numpy()).max(), np.abs(got_feats - feats.numpy()).max()
    print(f"lookup batch={batch} tokens={tokens}: {e1:.2e}; decoder: {e2:.2e}")
    assert got_feats.shape == (batch, tokens * vq.cfg.downsample, 263)
    assert e1 < FP32_BAR and e2 < FP32_BAR


def test_fp32_graphs_use_only_standard_operators(tiny):
    bundle = Bundle.load(tiny["bundle"])
    for graph in ("text_encoder", "step", "lookup", "decoder"):
        model = onnx.load(str(bundle.graph_path(graph, "fp32")))
        domains = {n.domain for n in model.graph.node}
        assert domains <= {"", "ai.onnx"}, (graph, domains)
        assert not {n.op_type for n in model.graph.node} & {"If", "Loop", "Scan"}
        meta = {p.key: p.value for p in model.metadata_props}
        assert graph == "text_encoder" or meta["mogo.graph"] == graph


def test_manifest_describes_dims_and_symbolic_shapes(tiny):
    manifest = json.loads((tiny["bundle"] / "manifest.json").read_text())
    tr = tiny["tr"]
    assert manifest["model"]["num_levels"] == tr.cfg.num_levels
    assert manifest["model"]["receptive_field"] == tiny["vq"].receptive_field
    step = {v["name"]: v["shape"] for v in manifest["graphs"]["step"]["inputs"]}
    assert step["tokens"][:2] == ["batch", "steps"] and step["past_key_values.0.key"][2] == "past"
    assert set(manifest["variants"]) == {"fp32", "int8", "portable", "int8_fixed", "compact", "int8_ort", "portable_ort"}
    assert manifest["variants"]["int8"]["step"]["file"] == "step.int8.onnx"
    assert manifest["variants"]["int8_fixed"]["step"] == {
        "file": "step.portable.int8.onnx", "quantization": {"method": "mogo.per_row_dynamic", "per_channel": True,
                                                            "weight_type": "QInt8", "reduce_range": True,
                                                            "op_types": ["MatMul", "Gemm"]}}
    assert manifest["variants"]["portable"]["step"]["file"] == "step.portable.onnx"


def test_bundle_load_refuses_corruption_and_missing_files(tiny, tmp_path):
    copy = tmp_path / "b"
    shutil.copytree(tiny["bundle"], copy)
    Bundle.load(copy)
    data = bytearray((copy / "lookup.onnx").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (copy / "lookup.onnx").write_bytes(bytes(data))
    with pytest.raises(BundleError, match="lookup.onnx: sha256"):
        Bundle.load(copy)
    (copy / "lookup.onnx").unlink()
    with pytest.raises(BundleError, match="lookup.onnx: listed in manifest"):
        Bundle.load(copy)
    with pytest.raises(BundleError, match="manifest missing"):
        Bundle.load(tmp_path)


def test_a_manifest_that_misdescribes_a_graph_is_refused_by_load_and_by_the_generator(tiny, tmp_path):
    from mogo_runtime.generator import MotionGenerator

    copy = tmp_path / "b"
    shutil.copytree(tiny["bundle"], copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["graphs"]["decoder"]["outputs"][0]["dtype"] = "float16"  # the graph's output is float32
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BundleError, match=r"decoder.onnx: output 'features' has type tensor\(float\), manifest "
                                          r"says float16"):
        Bundle.load(copy)
    for variant in ("fp32", "int8"):  # loads for one variant: its own sessions are what get checked
        with pytest.raises(BundleError, match=r"decoder.onnx: output 'features' has type"):
            MotionGenerator(copy, variant=variant)


def test_export_is_atomic_when_it_fails(tiny, tmp_path, monkeypatch):
    import mogo_export.export.bundle as B

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(B, "export_decoder", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        export_bundle(tiny["root"] / "ck", tmp_path / "bundle", log=lambda *a: None)
    assert list(tmp_path.iterdir()) == []  # no half bundle, no leftover temp folder


def test_an_export_killed_mid_way_leaves_nothing_the_next_export_keeps(tmp_path):
    """kill -9 during `mogo-export export` strands its `.NAME.partial-PID` folder; the next export removes the
    folders of dead exporters and keeps a live one's."""
    import subprocess
    from mogo_export.export.bundle import remove_dead_partials
    out = tmp_path / "bundle"
    dead = subprocess.Popen(["true"])
    dead.wait()                                        # a pid that no longer runs
    live = tmp_path / f".bundle.partial-{os.getppid()}"
    for folder in (tmp_path / f".bundle.partial-{dead.pid}", live, tmp_path / ".other.partial-1"):
        folder.mkdir()
        (folder / "step.onnx").write_bytes(b"half")
    assert remove_dead_partials(out) == [tmp_path / f".bundle.partial-{dead.pid}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, ".other.partial-1"])
