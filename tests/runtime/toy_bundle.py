"""A hand-built mogo bundle (onnx.helper graphs, no torch) that follows docs/bundle.md, for the generator tests.

Small and random but honest to the contract: a 2-layer step graph whose logits depend on the text, on every
cached token (through the presents it concatenates) and on the number of steps (END grows likelier), a
codebook lookup, and a causal decoder (receptive field 2) whose output sits around HumanML3D's mean pose, so
joints, BVH and previews look like a person. The int8 variant is `quantize_dynamic` of the step graph.

With `portable=True` the bundle also has the portable variant (docs/bundle.md, "The portable variant"): a step graph
with the same weights over a cache of CAPACITY slots, written at `position`, and every graph at opset 17; with
`ort=True` the int8 and portable variants also in ORT format, with a minimal build's operator list. With
`control=True` the model has control (docs/bundle.md, "Control"): every step graph takes a `control` input, projected
onto layer 0's keys, so a control vector changes the logits of its own position and, through the cache, of every later
one (a rebuilt context must feed each position its own vector again). The default bundle has none of these:
tests/golden/toy.json holds the sha256 of each of its files (tests/golden/toy_control.json: of the control bundle's).
"""
from __future__ import annotations

import copy
import hashlib
import importlib
import json
import sys
import tempfile
import types
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper
from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, processors

from mogo_runtime.bundle.manifest import COMPACT, INT8_FIXED, Manifest
from mogo_runtime.bundle.sampling import SamplingConfig
from mogo_runtime.bundle.sections import (PER_ROW_INT8, PORTABLE_OPSET, WEIGHT_INT8, ControlSpec, GraphFile, GraphSpec,
                                          ModelDims, Normalization, OrtFormat, PortableSpec, Quantization,
                                          StreamingSpec, TensorSpec, TextEncoderSpec, required_capacity)
from mogo_runtime.kinematics.features import FeatureLayout
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.text import TokenizerSettings, configure_tokenizer

WORDS = ["a", "person", "walks", "forward", "waves", "hand", "jumps", "twice", "left", "right", "runs", "sits",
         "down", "turns", "around", "and", "then", "kicks"]
L, K, N_LAYERS, N_HEADS, HEAD_DIM = 2, 16, 2, 1, 4
TEXT_DIM, LATENT, DOWNSAMPLE, RECEPTIVE, FPS, MAX_TOKENS, MAX_LEN = 8, 6, 4, 2, 20.0, 24, 12
D = FeatureLayout.for_skeleton(HUMANML3D).dim
WINDOW, REFRESH = 5, 3   # endless streams: the context is rebuilt every few tokens, so tests see many rebuilds
OPSET, IR = 18, 10   # onnx 1.23 stamps IR 14 by default; onnxruntime 1.31 loads at most IR 13
DIMS = ModelDims(num_levels=L, codebook_size=K, n_layers=N_LAYERS, n_heads=N_HEADS, head_dim=HEAD_DIM,
                 text_dim=TEXT_DIM, max_rel_dist=64, downsample=DOWNSAMPLE, fps=FPS, receptive_field=RECEPTIVE,
                 feature_dim=D, latent_dim=LATENT, max_tokens=MAX_TOKENS)
CAPACITY = required_capacity(DIMS, StreamingSpec(WINDOW, REFRESH))   # the portable step's cache slots
CONTROL = ControlSpec(horizon=2, dim=9)    # control=True: the wanted root of the next 2 tokens
TOY_WEIGHT_INT8_MIN = 16                   # the compact variant: the toy's weights are small; quantize them all


def _model(nodes, name, inputs, outputs, inits, meta, opset: int = OPSET) -> onnx.ModelProto:
    graph = helper.make_graph(nodes, name, inputs, outputs, [numpy_helper.from_array(v, k) for k, v in inits.items()])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)], ir_version=IR)
    helper.set_model_props(model, meta)
    onnx.checker.check_model(model, full_check=True)
    return model


def _vi(name, dtype, shape):
    return helper.make_tensor_value_info(name, TensorProto.FLOAT if dtype == "float32" else TensorProto.INT64, shape)


def _io(specs):
    return [_vi(s["name"], s["dtype"], s["shape"]) for s in specs]


def graph_specs(text_dim: int = TEXT_DIM, control: bool = False) -> dict:
    cache = ["batch", L * N_HEADS, "past", HEAD_DIM]
    present = ["batch", L * N_HEADS, "past_plus_steps", HEAD_DIM]
    step_in = [{"name": "text_embedding", "dtype": "float32", "shape": ["batch", text_dim]},
               {"name": "tokens", "dtype": "int64", "shape": ["batch", "steps", L]}]
    if control:
        step_in.append({"name": "control", "dtype": "float32", "shape": ["batch", "steps", CONTROL.dim]})
    step_out = [{"name": "logits", "dtype": "float32", "shape": ["batch", "steps", L, K + 1]}]
    for i in range(N_LAYERS):
        for kv in ("key", "value"):
            step_in.append({"name": f"past_key_values.{i}.{kv}", "dtype": "float32", "shape": cache})
            step_out.append({"name": f"present.{i}.{kv}", "dtype": "float32", "shape": present})
    return {
        "text_encoder": {"inputs": [{"name": "input_ids", "dtype": "int64", "shape": ["batch", "seq"]},
                                    {"name": "attention_mask", "dtype": "int64", "shape": ["batch", "seq"]}],
                         "outputs": [{"name": "text_embedding", "dtype": "float32", "shape": ["batch", text_dim]}]},
        "step": {"inputs": step_in, "outputs": step_out},
        "lookup": {"inputs": [{"name": "tokens", "dtype": "int64", "shape": ["batch", "tokens", L]}],
                   "outputs": [{"name": "latent", "dtype": "float32", "shape": ["batch", "tokens", LATENT]}]},
        "decoder": {"inputs": [{"name": "latent", "dtype": "float32", "shape": ["batch", "tokens", LATENT]}],
                    "outputs": [{"name": "features", "dtype": "float32", "shape": ["batch", "frames", D]}]},
    }


def portable_step_spec(control: bool = False) -> dict:
    """The portable step's I/O: one time step, [its control,] position, a cache of CAPACITY slots."""
    cache = ["batch", L * N_HEADS, CAPACITY, HEAD_DIM]
    step_in = [{"name": "text_embedding", "dtype": "float32", "shape": ["batch", TEXT_DIM]},
               {"name": "tokens", "dtype": "int64", "shape": ["batch", 1, L]},
               *([{"name": "control", "dtype": "float32", "shape": ["batch", 1, CONTROL.dim]}] if control else []),
               {"name": "position", "dtype": "int64", "shape": ["batch"]}]
    step_out = [{"name": "logits", "dtype": "float32", "shape": ["batch", 1, L, K + 1]}]
    for i in range(N_LAYERS):
        for kv in ("key", "value"):
            step_in.append({"name": f"past_key_values.{i}.{kv}", "dtype": "float32", "shape": cache})
            step_out.append({"name": f"present.{i}.{kv}", "dtype": "float32", "shape": cache})
    return {"inputs": step_in, "outputs": step_out}


def _spec(io: dict) -> GraphSpec:
    return GraphSpec(*(tuple(TensorSpec(d["name"], d["dtype"], tuple(d["shape"])) for d in io[k])
                       for k in ("inputs", "outputs")))


def mean_pool_encoder(table: np.ndarray, max_length: int, name: str = "toy", opset: int = OPSET) -> onnx.ModelProto:
    """text_embedding = l2norm(sum_s table[ids] * mask / sum_s mask), like MiniLM's pooling."""
    nodes = [
        helper.make_node("Gather", ["table", "input_ids"], ["h"]),                     # (N, S, E)
        helper.make_node("Cast", ["attention_mask"], ["m"], to=TensorProto.FLOAT),     # (N, S)
        helper.make_node("Unsqueeze", ["m", "axis_last"], ["m3"]),                    # (N, S, 1)
        helper.make_node("Mul", ["h", "m3"], ["hm"]),
        helper.make_node("ReduceSum", ["hm", "axis_seq"], ["s"], keepdims=0),          # (N, E)
        helper.make_node("ReduceSum", ["m3", "axis_seq"], ["n"], keepdims=0),          # (N, 1)
        helper.make_node("Div", ["s", "n"], ["mean"]),
        # ReduceL2 takes its axes as an input from opset 18, as an attribute before
        helper.make_node("ReduceL2", ["mean", "axis_last"], ["norm"], keepdims=1) if opset >= 18 else
        helper.make_node("ReduceL2", ["mean"], ["norm"], axes=[-1], keepdims=1),
        helper.make_node("Div", ["mean", "norm"], ["text_embedding"]),
    ]
    inits = {"table": table, "axis_last": np.array([-1], np.int64), "axis_seq": np.array([1], np.int64)}
    io = graph_specs(text_dim=table.shape[1])["text_encoder"]
    return _model(nodes, f"{name}_text_encoder", _io(io["inputs"]), _io(io["outputs"]), inits,
                  {"encoder": name, "dim": str(table.shape[1]), "pooling": "mean", "normalized": "true",
                   "max_length": str(max_length)}, opset)


def step(rng, spec, fixed: bool = False, opset: int = OPSET, w_control: np.ndarray | None = None) -> onnx.ModelProto:
    """`fixed`: the portable step, whose cache of CAPACITY slots is written at `position` (ScatterElements) and
    summed over the slots up to it; from an rng in the same state it has the dynamic step's weights. `w_control`
    (CONTROL.dim, HEAD_DIM): the `control` input's projection, added to every level's layer-0 key."""
    nodes, inits = [], {"axis_time": np.array([2], np.int64), "axis_step": np.array([1], np.int64),
                        "half": np.array(0.5, np.float32), "level_logits": np.array([0, L, K + 1], np.int64)}
    if fixed:
        inits.update({"slot_index": np.zeros((1, L * N_HEADS, 1, HEAD_DIM), np.int64), "one": np.array(1, np.int64),
                      "slots": np.arange(CAPACITY, dtype=np.int64), "axes_row": np.array([1, 2, 3], np.int64),
                      "axes_slot": np.array([1, 3], np.int64)})
        nodes += [helper.make_node("Unsqueeze", ["position", "axes_row"], ["position4"]),          # (B, 1, 1, 1)
                  helper.make_node("Add", ["position4", "slot_index"], ["write"]),                 # (B, LH, 1, Dh)
                  helper.make_node("Add", ["position", "one"], ["filled"]),
                  helper.make_node("Unsqueeze", ["filled", "axis_step"], ["filled2"]),             # (B, 1)
                  helper.make_node("Less", ["slots", "filled2"], ["valid_b"]),                     # (B, cap)
                  helper.make_node("Cast", ["valid_b"], ["valid2"], to=TensorProto.FLOAT),
                  helper.make_node("Unsqueeze", ["valid2", "axes_slot"], ["valid"])]               # (B, 1, cap, 1)
    inits["w_text"] = (2.0 * rng.standard_normal((TEXT_DIM, L * (K + 1)))).astype(np.float32)
    nodes += [helper.make_node("MatMul", ["text_embedding", "w_text"], ["zt"]),
              helper.make_node("Reshape", ["zt", "level_logits"], ["z_text"])]       # (B, L, K + 1)
    terms = ["z_text"]
    for i in range(N_LAYERS):
        # small token keys, so that the text keeps steering a long stream (the cache holds up to 9 of them)
        table = (0.3 * rng.standard_normal((K + 3, HEAD_DIM))).astype(np.float32)
        w = (0.7 * rng.standard_normal((HEAD_DIM, K + 1))).astype(np.float32)
        if i == 0:   # channel 0 counts the steps taken: END (column K) grows likelier with every step
            table[:, 0] = 1.0
            w[0, :] = 0.0
            w[0, K] = 0.25
        inits[f"table{i}"], inits[f"w{i}"] = table, w
        controlled = i == 0 and w_control is not None
        nodes += [helper.make_node("Gather", [f"table{i}", "tokens"], [f"tok{i}" if controlled else f"e{i}"])]
        if controlled:   # the control of each position onto its keys: (B, S, C) @ (C, Dh) -> (B, S, 1, Dh)
            inits["w_control"] = w_control
            nodes += [helper.make_node("MatMul", ["control", "w_control"], ["control_key"]),
                      helper.make_node("Unsqueeze", ["control_key", "axis_time"], ["control_key4"]),
                      helper.make_node("Add", [f"tok{i}", "control_key4"], [f"e{i}"])]
        nodes += [
            helper.make_node("Transpose", [f"e{i}"], [f"kv{i}"], perm=[0, 2, 1, 3]),          # (B, L, S, Dh)
            helper.make_node("Mul", [f"kv{i}", "half"], [f"v{i}"])]
        if fixed:
            nodes += [
                helper.make_node("ScatterElements", [f"past_key_values.{i}.key", "write", f"kv{i}"],
                                 [f"present.{i}.key"], axis=2),
                helper.make_node("ScatterElements", [f"past_key_values.{i}.value", "write", f"v{i}"],
                                 [f"present.{i}.value"], axis=2),
                helper.make_node("Mul", [f"present.{i}.key", "valid"], [f"cached{i}"]),           # slots <= position
                helper.make_node("ReduceSum", [f"cached{i}", "axis_time"], [f"h{i}"], keepdims=0)]
        else:
            nodes += [
                helper.make_node("Concat", [f"past_key_values.{i}.key", f"kv{i}"], [f"present.{i}.key"], axis=2),
                helper.make_node("Concat", [f"past_key_values.{i}.value", f"v{i}"], [f"present.{i}.value"], axis=2),
                helper.make_node("ReduceSum", [f"present.{i}.key", "axis_time"], [f"h{i}"], keepdims=0)]
        nodes += [helper.make_node("MatMul", [f"h{i}", f"w{i}"], [f"z{i}"])]                 # (B, L, K + 1)
        terms.append(f"z{i}")
    nodes += [helper.make_node("Sum", terms, ["z"]),
              helper.make_node("Unsqueeze", ["z", "axis_step"], ["logits"])]                # (B, 1, L, K + 1)
    return _model(nodes, "toy_step", _io(spec["inputs"]), _io(spec["outputs"]), inits, {"graph": "step"}, opset)


def lookup(rng, spec, opset: int = OPSET) -> onnx.ModelProto:
    inits = {"codes": rng.standard_normal((L * K, LATENT)).astype(np.float32),
             "level_offset": (np.arange(L) * K).astype(np.int64), "axis_level": np.array([2], np.int64)}
    nodes = [helper.make_node("Add", ["tokens", "level_offset"], ["flat"]),
             helper.make_node("Gather", ["codes", "flat"], ["per_level"]),                   # (B, T, L, C)
             helper.make_node("ReduceSum", ["per_level", "axis_level"], ["latent"], keepdims=0)]
    return _model(nodes, "toy_lookup", _io(spec["inputs"]), _io(spec["outputs"]), inits, {"graph": "lookup"}, opset)


def _noise_scale() -> np.ndarray:
    """(D,) how far the toy decoder strays from the mean pose: the root moves freely, the body stays near
    rigid (bone lengths vary by millimetres), so BVH files of toy motions reproduce them closely."""
    scale = np.full(D, 0.002)
    scale[:3] = 0.02                        # root yaw velocity and xz velocity (height stays near the mean)
    return scale


def decoder_weights(rng, mean: np.ndarray) -> dict:
    return {"conv": (0.5 * rng.standard_normal((LATENT, LATENT, RECEPTIVE + 1))).astype(np.float32),
            "w_out": (rng.standard_normal((LATENT, DOWNSAMPLE, D)) * _noise_scale()).reshape(LATENT, -1)
            .astype(np.float32),
            "bias": np.tile(mean.astype(np.float32), DOWNSAMPLE),
            "frames_shape": np.array([0, -1, D], np.int64)}


def _features(y: str) -> list:
    """tanh(y) (B, T, C) -> features (B, T * ds, D), around the mean pose."""
    return [helper.make_node("MatMul", [y, "w_out"], ["o"]),
            helper.make_node("Add", ["o", "bias"], ["ob"]),                                  # (B, T, ds * D)
            helper.make_node("Reshape", ["ob", "frames_shape"], ["features"])]               # (B, T * ds, D)


def decoder(weights: dict, spec, opset: int = OPSET) -> onnx.ModelProto:
    inits = {"pads": np.array([0, 0, RECEPTIVE, 0, 0, 0], np.int64), **weights}
    nodes = [helper.make_node("Transpose", ["latent"], ["x"], perm=[0, 2, 1]),                # (B, C, T)
             helper.make_node("Pad", ["x", "pads"], ["xp"]),                                  # causal: left only
             helper.make_node("Conv", ["xp", "conv"], ["y"]),                                 # (B, C, T)
             helper.make_node("Tanh", ["y"], ["ya"]),
             helper.make_node("Transpose", ["ya"], ["yt"], perm=[0, 2, 1]),                   # (B, T, C)
             *_features("yt")]
    return _model(nodes, "toy_decoder", _io(spec["inputs"]), _io(spec["outputs"]), inits, {"graph": "decoder"},
                  opset)


def decoder_step(weights: dict, opset: int = OPSET) -> onnx.ModelProto:
    """The toy decoder with its state explicit (docs/bundle.md, decoder_step): the last RECEPTIVE latents. Its conv
    is one MatMul over the taps side by side, as the exporter's (so a token's frames are the same bits at any chunk)."""
    taps = weights["conv"].transpose(2, 1, 0).reshape((RECEPTIVE + 1) * LATENT, LATENT)      # [k * in, out]
    inits = {"state_start": np.array([-RECEPTIVE], np.int64), "end": np.array([2 ** 62], np.int64),
             "time_axis": np.array([1], np.int64), "taps": np.ascontiguousarray(taps),
             **{f"tap_{j}": np.array([j], np.int64) for j in range(RECEPTIVE + 1)},
             **{f"tap_end_{j}": np.array([j - RECEPTIVE], np.int64) for j in range(RECEPTIVE)},
             **{k: v for k, v in weights.items() if k != "conv"}}
    nodes = [helper.make_node("Concat", ["decoder_state.0", "latent"], ["seen"], axis=1),     # (B, R + T, C)
             helper.make_node("Slice", ["seen", "state_start", "end", "time_axis"], ["next_decoder_state.0"]),
             *(helper.make_node("Slice", ["seen", f"tap_{j}", f"tap_end_{j}" if j < RECEPTIVE else "end", "time_axis"],
                                [f"x{j}"]) for j in range(RECEPTIVE + 1)),                   # (B, T, C) each
             helper.make_node("Concat", [f"x{j}" for j in range(RECEPTIVE + 1)], ["x"], axis=2),
             helper.make_node("MatMul", ["x", "taps"], ["y"]),                                # (B, T, C)
             helper.make_node("Tanh", ["y"], ["ya"]),
             *_features("ya")]
    spec = decoder_step_spec()
    return _model(nodes, "toy_decoder_step", _io(spec["inputs"]), _io(spec["outputs"]), inits,
                  {"graph": "decoder_step"}, opset)


def decoder_step_spec() -> dict:
    state = {"dtype": "float32", "shape": ["batch", RECEPTIVE, LATENT]}
    return {"inputs": [{"name": "latent", "dtype": "float32", "shape": ["batch", "tokens", LATENT]},
                       {"name": "decoder_state.0", **state}],
            "outputs": [{"name": "features", "dtype": "float32", "shape": ["batch", "frames", D]},
                        {"name": "next_decoder_state.0", **state}]}


def word_tokenizer(words: list[str]) -> Tokenizer:
    """A WordLevel tokenizer over `words` with BERT's special tokens, not yet configured (no truncation)."""
    vocab = {"[PAD]": 0, "[UNK]": 1, "[CLS]": 2, "[SEP]": 3, **{w: i + 4 for i, w in enumerate(words)}}
    tok = Tokenizer(models.WordLevel(vocab, unk_token="[UNK]"))
    tok.normalizer = normalizers.Lowercase()
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    tok.post_processor = processors.TemplateProcessing(single="[CLS] $A [SEP]",
                                                       special_tokens=[("[CLS]", 2), ("[SEP]", 3)])
    return tok


def to_ort(folder: Path, variants: dict, names: list[str]) -> OrtFormat:
    """Variants `names` also in ORT format as `<name>_ort`, as mogo_export/export/ort_format.py writes them (that
    module imports onnxruntime.tools, which imports torch where it is installed: not in the runtime's tests).
    The operator list is read from the same optimized graphs saved as ONNX, by the opsets they import."""
    import onnxruntime as ort

    converted, ops = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for v in names:
            for entry in variants[v].values():
                if entry.file in converted:
                    continue
                converted[entry.file] = folder / (Path(entry.file).stem + ".ort")
                for target, fmt in ((converted[entry.file], "ORT"), (Path(tmp) / entry.file, "ONNX")):
                    so = ort.SessionOptions()
                    so.optimized_model_filepath = str(target)
                    so.add_session_config_entry("session.save_model_format", fmt)
                    ort.InferenceSession(str(folder / entry.file), so, providers=["CPUExecutionProvider"],
                                         disabled_optimizers=["NchwcTransformer"])
                optimized = onnx.load(str(Path(tmp) / entry.file))
                opsets = {o.domain or "ai.onnx": o.version for o in optimized.opset_import}
                for n in optimized.graph.node:
                    ops.setdefault((n.domain or "ai.onnx", opsets[n.domain or "ai.onnx"]), set()).add(n.op_type)
            variants[f"{v}_ort"] = {g: GraphFile(converted[e.file].name, e.quantization)
                                    for g, e in variants[v].items()}
    lines = ["# Generated from model/s:", *(f"# - {p.name}" for p in sorted(converted.values())),
             *(f"{d};{o};{','.join(sorted(names))}" for (d, o), names in sorted(ops.items()))]
    (folder / "required_operators.config").write_text("\n".join(lines) + "\n")
    return OrtFormat("required_operators.config", {f"{v}_ort": v for v in names}, ort.__version__)


def _exporter_module(name: str):
    """mogo_export/export/<name>.py loaded by path: graph rewrites that need only onnx and numpy. The runtime's
    tests block importing mogo_export (the runtime must never need it); building a test bundle is export work. The
    folder is loaded as a package of its own (not mogo_export.export), so a module's relative imports resolve."""
    if _EXPORTER_PACKAGE not in sys.modules:
        package = types.ModuleType(_EXPORTER_PACKAGE)
        package.__path__ = [str(Path(__file__).resolve().parents[2] / "mogo_export" / "export")]
        sys.modules[_EXPORTER_PACKAGE] = package
    return importlib.import_module(f"{_EXPORTER_PACKAGE}.{name}")


_EXPORTER_PACKAGE = "_toy_exporter"


def control_weights(seed: int) -> np.ndarray:
    """(CONTROL.dim, HEAD_DIM): the control's projection, from a generator of its own (the other weights are
    drawn as without control). Channel 0 of the keys counts the steps (END's growth): the control leaves it alone."""
    w = (0.5 * np.random.default_rng([seed, 26]).standard_normal((CONTROL.dim, HEAD_DIM))).astype(np.float32)
    w[:, 0] = 0.0
    return w


def build_toy_bundle(out: Path, mean: np.ndarray, seed: int = 0, int8: bool = True, streaming: bool = True,
                     portable: bool = False, ort: bool = False, control: bool = False,
                     with_decoder_step: bool | None = None) -> Path:
    """Write a complete bundle to `out` (graphs, tokenizer.json, manifest.json with sizes and hashes).
    `with_decoder_step`: the decoder_step graph too (default: with the portable variant, as the exporter writes)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    specs = graph_specs(control=control)
    w_control = control_weights(seed) if control else None
    opset = PORTABLE_OPSET if portable else OPSET      # every graph of the portable variant at its opset
    table = rng.standard_normal((len(WORDS) + 4, TEXT_DIM)).astype(np.float32)
    onnx.save(mean_pool_encoder(table, MAX_LEN, opset=opset), out / "text_encoder.onnx")
    step_rng = copy.deepcopy(rng)                      # the portable step: the same weights
    onnx.save(step(rng, specs["step"], opset=opset, w_control=w_control), out / "step.onnx")
    onnx.save(lookup(rng, specs["lookup"], opset), out / "lookup.onnx")
    weights = decoder_weights(rng, mean)
    onnx.save(decoder(weights, specs["decoder"], opset), out / "decoder.onnx")
    if portable if with_decoder_step is None else with_decoder_step:
        specs["decoder_step"] = decoder_step_spec()
        onnx.save(decoder_step(weights, opset), out / "decoder_step.onnx")
    configure_tokenizer(word_tokenizer(WORDS), TokenizerSettings(max_length=MAX_LEN)).save(str(out / "tokenizer.json"))
    fp32 = {g: GraphFile(f"{g}.onnx") for g in specs}
    variants = {"fp32": fp32}
    if int8:
        quantize_dynamic(str(out / "step.onnx"), str(out / "step.int8.onnx"), weight_type=QuantType.QInt8)
        variants["int8"] = {**fp32, "step": GraphFile("step.int8.onnx", Quantization("dynamic", {"weight_type": "QInt8"}))}
    if portable:
        onnx.save(step(step_rng, portable_step_spec(control), fixed=True, opset=opset, w_control=w_control),
                  out / "step.portable.onnx")
        variants["portable"] = {**fp32, "step": GraphFile("step.portable.onnx")}
        if int8:   # the per-row int8 portable step
            quantize_per_row = _exporter_module("rowquant").quantize_per_row
            quantize_dynamic(str(out / "step.portable.onnx"), str(out / "step.portable.int8.onnx"),
                             weight_type=QuantType.QInt8)
            onnx.save(quantize_per_row(onnx.load(out / "step.portable.int8.onnx")), out / "step.portable.int8.onnx")
            variants[INT8_FIXED] = {**fp32, "step": GraphFile("step.portable.int8.onnx", Quantization(PER_ROW_INT8, {}))}
        # the compact variant as the exporter writes it; the toy's weights are small, so every weight is quantized
        write_compact = _exporter_module("weightquant").write_compact
        variants[COMPACT] = {}
        for g, e in variants["portable"].items():
            options = write_compact(out / e.file, out / f"{g}.compact.onnx", min_elements=TOY_WEIGHT_INT8_MIN)
            variants[COMPACT][g] = GraphFile(f"{g}.compact.onnx", Quantization(WEIGHT_INT8, options))
    ort_format = to_ort(out, variants, [v for v in ("int8", "portable") if v in variants]) if ort else None
    files = {p.name: (p.stat().st_size, hashlib.sha256(p.read_bytes()).hexdigest())
             for p in sorted(out.iterdir()) if p.is_file() and p.name != "manifest.json"}
    manifest = Manifest(
        producer={"name": "tests/runtime/toy_bundle.py", "onnx": onnx.__version__, "opset": opset},
        model=DIMS, skeleton=HUMANML3D,
        normalization=Normalization(mean=tuple(float(x) for x in mean), std=(1.0,) * D),
        text_encoder=TextEncoderSpec(name="toy", tokenizer="tokenizer.json", max_length=MAX_LEN),
        sampling_defaults=SamplingConfig(temperature=1.0, top_p=0.95),
        graphs={g: _spec(io) for g, io in specs.items()}, variants=variants, files=files,
        streaming=StreamingSpec(window=WINDOW, refresh=REFRESH) if streaming else None,
        portable=PortableSpec(CAPACITY, opset, _spec(portable_step_spec(control))) if portable else None,
        ort=ort_format, control=CONTROL if control else None)
    manifest = manifest.to_dict()
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return out


@pytest.fixture(scope="session")
def toy_bundle(tmp_path_factory, humanml3d_fixture) -> Path:
    """Path of a freshly built toy bundle (about 0.2 s); import this fixture into a test module to use it."""
    return build_toy_bundle(tmp_path_factory.mktemp("toy_bundle"), np.load(humanml3d_fixture / "Mean.npy"))


@pytest.fixture(scope="session")
def portable_toy_bundle(tmp_path_factory, humanml3d_fixture) -> Path:
    """The toy bundle with the portable variant and the ORT-format variants int8_ort and portable_ort."""
    return build_toy_bundle(tmp_path_factory.mktemp("portable_toy_bundle"), np.load(humanml3d_fixture / "Mean.npy"),
                            portable=True, ort=True)


@pytest.fixture(scope="session")
def control_toy_bundle(tmp_path_factory, humanml3d_fixture) -> Path:
    """The toy bundle whose model has control, with the portable variant (tests/golden/toy_control.json)."""
    return build_toy_bundle(tmp_path_factory.mktemp("control_toy_bundle"), np.load(humanml3d_fixture / "Mean.npy"),
                            portable=True, control=True)


if __name__ == "__main__":   # js/test/run.sh and web/test/run.sh: python tests/runtime/toy_bundle.py OUT [--seed N] [--clips]
    import argparse

    ap = argparse.ArgumentParser(description="build the toy bundle (the HumanML3D fixture's Mean.npy beside the repo)")
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--clips", action="store_true", help="no streaming section: a bundle of single clips")
    ap.add_argument("--control", action="store_true", help="a model with control, and the portable variant")
    args = ap.parse_args()
    mean = np.load(Path(__file__).resolve().parents[3] / "shared" / "fixtures" / "humanml3d" / "Mean.npy")
    build_toy_bundle(args.out, mean, seed=args.seed, streaming=not args.clips, portable=args.control,
                     control=args.control)
    print(f"toy bundle built in {args.out}")
