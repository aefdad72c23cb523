"""Per-row dynamic int8: the quantizer's per-tensor activation scales turned into one scale per row, so that a
row's numbers never depend on the other rows of its batch.

onnxruntime's `quantize_dynamic` quantizes each MatMul input with DynamicQuantizeLinear, whose scale and zero point
come from the range of the whole tensor: in a batch, a character's activations are rounded on a grid its
neighbours chose, and its motion changes with who else is in the batch (the runtime had to run int8 one row per
call). Here every DynamicQuantizeLinear becomes the same formula over the last axis (a token row):

    lo = min(0, min_k x),  hi = max(0, max_k x),  s = max((hi - lo) / 255, FLT_MIN)
    zp = clip(round(-lo / s), 0, 255),  q = uint8(clip(round(x / s) + zp, 0, 255))

and, as MatMulInteger takes only one activation zero point, the zero point leaves the integer product exactly:
q·W = sum_k (q_k - zp) W_k + zp · colsum(W), so each MatMulInteger runs without it and subtracts zp · colsum(W)
(int32, a constant per weight). Everything else in the graph (weights, their per-channel scales, the Cast and
scale Muls after each product) is the quantizer's. Rounding is ONNX Round (half to even), as DynamicQuantizeLinear.
A manifest names such graphs' method mogo_runtime.manifest.PER_ROW_INT8.
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper



def quantize_per_row(model: onnx.ModelProto) -> onnx.ModelProto:
    """`model` from onnxruntime's quantize_dynamic (uint8 activations, int8 weights) -> the same model with
    per-row activation quantization (module docstring). Raises ValueError on a pattern it does not know."""
    g = model.graph
    opset = next(o.version for o in model.opset_import if o.domain in ("", "ai.onnx"))
    inits = {i.name: i for i in g.initializer}
    users = defaultdict(list)
    for n in g.node:
        for name in n.input:
            users[name].append(n)
    const = _Constants(g)
    nodes: list[onnx.NodeProto] = []
    for n in g.node:
        if n.op_type == "DynamicQuantizeLinear":
            nodes += _per_row(n, opset, const)
        elif n.op_type == "MatMulInteger":
            nodes += _without_zero_point(n, inits, const)
        else:
            nodes.append(n)
    del g.node[:]
    g.node.extend(const.nodes + nodes)
    g.initializer.extend(const.initializers)
    return model


class _Constants:
    """Scalar and column-sum initializers, each made once."""

    def __init__(self, graph: onnx.GraphProto):
        self.taken = {i.name for i in graph.initializer} | {n for node in graph.node for n in node.output}
        self.initializers: list[onnx.TensorProto] = []
        self.nodes: list[onnx.NodeProto] = []
        self.made: dict[tuple, str] = {}

    def add(self, key: tuple, array: np.ndarray, name: str) -> str:
        if key not in self.made:
            while name in self.taken:
                name += "_"
            self.taken.add(name)
            self.initializers.append(numpy_helper.from_array(array, name))
            self.made[key] = name
        return self.made[key]

    def scalar(self, value, dtype) -> str:
        return self.add(("scalar", float(value), np.dtype(dtype).name), np.array(value, dtype),
                        f"rowquant_{np.dtype(dtype).name}_{value:g}")


def _per_row(n: onnx.NodeProto, opset: int, const: _Constants) -> list[onnx.NodeProto]:
    x, (q, scale, zero) = n.input[0], n.output
    p = f"{n.name or q}_rowquant"

    def out(suffix):
        return f"{p}_{suffix}"

    if opset >= 18:
        axes = const.add(("axes",), np.array([-1], np.int64), "rowquant_last_axis")
        reduce = [helper.make_node("ReduceMin", [x, axes], [out("min")], keepdims=1),
                  helper.make_node("ReduceMax", [x, axes], [out("max")], keepdims=1)]
    else:
        reduce = [helper.make_node("ReduceMin", [x], [out("min")], axes=[-1], keepdims=1),
                  helper.make_node("ReduceMax", [x], [out("max")], axes=[-1], keepdims=1)]
    zero_f, q_max = const.scalar(0.0, np.float32), const.scalar(255.0, np.float32)
    tiny = const.scalar(np.finfo(np.float32).tiny, np.float32)
    return reduce + [
        helper.make_node("Min", [out("min"), zero_f], [out("lo")]),
        helper.make_node("Max", [out("max"), zero_f], [out("hi")]),
        helper.make_node("Sub", [out("hi"), out("lo")], [out("range")]),
        helper.make_node("Div", [out("range"), q_max], [out("raw_scale")]),
        helper.make_node("Max", [out("raw_scale"), tiny], [scale]),           # an all-zero row: scale tiny, q = 0
        helper.make_node("Neg", [out("lo")], [out("neg_lo")]),
        helper.make_node("Div", [out("neg_lo"), scale], [out("zp_raw")]),
        helper.make_node("Round", [out("zp_raw")], [out("zp_round")]),
        helper.make_node("Clip", [out("zp_round"), zero_f, q_max], [out("zp_float")]),
        helper.make_node("Cast", [out("zp_float")], [zero], to=TensorProto.INT32),   # (..., 1) int32
        helper.make_node("Div", [x, scale], [out("scaled")]),
        helper.make_node("Round", [out("scaled")], [out("rounded")]),
        helper.make_node("Add", [out("rounded"), out("zp_float")], [out("shifted")]),
        helper.make_node("Clip", [out("shifted"), zero_f, q_max], [out("clipped")]),
        helper.make_node("Cast", [out("clipped")], [q], to=TensorProto.UINT8),
    ]


def _without_zero_point(n: onnx.NodeProto, inits: dict, const: _Constants) -> list[onnx.NodeProto]:
    """MatMulInteger(q, W, zp, w_zp) -> MatMulInteger(q, W, -, w_zp) - zp * colsum(W - w_zp), in int32."""
    a, w = n.input[0], n.input[1]
    a_zero = n.input[2] if len(n.input) > 2 else ""
    w_zero = n.input[3] if len(n.input) > 3 else ""
    if not a_zero:                      # no activation zero point: nothing to move
        return [n]
    if w not in inits or (w_zero and w_zero not in inits):
        raise ValueError(f"MatMulInteger {n.name}: its weights {w!r} are not constants")
    weights = numpy_helper.to_array(inits[w]).astype(np.int64)
    if weights.ndim != 2:
        raise ValueError(f"MatMulInteger {n.name}: weights of rank {weights.ndim}, expected 2")
    if w_zero:
        weights = weights - numpy_helper.to_array(inits[w_zero]).astype(np.int64)
    colsum = const.add(("colsum", w, w_zero), weights.sum(0).astype(np.int32), f"{w}_colsum")
    product, result = f"{n.output[0]}_without_zero_point", n.output[0]
    rewritten = helper.make_node("MatMulInteger", [a, w, "", w_zero] if w_zero else [a, w], [product],
                                 name=n.name)
    return [rewritten,
            helper.make_node("Mul", [a_zero, colsum], [f"{result}_zero_point_share"]),
            helper.make_node("Sub", [product, f"{result}_zero_point_share"], [result])]
