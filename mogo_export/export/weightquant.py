"""Weight-only int8: the compact variant's graphs (docs/bundle.md, "The compact variant"). Weights are stored as
int8 with one float32 scale per output channel; the graph turns them back into float32 itself, with the two
operators every ONNX runtime has, and computes in float32 from there:

    W (float32 [in, out])  ->  q = round(W / s) (int8 [in, out]),  s = max|W[:, j]| / 127 (float32 [out])
    graph:  Cast(q, to=float) -> Mul(s) -> the MatMul that read W

Why not DequantizeLinear: Unity's Inference Engine imports no QuantizeLinear/DequantizeLinear, and onnxruntime
fuses DequantizeLinear -> MatMul into integer kernels (QDQ fusion), which is where the platforms part (int8 on
CPUs with and without VNNI, wasm). Cast and Mul are exact in IEEE float32 on every CPU and in wasm, so each
runtime holds the same weights q * s and the arithmetic is the portable variant's; onnxruntime folds the pair into
a float32 constant when it loads the graph (tests/export/test_compact.py checks that no integer kernel appears).

Which initializers: those a MatMul or Gemm multiplies by (input B), a Gather looks rows up in (input 0: the token
and word embeddings) and a Conv convolves with (input 1), with at least MIN_ELEMENTS numbers. Biases, norms and
the graph's own constants (masks, one-hots, indices) stay as they are: exact, and small.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from .opset import UNITY_OPSET, to_opset, unity_problems

WEIGHT_INT8_MIN_ELEMENTS = 4096    # a weight smaller than this stays float32 (biases, norms, 1-D tables)
COMPACT_OPSET = UNITY_OPSET        # Unity's recommended opset; every portable graph converts to it (opset.py)


def _channel_axis(node: onnx.NodeProto, index: int) -> int | None:
    """The axis of the weight `node.input[index]` that indexes output channels (one scale each), or None where
    the initializer is not a weight this module quantizes."""
    if node.op_type == "MatMul" and index == 1:
        return -1                                              # [..., in, out]
    if node.op_type == "Gemm" and index == 1:
        trans_b = next((a.i for a in node.attribute if a.name == "transB"), 0)
        return 0 if trans_b else 1                             # [out, in] or [in, out]
    if node.op_type == "Gather" and index == 0:
        axis = next((a.i for a in node.attribute if a.name == "axis"), 0)
        return axis                                            # one scale per row looked up
    if node.op_type == "Conv" and index == 1:
        return 0                                               # [out, in/groups, *kernel]
    return None


def quantize_weight(w: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """float32 `w` -> (int8 q, float32 scale broadcastable to w) with w ~= q * scale, symmetric per channel along
    `axis`. A channel of zeros gets scale 1 (q = 0 there)."""
    axis = axis % w.ndim
    reduce = tuple(a for a in range(w.ndim) if a != axis)
    peak = np.abs(w).max(axis=reduce, keepdims=True).astype(np.float32)
    scale = np.where(peak > 0, peak / np.float32(127), np.float32(1)).astype(np.float32)
    q = np.clip(np.rint(w / scale), -127, 127).astype(np.int8)
    return q, scale


def quantize_weights(model: onnx.ModelProto, min_elements: int = WEIGHT_INT8_MIN_ELEMENTS) -> onnx.ModelProto:
    """A copy of `model` whose weights (module docstring) are stored int8 + per-channel scales and dequantized in
    the graph by Cast and Mul. An initializer read by several nodes is quantized only if every reader agrees on
    its channel axis. The model's opset is kept (Cast and Mul exist in every opset)."""
    out = onnx.ModelProto()
    out.CopyFrom(model)
    g = out.graph
    inits = {t.name: t for t in g.initializer}
    axes = defaultdict(set)
    for n in g.node:
        for i, name in enumerate(n.input):
            if name in inits:
                axes[name].add(_channel_axis(n, i))
    taken = {t.name for t in g.initializer} | {o for n in g.node for o in n.output} | {i.name for i in g.input}
    kept, added, dequantize = [], [], []
    for t in g.initializer:
        w = numpy_helper.to_array(t)
        readers = axes.get(t.name, set())
        if (t.data_type != TensorProto.FLOAT or w.size < min_elements or len(readers) != 1 or None in readers):
            kept.append(t)
            continue
        q, scale = quantize_weight(w, next(iter(readers)))
        q_name, s_name, f_name = (_fresh(f"{t.name}_{suffix}", taken) for suffix in ("int8", "scale", "float"))
        added += [numpy_helper.from_array(q, q_name), numpy_helper.from_array(scale, s_name)]
        dequantize += [helper.make_node("Cast", [q_name], [f_name], to=TensorProto.FLOAT, name=f"{f_name}_cast"),
                       helper.make_node("Mul", [f_name, s_name], [t.name], name=f"{t.name}_dequantize")]
    del g.initializer[:]
    g.initializer.extend(kept + added)
    nodes = list(g.node)
    del g.node[:]
    g.node.extend(dequantize + nodes)
    onnx.checker.check_model(out, full_check=True)
    return out


def _fresh(name: str, taken: set) -> str:
    while name in taken:
        name += "_"
    taken.add(name)
    return name


def write_compact(src: Path, dst: Path, opset: int = COMPACT_OPSET,
                  min_elements: int = WEIGHT_INT8_MIN_ELEMENTS) -> dict:
    """A bundle graph (the portable step, the text encoder, lookup, decoder) -> its compact form at `dst`: converted
    to `opset`, weights stored int8. Raises RuntimeError if the result is not a graph Unity's Inference Engine
    imports (opset.unity_problems). Returns the quantization options the manifest records."""
    model = quantize_weights(to_opset(onnx.load(str(src)), opset), min_elements)
    problems = unity_problems(model)
    if problems:
        raise RuntimeError(f"{dst.name} cannot be in the compact variant: {'; '.join(problems)}")
    onnx.save(model, str(dst))
    return {"opset": opset, "per_channel": True, "symmetric": True, "min_elements": min_elements}
