"""Opsets below the ones torch.onnx writes, and the rules a portable graph follows (docs/bundle.md, "The portable
variant").

    model = to_opset(onnx.load("decoder.onnx"), 15)     # the lowest opset every portable graph converts to
    assert not portable_problems(model, 15)

torch.onnx (dynamo) writes opset 18 and newer itself. Asked for less, it converts with onnxscript, falls back to
onnx's C converter without the initializers, fails (ReduceMean/ReduceL2 axes "No initializer or constant input")
and then **keeps opset 18 without an error**. So the exporters ask torch for 18 and convert here, on the whole
model, after the rewrites onnx.version_converter lacks (measured with onnx 1.23.2 on the base graphs):
- 18 -> 17: Reduce* nodes keep `noop_with_empty_axes` and Split keeps `num_outputs`, attributes opset 17 does not
  know ("Unrecognized attribute"); both are dropped (0 is that attribute's default; torch's splits are equal parts,
  which is what a Split without sizes does at 17).
- 17 -> 16: LayerNormalization has no earlier version ("No Previous Version of LayerNormalization exists"); it is
  rewritten as ReduceMean/Sub/Mul/Sqrt/Div/Add (logits move by ~5e-6 on base).
- 15 -> 14: no adapter for Shape (opset 15 added `start`/`end`): the text encoder and the decoder read their
  dynamic sizes with Shape, so **15 is the lowest for the whole portable variant** (the Unity Sentis range is 7-15).
  The portable step has no Shape (portable.py) and goes to 14;
- 14 -> 13: no adapter for Add (and Sub, Mul, Div, Reshape: opset 14 added types and `allowzero`), in every graph.
  Below that, CumSum (opset 11) has no earlier version at all.
tests/export/test_portable.py runs every portable graph at 15 (the step at 14) and checks that one opset lower
still fails, so a newer onnx that can go lower is noticed.
"""
from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper, version_converter

TORCH_MIN_OPSET = 18           # what torch.onnx writes without converting
LOWEST_OPSET = 15              # what to_opset takes every portable graph to (the step graph: 14; docstring)
LOWEST_STEP_OPSET = 14
# int8 operators: Unity Sentis imports none of them (DynamicQuantizeLinear, MatMulInteger, ...)
INT8_OPS = frozenset({"DynamicQuantizeLinear", "MatMulInteger", "ConvInteger", "QuantizeLinear", "DequantizeLinear",
                      "QLinearMatMul", "QLinearConv", "DynamicQuantizeMatMul", "MatMulIntegerToFloat"})
CONTROL_FLOW = frozenset({"If", "Loop", "Scan"})
MAX_RANK = 8                   # Sentis tensors have at most 8 dims
# The ai.onnx operators Unity's Inference Engine imports (the "Supported ONNX operators" table of its manual,
# com.unity.ai.inference 2.3; Sentis 2.1 lists the same): the compact variant uses none but these. None of INT8_OPS
# is there, nor If/Loop/Scan. Its manual recommends opset 15.
UNITY_OPS = frozenset("""
    Abs Acos Acosh Add And ArgMax ArgMin Asin Asinh Atan Atanh AveragePool BatchNormalization Bernoulli Cast CastLike
    Ceil Celu Clip Compress Concat Constant ConstantOfShape Conv ConvTranspose Cos Cosh CumSum DepthToSpace Div
    Dropout Einsum Elu Equal Erf Exp Expand EyeLike Flatten Floor Gather GatherElements GatherND Gelu Gemm
    GlobalAveragePool GlobalMaxPool Greater GreaterOrEqual GridSample Hardmax HardSigmoid HardSwish Identity
    InstanceNormalization IsInf IsNaN LayerNormalization LeakyRelu Less LessOrEqual Log LogSoftmax LRN LSTM MatMul Max
    MaxPool Mean Min Mod Mul Multinomial Neg NonMaxSuppression NonZero Not OneHot Or Pad Pow PRelu RandomNormal
    RandomNormalLike RandomUniform RandomUniformLike Range Reciprocal ReduceL1 ReduceL2 ReduceLogSum ReduceLogSumExp
    ReduceMax ReduceMean ReduceMin ReduceProd ReduceSum ReduceSumSquare Relu Reshape Resize RoiAlign Round
    ScatterElements ScatterND Selu Shape Shrink Sigmoid Sign Sin Sinh Size Slice Softmax Softplus Softsign
    SpaceToDepth Split Sqrt Squeeze Sub Sum Tan Tanh ThresholdedRelu Tile TopK Transpose Trilu Unsqueeze Upsample Where
    Xor""".split())
UNITY_OPSET = 15
_NEW_AT_18 = {"noop_with_empty_axes": "Reduce", "num_outputs": "Split"}   # attribute -> op (prefix) that gained it


def default_opset(model: onnx.ModelProto) -> int:
    versions = [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")]
    if len(versions) != 1:
        imports = [(o.domain, o.version) for o in model.opset_import]
        raise ValueError(f"expected one ai.onnx opset import, got {imports}")
    return versions[0]


def to_opset(model: onnx.ModelProto, opset: int) -> onnx.ModelProto:
    """A copy of `model` at ai.onnx `opset` (<= its own), checked; ValueError where onnx cannot convert it."""
    current = default_opset(model)
    if opset > current:
        raise ValueError(f"to_opset converts down only: the model is at opset {current}, asked for {opset}")
    if opset == current:
        return model
    out = onnx.ModelProto()
    out.CopyFrom(model)
    if current > 17:
        _drop_attributes_new_at_18(out.graph)
        out = _convert(out, max(opset, 17))
    if opset < 17:
        _decompose_layer_norm(out.graph)
        out = _convert(out, opset)
    onnx.checker.check_model(out, full_check=True)
    return out


def _convert(model: onnx.ModelProto, opset: int) -> onnx.ModelProto:
    try:
        return version_converter.convert_version(model, opset)
    except RuntimeError as e:   # onnx reports a missing adapter as an assertion in its C++ code
        raise ValueError(f"onnx.version_converter cannot take this graph to opset {opset}: "
                         f"{str(e).splitlines()[0]}") from None


def _drop_attributes_new_at_18(graph: onnx.GraphProto) -> None:
    for node in graph.node:
        keep = [a for a in node.attribute
                if not (a.name in _NEW_AT_18 and node.op_type.startswith(_NEW_AT_18[a.name])
                        and (a.name == "num_outputs" or a.i == 0))]
        if len(keep) != len(node.attribute):
            del node.attribute[:]
            node.attribute.extend(keep)


def _decompose_layer_norm(graph: onnx.GraphProto) -> None:
    """LayerNormalization (opset 17) over the last axis as the ops every opset has:
    y = (x - mean) / sqrt(mean((x - mean)^2) + eps) * scale + bias."""
    nodes, consts = [], []
    for k, node in enumerate(graph.node):
        if node.op_type != "LayerNormalization":
            nodes.append(node)
            continue
        attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
        if attrs.get("axis", -1) != -1 or any(node.output[1:]):
            raise ValueError(f"{node.name}: only LayerNormalization over the last axis with one output is rewritten")
        x, scale, bias = node.input[0], node.input[1], node.input[2] if len(node.input) > 2 else ""
        p = f"{node.name or 'layer_norm'}_{k}/"
        consts.append(numpy_helper.from_array(np.array(attrs.get("epsilon", 1e-5), np.float32), p + "epsilon"))
        scaled = p + "scaled" if bias else node.output[0]
        nodes += [helper.make_node("ReduceMean", [x], [p + "mean"], axes=[-1], keepdims=1),
                  helper.make_node("Sub", [x, p + "mean"], [p + "centred"]),
                  helper.make_node("Mul", [p + "centred", p + "centred"], [p + "squared"]),
                  helper.make_node("ReduceMean", [p + "squared"], [p + "variance"], axes=[-1], keepdims=1),
                  helper.make_node("Add", [p + "variance", p + "epsilon"], [p + "variance_eps"]),
                  helper.make_node("Sqrt", [p + "variance_eps"], [p + "std"]),
                  helper.make_node("Div", [p + "centred", p + "std"], [p + "normalised"]),
                  helper.make_node("Mul", [p + "normalised", scale], [scaled])]
        if bias:
            nodes.append(helper.make_node("Add", [scaled, bias], [node.output[0]]))
    del graph.node[:]
    graph.node.extend(nodes)
    graph.initializer.extend(consts)


def unity_problems(model: onnx.ModelProto) -> list[str]:
    """What keeps `model` out of Unity's Inference Engine as far as this table knows: operators it does not import,
    and the portable rules at its recommended opset. Empty when none."""
    ops = sorted({n.op_type for n in model.graph.node if n.domain in ("", "ai.onnx")} - UNITY_OPS)
    return portable_problems(model, UNITY_OPSET) + [f"operator {op} is not imported by Unity's Inference Engine"
                                                    for op in ops]


def portable_problems(model: onnx.ModelProto, opset: int) -> list[str]:
    """What keeps `model` from the portable variant: another opset than `opset` or another operator domain,
    int8 operators, control flow, a tensor of more than 8 dims. Empty when it complies."""
    problems = []
    imports = [(o.domain, o.version) for o in model.opset_import]
    if [v for d, v in imports if d in ("", "ai.onnx")] != [opset] or any(d not in ("", "ai.onnx") for d, _ in imports):
        problems.append(f"opset imports {imports}, expected only ai.onnx {opset}")
    ops = {(n.domain, n.op_type) for n in model.graph.node}
    problems += [f"operator {d}:{op} is not in the default domain" for d, op in sorted(ops) if d not in ("", "ai.onnx")]
    problems += [f"int8 operator {op}" for _, op in sorted(ops) if op in INT8_OPS]
    problems += [f"control flow {op}" for _, op in sorted(ops) if op in CONTROL_FLOW]
    inferred = onnx.shape_inference.infer_shapes(model)
    g = inferred.graph
    for v in (*g.input, *g.output, *g.value_info):
        if v.type.tensor_type.HasField("shape") and len(v.type.tensor_type.shape.dim) > MAX_RANK:
            problems.append(f"tensor {v.name} has {len(v.type.tensor_type.shape.dim)} dims (at most {MAX_RANK})")
    problems += [f"initializer {t.name} has {len(t.dims)} dims (at most {MAX_RANK})" for t in g.initializer
                 if len(t.dims) > MAX_RANK]
    return problems
