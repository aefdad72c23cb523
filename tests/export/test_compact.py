"""The compact variant as exported (mogo_export/export/weightquant.py): weights stored int8 per channel and turned
back into float32 by Cast and Mul inside the graph, so every runtime holds the same weights and computes in float32;
opset 15 and only operators Unity's Inference Engine imports; onnxruntime folds the dequantization into float32
constants and never into integer kernels.
"""
import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper
from random_tiny import random_tiny_bundle

from mogo_export.export.opset import INT8_OPS, UNITY_OPS, UNITY_OPSET, unity_problems
from mogo_export.export.weightquant import quantize_weight, quantize_weights
from mogo_runtime.bundle import Bundle
from mogo_runtime.bundle.manifest import COMPACT
from mogo_runtime.bundle.sections import WEIGHT_INT8

GRAPHS = ("text_encoder", "step", "lookup", "decoder", "decoder_step")   # the exporter writes all five


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return random_tiny_bundle(tmp_path_factory)


def session(model, level=ort.GraphOptimizationLevel.ORT_ENABLE_ALL, optimized_to=None):
    so = ort.SessionOptions()
    so.graph_optimization_level = level
    if optimized_to:
        so.optimized_model_filepath = str(optimized_to)
    data = model.SerializeToString() if isinstance(model, onnx.ModelProto) else str(model)
    return ort.InferenceSession(data, so, providers=["CPUExecutionProvider"])


def dequantized(model: onnx.ModelProto) -> onnx.ModelProto:
    """The compact graph with every Cast(int8) -> Mul(scale) pair replaced by its float32 product, computed by
    numpy: the portable graph a reader would run if the weights had been stored as these float32 numbers."""
    out = onnx.ModelProto()
    out.CopyFrom(model)
    g = out.graph
    inits = {t.name: numpy_helper.to_array(t) for t in g.initializer}
    producers = {o: n for n in g.node for o in n.output}
    fold, drop = [], set()
    for n in g.node:
        if n.op_type == "Mul" and n.input[0] in producers and producers[n.input[0]].op_type == "Cast":
            cast = producers[n.input[0]]
            if cast.input[0] in inits and inits[cast.input[0]].dtype == np.int8:
                w = inits[cast.input[0]].astype(np.float32) * inits[n.input[1]]
                fold.append(numpy_helper.from_array(w.astype(np.float32), n.output[0]))
                drop |= {id(n), id(cast)}
    nodes = [n for n in g.node if id(n) not in drop]
    used = {i for n in nodes for i in n.input}
    kept = [t for t in g.initializer if t.name in used]
    del g.node[:], g.initializer[:]
    g.node.extend(nodes)
    g.initializer.extend(kept + fold)
    return out


def feed_for(sess, rng, codebook_size):
    feed = {}
    for i in sess.get_inputs():
        shape = [d if isinstance(d, int) else 2 if d == "batch" else 5 for d in i.shape]
        if i.name == "position":
            feed[i.name] = np.array([0, 3])
        elif i.name == "tokens":
            feed[i.name] = rng.integers(0, codebook_size, shape)
        elif i.name in ("input_ids", "attention_mask"):
            feed[i.name] = rng.integers(1, 50, shape) if i.name == "input_ids" else np.ones(shape, np.int64)
        else:
            feed[i.name] = rng.standard_normal(shape).astype(np.float32)
    return feed


def test_a_weight_is_stored_within_half_a_step_per_output_channel():
    rng = np.random.default_rng(0)
    w = rng.standard_normal((64, 48)).astype(np.float32) * rng.uniform(0.01, 3, 48).astype(np.float32)
    w[:, 5] = 0.0                                             # a channel of zeros: scale 1, q 0
    q, scale = quantize_weight(w, -1)
    assert q.dtype == np.int8 and scale.shape == (1, 48) and scale.dtype == np.float32
    assert np.all(np.abs(w - q * scale) <= scale / 2 + 1e-7) and np.abs(q).max() == 127
    assert np.all(q[:, 5] == 0) and scale[0, 5] == 1.0
    q0, s0 = quantize_weight(w, 0)                            # rows (a Gather table, Gemm with transB)
    assert s0.shape == (64, 1) and np.all(np.abs(w - q0 * s0) <= s0 / 2 + 1e-7)


def _matmul_graph(w: np.ndarray, bias: np.ndarray, shared_by_gather: bool = False) -> onnx.ModelProto:
    nodes = [helper.make_node("MatMul", ["x", "w"], ["xw"]), helper.make_node("Add", ["xw", "b"], ["y"])]
    if shared_by_gather:                                      # the same table read along its rows as well
        nodes.append(helper.make_node("Gather", ["w", "i"], ["rows"], axis=0))
    graph = helper.make_graph(
        nodes, "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", w.shape[0]])]
        + ([helper.make_tensor_value_info("i", TensorProto.INT64, ["m"])] if shared_by_gather else []),
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["n", w.shape[1]])]
        + ([helper.make_tensor_value_info("rows", TensorProto.FLOAT, ["m", w.shape[1]])] if shared_by_gather else []),
        [numpy_helper.from_array(w, "w"), numpy_helper.from_array(bias, "b")])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", UNITY_OPSET)], ir_version=8)


def test_weights_become_int8_biases_stay_and_the_arithmetic_is_float32():
    rng = np.random.default_rng(1)
    w = rng.standard_normal((96, 80)).astype(np.float32)
    bias = rng.standard_normal(80).astype(np.float32)
    model = _matmul_graph(w, bias)
    q = quantize_weights(model, min_elements=1000)
    types = {t.name: t.data_type for t in q.graph.initializer}
    assert types["w_int8"] == TensorProto.INT8 and types["b"] == TensorProto.FLOAT and "w" not in types
    assert {n.op_type for n in q.graph.node} == {"Cast", "Mul", "MatMul", "Add"}
    x = rng.standard_normal((7, 96)).astype(np.float32)
    got = session(q).run(None, {"x": x})[0]
    want = session(dequantized(q)).run(None, {"x": x})[0]
    assert np.array_equal(got, want)                          # the same float32 arithmetic, bit for bit
    err = np.abs(got - session(model).run(None, {"x": x})[0])
    _, scale = quantize_weight(w, -1)
    bound = np.abs(x) @ np.broadcast_to(scale / 2, w.shape)   # each weight within half its channel's step
    print(f"int8-stored weights vs float32: max abs difference {err.max():.2e} (outputs ~{np.abs(want).mean():.1f})")
    assert 0 < err.max() and np.all(err <= bound + 1e-4)
    # below the size threshold, or read along two different axes: left in float32
    assert quantize_weights(model, min_elements=w.size + 1).graph.initializer[0].data_type == TensorProto.FLOAT
    shared = quantize_weights(_matmul_graph(w, bias, shared_by_gather=True), min_elements=1000)
    assert {t.name: t.data_type for t in shared.graph.initializer}["w"] == TensorProto.FLOAT


def test_the_compact_variant_is_exported_small_standard_and_folded_to_float32(tiny, tmp_path):
    bundle = Bundle.load(tiny["bundle"])
    m = bundle.manifest
    assert m.fixed_cache(COMPACT) and not m.row_by_row(COMPACT)            # batched, as int8_fixed
    rng = np.random.default_rng(2)
    sizes = {}
    for graph in GRAPHS:
        entry = m.variants[COMPACT][graph]
        assert entry.quantization.method == WEIGHT_INT8 and entry.quantization.options["opset"] == UNITY_OPSET
        model = onnx.load(str(bundle.graph_path(graph, COMPACT)))
        assert unity_problems(model) == [], graph
        scales = {n.input[1] for n in model.graph.node if n.name.endswith("_dequantize")}
        big = [(t.name, TensorProto.DataType.Name(t.data_type)) for t in model.graph.initializer
               if np.prod(t.dims) >= entry.quantization.options["min_elements"] and t.name not in scales]
        assert all(dtype == "INT8" for _, dtype in big), (graph, big)   # every large tensor is a stored weight
        # onnxruntime folds Cast -> Mul into float32 constants: no integer kernel, no int8 left
        optimized = tmp_path / f"{graph}.optimized.onnx"
        sess = session(model, optimized_to=optimized)
        done = onnx.load(str(optimized))
        ops = {n.op_type for n in done.graph.node}
        assert not ops & (INT8_OPS | {"MatMulNBits", "QGemm", "DynamicQuantizeLSTM"}), (graph, ops & INT8_OPS)
        assert TensorProto.INT8 not in {t.data_type for t in done.graph.initializer}, graph
        assert big or graph == "lookup", graph                   # the tiny codebook is below the threshold
        # and it computes what the same graph with the float32 weights q * s computes, bit for bit
        feed = feed_for(sess, rng, tiny["tr"].cfg.codebook_size)
        for got, want in zip(sess.run(None, feed), session(dequantized(model)).run(None, feed)):
            assert np.array_equal(got, want), graph
        portable = bundle.graph_path(graph, "portable")
        sizes[graph] = (bundle.graph_path(graph, COMPACT).stat().st_size, portable.stat().st_size)
    print("compact vs portable bytes:", sizes)
    assert sum(c for c, _ in sizes.values()) < 0.4 * sum(p for _, p in sizes.values())
    manifest = json.loads((tiny["bundle"] / "manifest.json").read_text())
    assert set(manifest["variants"][COMPACT]) == set(GRAPHS)


def test_the_unity_check_names_what_unity_cannot_import(tiny):
    """The int8 step (DynamicQuantizeLinear, MatMulInteger at opset 20) and an operator outside Unity's table."""
    bundle = Bundle.load(tiny["bundle"])
    problems = unity_problems(onnx.load(str(bundle.graph_path("step", "int8"))))
    assert any("DynamicQuantizeLinear" in p for p in problems) and any("MatMulInteger" in p for p in problems)
    assert any("opset" in p for p in problems)
    assert "Det" not in UNITY_OPS
    det = helper.make_model(helper.make_graph(
        [helper.make_node("Det", ["x"], ["y"])], "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [3, 3])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [])]), opset_imports=[helper.make_opsetid("", 15)])
    assert unity_problems(det) == ["operator Det is not imported by Unity's Inference Engine"]
