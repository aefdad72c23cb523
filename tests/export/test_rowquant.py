"""Per-row int8 (mogo_export/export/rowquant.py): on one row it is exactly onnxruntime's per-tensor dynamic int8, and a
row's numbers never depend on the rest of its batch (which per-tensor int8's do)."""
import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper
from onnxruntime.quantization import QuantType, quantize_dynamic

from mogo_export.export.rowquant import quantize_per_row

K, H, N = 48, 64, 24


@pytest.fixture(scope="module")
def graphs(tmp_path_factory):
    """x (B, S, K) -> MatMul -> Gelu-like (Tanh) -> MatMul, both weights constant; -> (per-tensor, per-row) sessions."""
    rng = np.random.default_rng(0)
    w1 = numpy_helper.from_array(rng.normal(size=(K, H)).astype(np.float32), "w1")
    w2 = numpy_helper.from_array(rng.normal(size=(H, N)).astype(np.float32) * 0.2, "w2")
    nodes = [helper.make_node("MatMul", ["x", "w1"], ["h"]), helper.make_node("Tanh", ["h"], ["a"]),
             helper.make_node("MatMul", ["a", "w2"], ["y"])]
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["B", "S", K])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["B", "S", N])], [w1, w2])
    folder = tmp_path_factory.mktemp("rowquant")
    for opset in (17, 20):
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
        onnx.save(model, folder / f"fp32_{opset}.onnx")
        quantize_dynamic(str(folder / f"fp32_{opset}.onnx"), str(folder / f"int8_{opset}.onnx"), per_channel=True,
                         weight_type=QuantType.QInt8)
        row = quantize_per_row(onnx.load(folder / f"int8_{opset}.onnx"))
        onnx.checker.check_model(row, full_check=True)
        onnx.save(row, folder / f"row_{opset}.onnx")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1

    def session(name):
        return ort.InferenceSession(str(folder / name), opts, providers=["CPUExecutionProvider"])
    return {opset: (session(f"int8_{opset}.onnx"), session(f"row_{opset}.onnx")) for opset in (17, 20)}


def run(sess, x):
    return sess.run(["y"], {"x": x})[0]


@pytest.mark.parametrize("opset", [17, 20])
def test_one_row_is_exactly_per_tensor_int8(graphs, opset):
    per_tensor, per_row = graphs[opset]
    rng = np.random.default_rng(1)
    for scale, shift in ((1.0, 0.0), (3.0, 2.0), (0.01, -0.5), (100.0, 0.0)):
        x = (rng.normal(size=(1, 1, K)) * scale + shift).astype(np.float32)
        assert np.array_equal(run(per_tensor, x), run(per_row, x)), (scale, shift)


@pytest.mark.parametrize("opset", [17, 20])
def test_a_row_does_not_depend_on_its_batch(graphs, opset):
    per_tensor, per_row = graphs[opset]
    rng = np.random.default_rng(2)
    x = (rng.normal(size=(16, 3, K)) * rng.uniform(0.1, 10, size=(16, 3, 1))).astype(np.float32)
    alone = np.concatenate([run(per_row, x[b:b + 1]) for b in range(16)])
    assert np.array_equal(run(per_row, x), alone)
    # per-tensor int8 scales every row by the whole batch's range: the same rows give other numbers
    alone_pt = np.concatenate([run(per_tensor, x[b:b + 1]) for b in range(16)])
    assert np.abs(run(per_tensor, x) - alone_pt).max() > 1e-3


def test_an_all_zero_row_stays_zero_and_finite(graphs):
    _, per_row = graphs[20]
    x = np.zeros((2, 1, K), np.float32)
    x[1] = 1.0
    y = run(per_row, x)
    assert np.isfinite(y).all() and np.array_equal(y[0], np.zeros_like(y[0]))


def test_unknown_patterns_are_refused():
    # a MatMulInteger whose weights are not constants cannot have its zero point moved out
    nodes = [helper.make_node("DynamicQuantizeLinear", ["x"], ["q", "s", "z"]),
             helper.make_node("MatMulInteger", ["q", "w", "z"], ["y"])]
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, K]),
                                           helper.make_tensor_value_info("w", TensorProto.INT8, [K, N])],
                              [helper.make_tensor_value_info("y", TensorProto.INT32, [1, N])])
    with pytest.raises(ValueError, match="not constants"):
        quantize_per_row(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 20)]))
