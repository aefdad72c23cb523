"""The portable variant as exported: the fixed-capacity step computes the torch step, every portable graph follows
the rules (opset 17, default domain, no int8 ops, no control flow, at most 8 dims) and converts down to the lowest
opset we can reach, and the ORT-format graphs load, run and compute what their ONNX sources compute.

Lowest opsets (mogo_export/export/opset.py): 15 for every portable graph, 14 for the step graph; one lower fails,
and these tests say so if a newer onnx stops failing.
"""
import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from random_tiny import random_tiny_bundle

from mogo_export.export.bundle import export_bundle
from mogo_export.export.graphs import StepGraph
from mogo_export.export.opset import LOWEST_OPSET, LOWEST_STEP_OPSET, portable_problems, to_opset
from mogo_export.export.portable import FixedCacheStepGraph
from mogo_runtime.bundle import Bundle, BundleError, read_manifest
from mogo_runtime.bundle.sections import PORTABLE_OPSET, required_capacity

FP32_BAR = 1e-4
GRAPHS = ("text_encoder", "step", "lookup", "decoder", "decoder_step")   # the exporter writes all five


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """Random tiny models and their bundle, exported once for the test process (random_tiny.py)."""
    return random_tiny_bundle(tmp_path_factory)


def session(model):
    data = model.SerializeToString() if isinstance(model, onnx.ModelProto) else str(model)
    return ort.InferenceSession(data, providers=["CPUExecutionProvider"])


def portable_feed(tr, capacity, batch, position, seed):
    """Random text, one step of tokens (BOS at position 0), a random control and a random full cache."""
    c = tr.cfg
    g = torch.Generator().manual_seed(seed)
    text = torch.randn(batch, c.text_dim, generator=g)
    tokens = torch.randint(0, c.codebook_size, (batch, 1, c.num_levels), generator=g)
    if position == 0:
        tokens[:] = c.bos_id
    cache = [torch.randn(batch, c.num_levels * c.n_heads, capacity, c.d_model // c.n_heads, generator=g)
             for _ in range(2 * c.n_layers)]
    control = torch.randn(batch, 1, c.control_dim, generator=g)               # the tiny preset has control
    return text, tokens, control, cache


def graph_feed(path: str, tiny, rng) -> dict:
    """Inputs for any graph of the bundle, from its declared shapes (symbolic dims: batch 2, any other 5)."""
    s = session(path)
    feed = {}
    for i in s.get_inputs():
        shape = [d if isinstance(d, int) else 2 if d == "batch" else 5 for d in i.shape]
        if i.name == "position":
            feed[i.name] = np.array([0, 3])
        elif i.name == "tokens":
            feed[i.name] = rng.integers(0, tiny["tr"].cfg.codebook_size, shape)
        elif i.name in ("input_ids", "attention_mask"):
            feed[i.name] = rng.integers(1, 50, shape) if i.name == "input_ids" else np.ones(shape, np.int64)
        else:
            feed[i.name] = rng.standard_normal(shape).astype(np.float32)
    return feed


@pytest.mark.parametrize("batch,position", [(1, 0), (2, 1), (3, 5), (1, 11), (2, 23), (1, 24)])
def test_the_fixed_cache_step_is_the_torch_step_over_the_first_position_slots(tiny, batch, position):
    """The graph's logits and written slot equal the torch step whose past is the cache's first `position` slots;
    the slots after it come back unchanged (the tiny model clips distances at 8: 11 and 24 are past the clip)."""
    tr = tiny["tr"]
    manifest = read_manifest(tiny["bundle"])
    cap = manifest.portable.capacity
    text, tokens, control, cache = portable_feed(tr, cap, batch, position, seed=batch * 100 + position)
    with torch.no_grad():
        want = StepGraph(tr)(text, tokens, control, *(p[:, :, :position] for p in cache))
        module = FixedCacheStepGraph(tr, cap)(text, tokens, control, torch.full((batch,), position), *cache)
    feed = {"text_embedding": text.numpy(), "tokens": tokens.numpy(), "position": np.full(batch, position),
            "control": control.numpy(), **dict(zip(manifest.past_names, (p.numpy() for p in cache)))}
    got = session(tiny["bundle"] / "step.portable.onnx").run(None, feed)
    for name, out in (("onnx", got), ("torch module", [o.numpy() for o in module])):
        err_logits = np.abs(out[0] - want[0].numpy()).max()
        err_cache = max(np.abs(p[:, :, :position + 1] - w.numpy()).max() for p, w in zip(out[1:], want[1:]))
        print(f"portable step ({name}) b={batch} position={position} of {cap}: logits {err_logits:.2e}, "
              f"cache {err_cache:.2e}")
        assert err_logits < FP32_BAR and err_cache < FP32_BAR
        assert all(np.array_equal(p[:, :, position + 1:], c[:, :, position + 1:].numpy()) for p, c in zip(out[1:],
                                                                                                      cache))
        assert out[1].shape == (batch, tr.cfg.num_levels * tr.cfg.n_heads, cap, tr.cfg.d_model // tr.cfg.n_heads)


def test_a_position_past_the_capacity_is_an_error_not_a_lost_write(tiny):
    tr = tiny["tr"]
    manifest = read_manifest(tiny["bundle"])
    cap = manifest.portable.capacity
    text, tokens, control, cache = portable_feed(tr, cap, 1, 0, seed=0)
    feed = {"text_embedding": text.numpy(), "tokens": tokens.numpy(), "position": np.array([cap]),
            "control": control.numpy(), **dict(zip(manifest.past_names, (p.numpy() for p in cache)))}
    with pytest.raises(Exception, match="(?i)index|indices|indice"):
        session(tiny["bundle"] / "step.portable.onnx").run(None, feed)


def test_the_portable_graphs_follow_the_rules_and_the_manifest_gives_every_size(tiny):
    manifest = json.loads((tiny["bundle"] / "manifest.json").read_text())
    bundle = Bundle.load(tiny["bundle"])
    m = bundle.manifest
    assert m.portable.opset == PORTABLE_OPSET == 17
    assert m.portable.capacity == required_capacity(m.model, m.streaming) == m.model.max_tokens + 1
    for graph in GRAPHS:
        model = onnx.load(str(bundle.graph_path(graph, "portable")))
        assert portable_problems(model, PORTABLE_OPSET) == [], graph
    # everything but the batch is a number a consumer can allocate from
    step = manifest["portable"]["step"]
    for spec in step["inputs"] + step["outputs"]:
        assert spec["shape"][0] == "batch" and all(isinstance(d, int) for d in spec["shape"][1:]), spec
    assert [s["name"] for s in step["inputs"][:4]] == ["text_embedding", "tokens", "control", "position"]
    # the dynamic step (opset 20, int8 ops in its int8 file) is not portable: the rules would say why
    assert portable_problems(onnx.load(str(bundle.graph_path("step", "int8"))), PORTABLE_OPSET)


def test_every_portable_graph_runs_at_the_lowest_opset_and_one_lower_fails(tiny):
    """What the exporter can produce below 17 (mogo_export/export/opset.py): LayerNormalization rewritten, then
    onnx.version_converter. The step and the lookup go to 14, the decoders (Shape-15 on their dynamic sizes) to 15, so
    the variant as a whole to 15; no graph to 13 (Add-14). The outputs stay those of the opset-17 graph."""
    bundle = Bundle.load(tiny["bundle"])
    rng = np.random.default_rng(0)
    lowest = {}
    for graph in GRAPHS:
        path = bundle.graph_path(graph, "portable")
        model = onnx.load(str(path))
        feed = graph_feed(str(path), tiny, rng)
        want = session(model).run(None, feed)
        for opset in range(PORTABLE_OPSET - 1, LOWEST_STEP_OPSET - 2, -1):
            try:
                low = to_opset(model, opset)
            except ValueError as e:
                assert "No Adapter From Version" in str(e), str(e)
                break
            assert portable_problems(low, opset) == [] and "LayerNormalization" not in {n.op_type for n in
                                                                                        low.graph.node}
            got = session(low).run(None, feed)
            err = max(float(np.abs(a - b).max()) for a, b in zip(got, want))
            assert err < FP32_BAR, (path.name, opset, err)
            lowest[graph] = (opset, err)
    print("lowest opset (max abs difference to the opset-17 graph):", lowest)
    assert {g: o for g, (o, _) in lowest.items() if g != "text_encoder"} == {"step": LOWEST_STEP_OPSET,
                                                                            "lookup": 14, "decoder": LOWEST_OPSET,
                                                                            "decoder_step": LOWEST_OPSET}
    assert LOWEST_STEP_OPSET <= lowest["text_encoder"][0] <= LOWEST_OPSET   # MiniLM (Shape-15) stops at 15


def test_ort_files_load_run_and_compute_what_their_sources_compute(tiny):
    bundle = Bundle.load(tiny["bundle"])
    m = bundle.manifest
    assert m.ort.variants == {"int8_ort": "int8", "portable_ort": "portable"}
    rng = np.random.default_rng(1)
    sizes = {}
    for variant, source in m.ort.variants.items():
        for graph in GRAPHS:
            ort_path, onnx_path = bundle.graph_path(graph, variant), bundle.graph_path(graph, source)
            assert ort_path.suffix == ".ort" and ort_path.stem == onnx_path.stem
            feed = graph_feed(str(onnx_path), tiny, rng)
            got, want = session(ort_path).run(None, feed), session(onnx_path).run(None, feed)
            assert max(float(np.abs(a - b).max()) for a, b in zip(got, want)) < FP32_BAR, ort_path.name
            sizes[ort_path.name] = ort_path.stat().st_size
    print("ORT-format files (tiny model):", sizes)
    config = (tiny["bundle"] / m.ort.required_operators).read_text().splitlines()
    listed = [line[4:] for line in config if line.startswith("# - ")]
    assert sorted(listed) == sorted(sizes)          # every .ort, by its name in the bundle
    entries = [line.split(";") for line in config if line and not line.startswith("#")]
    assert entries and all(len(e) == 3 and e[0] in ("ai.onnx", "com.microsoft") and int(e[1]) > 0 for e in entries)
    ops = {op for e in entries for op in e[2].split(",")}
    assert {"ScatterND", "CumSum", "Softmax", "MatMulIntegerToFloat", "DynamicQuantizeLinear"} <= ops


def test_a_damaged_ort_file_or_operator_list_is_refused(tiny, tmp_path):
    import shutil

    copy = tmp_path / "b"
    shutil.copytree(tiny["bundle"], copy)
    for name in ("step.portable.ort", "required_operators.config"):
        data = bytearray((copy / name).read_bytes())
        data[len(data) // 2] ^= 0xFF
        (copy / name).write_bytes(bytes(data))
        with pytest.raises(BundleError, match=f"{name}: sha256"):
            Bundle.load(copy)
        shutil.copy(tiny["bundle"] / name, copy / name)


def test_export_without_the_portable_variant_and_its_options(tiny, tmp_path):
    with pytest.raises(ValueError, match="--ort accepts"):
        export_bundle(tiny["root"] / "ck", tmp_path / "x", portable=False, ort=("portable",), log=lambda *a: None)
    out = export_bundle(tiny["root"] / "ck", tmp_path / "plain", int8=(), portable=False, ort=(),
                        log=lambda *a: None)
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["variants"]) == {"fp32", "int8"} and "portable" not in manifest and "ort" not in manifest
    assert not list(out.glob("*.ort")) and not (out / "step.portable.onnx").exists()
    Bundle.load(out)
