"""One exporter per ONNX graph of the bundle: step (transformer + KV cache), lookup (tokens -> latent), decoder,
decoder_step (the decoder a few tokens at a time, its causal state explicit).

Each function's docstring lists the graph's inputs and outputs; docs/bundle.md is the full contract. All use
`torch.onnx.export(..., dynamo=True)` and then check the saved file: `onnx.checker` with full_check (a colliding
name once exported fine and failed to load), symbolic dims really symbolic (a dim traced at size 0 or 1 is
silently fixed, so we trace at sizes >= 2), only the default operator domain, no If/Loop nodes.
"""
from __future__ import annotations

import contextlib
import io
import warnings
from pathlib import Path

import onnx
import torch
import torch.nn as nn
from torch.export import Dim

from ..models.transformer import RQHCTransformer
from ..models.vq import CausalConv1d, MoSAVQ, ResBlock, Upsample
from .opset import TORCH_MIN_OPSET, default_opset, to_opset

DEFAULT_OPSET = 20
_DTYPES = {onnx.TensorProto.FLOAT: "float32", onnx.TensorProto.INT64: "int64", onnx.TensorProto.FLOAT16: "float16"}


class StepGraph(nn.Module):
    """The transformer's `step`, with caches laid out per prompt: [batch, L * n_heads, past, head_dim].

    Inside the model the L level streams are rows b*L + l; folding them into the head axis keeps `batch` the one
    batch dim a consumer sees. The model concatenates in this layout, so each `present` is a Concat's output
    (no copy after it) and attention reads it through a reshape.
    """

    def __init__(self, model: RQHCTransformer):
        super().__init__()
        self.model = model

    def forward(self, text_embedding, tokens, *inputs):
        control, past_flat = (inputs[0], inputs[1:]) if self.model.cfg.control_dim else (None, inputs)
        past = [(past_flat[2 * i], past_flat[2 * i + 1]) for i in range(len(past_flat) // 2)]
        logits, presents = self.model.step(text_embedding, tokens, past, control)
        return (logits, *(t for kv in presents for t in kv))


class LookupGraph(nn.Module):
    def __init__(self, vq: MoSAVQ):
        super().__init__()
        self.quantizer = vq.quantizer

    def forward(self, tokens):
        return self.quantizer.lookup(tokens)


class DecoderGraph(nn.Module):
    """The causal decoder with de-normalisation folded in, so its output is HumanML3D features as they are."""

    def __init__(self, vq: MoSAVQ, mean, std):
        super().__init__()
        self.decoder = vq.decoder
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(std, dtype=torch.float32))

    def forward(self, latent):
        return self.decoder(latent) * self.std + self.mean


class DecoderStepGraph(nn.Module):
    """The causal decoder over the tokens that are new, its state explicit: what each causal conv must still see
    of its input (the last `reach` steps), time-major [batch, reach, channels], zeros at a motion's start (the
    left padding of the whole-clip decode). Frames equal the whole-clip decoder's within float32 rounding.

    Each conv runs as one MatMul over every row and new step (taps side by side), not as a Conv: onnxruntime's Conv
    loops over the batch, so a crowd's 256 one-token rows cost as much as 256 calls (on base, 156 us a row as a
    Conv, 33 us as a MatMul; the stateless decoder over a 17-token window: 780 us, benchmarks/NOTES.md).
    """

    def __init__(self, vq: MoSAVQ, mean, std):
        super().__init__()
        self.layers = list(vq.decoder.net)
        self.convs = [m.conv1 if isinstance(m, ResBlock) else m for m in self.layers
                      if isinstance(m, (ResBlock, CausalConv1d))]
        for i, m in enumerate(self.convs):    # [k * in, out], tap-major: the rows of the taps side by side
            k, c_in, c_out = m.kernel_size[0], m.in_channels, m.out_channels
            self.register_buffer(f"w{i}", m.weight.detach().permute(2, 1, 0).reshape(k * c_in, c_out).clone())
            self.register_buffer(f"b{i}", m.bias.detach().clone())
        self.pointwise = [m.conv2 for m in self.layers if isinstance(m, ResBlock)]
        for i, m in enumerate(self.pointwise):
            self.register_buffer(f"p{i}", m.weight.detach()[:, :, 0].T.clone())
            self.register_buffer(f"pb{i}", m.bias.detach().clone())
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(std, dtype=torch.float32))

    @property
    def state_shapes(self) -> list[tuple[int, int]]:
        """[reach, channels] of each state, in input order."""
        return [(m.reach, m.in_channels) for m in self.convs]

    def forward(self, latent, *state):   # latent [batch, tokens, code_dim]
        x, nxt, convs, points = latent, [], iter(range(len(self.convs))), iter(range(len(self.pointwise)))

        def conv(x):
            i = next(convs)
            m = self.convs[i]
            seen = torch.cat([state[i], x], 1)                                   # [batch, reach + t, in]
            nxt.append(seen[:, seen.shape[1] - m.reach:])
            d, t = m.dilation[0], x.shape[1]
            taps = torch.cat([seen[:, j * d: j * d + t] for j in range(m.kernel_size[0])], 2)   # [batch, t, k * in]
            return taps @ getattr(self, f"w{i}") + getattr(self, f"b{i}")

        for layer in self.layers:
            if isinstance(layer, CausalConv1d):
                x = conv(x)
            elif isinstance(layer, nn.ReLU):
                x = torch.relu(x)
            elif isinstance(layer, ResBlock):
                i = next(points)
                x = x + torch.relu(conv(torch.relu(x))) @ getattr(self, f"p{i}") + getattr(self, f"pb{i}")
            elif isinstance(layer, Upsample):
                x = x.unsqueeze(2).expand(-1, -1, layer.factor, -1).flatten(1, 2)
            else:
                raise TypeError(f"the decoder step has no rule for {type(layer).__name__}")
        return (x * self.std + self.mean, *nxt)


def io_spec(model: onnx.ModelProto) -> dict:
    """Inputs/outputs of a saved graph: name, dtype, shape with symbolic dims as strings."""
    def one(v):
        t = v.type.tensor_type
        dims = [d.dim_param if d.dim_param else d.dim_value for d in t.shape.dim]
        return {"name": v.name, "dtype": _DTYPES.get(t.elem_type, str(t.elem_type)), "shape": dims}
    return {"inputs": [one(v) for v in model.graph.input], "outputs": [one(v) for v in model.graph.output]}


def check_graph(path: Path, expected: dict[str, list]) -> dict:
    """Validate a saved graph; `expected` maps each input/output name to its intended shape (str = symbolic)."""
    model = onnx.load(str(path))
    onnx.checker.check_model(model, full_check=True)
    spec = io_spec(model)
    got = {v["name"]: v["shape"] for v in spec["inputs"] + spec["outputs"]}
    for name, shape in expected.items():
        if name not in got:
            raise RuntimeError(f"{path.name}: expected graph input/output {name!r}, graph has {sorted(got)}")
        if len(got[name]) != len(shape) or any(
                isinstance(want, str) != isinstance(have, str) or (not isinstance(want, str) and want != have)
                for want, have in zip(shape, got[name])):
            raise RuntimeError(f"{path.name}: {name!r} has shape {got[name]}, expected {shape} "
                               "(a dynamic dim traced at size 0/1 becomes static)")
    domains = {n.domain for n in model.graph.node} - {"", "ai.onnx"}
    if domains:
        raise RuntimeError(f"{path.name}: uses non-standard operator domains {sorted(domains)}")
    control = {n.op_type for n in model.graph.node} & {"If", "Loop", "Scan"}
    if control:
        raise RuntimeError(f"{path.name}: contains control-flow nodes {sorted(control)}")
    return spec


def export_module(module: nn.Module, args: tuple, path: Path, input_names, output_names, dynamic_shapes,
                  opset: int, metadata: dict) -> None:
    """Below opset 18 torch would convert, fail, and silently keep 18: we export at 18 and convert (opset.py)."""
    module.eval()
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        program = torch.onnx.export(module, args, dynamo=True, input_names=input_names, output_names=output_names,
                                    dynamic_shapes=dynamic_shapes, opset_version=max(opset, TORCH_MIN_OPSET),
                                    external_data=False, optimize=True, verbose=False)
    model = to_opset(program.model_proto, opset)
    if default_opset(model) != opset:
        raise RuntimeError(f"{path.name}: exported at opset {default_opset(model)}, asked for {opset}")
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, str(value)
    onnx.save_model(model, str(path))


def export_step(model: RQHCTransformer, path: Path, opset: int = DEFAULT_OPSET, metadata: dict | None = None) -> dict:
    """step.onnx. Inputs: text_embedding float32 [batch, text_dim]; tokens int64 [batch, steps, L]; with control,
    control float32 [batch, steps, control_dim]; past_key_values.{i}.key/.value float32 [batch, L*n_heads, past,
    head_dim]. Outputs: logits float32 [batch, steps, L, K+1]; present.{i}.key/.value float32 [batch, L*n_heads,
    past+steps, head_dim]."""
    c = model.cfg
    L, H, hd = c.num_levels, c.n_heads, c.d_model // c.n_heads
    B, S, P = 2, 3, 4  # every dynamic size >= 2 at trace time
    g = torch.Generator().manual_seed(0)
    text = torch.randn(B, c.text_dim, generator=g)
    tokens = torch.randint(0, c.codebook_size, (B, S, L), generator=g)
    past = [torch.randn(B, L * H, P, hd, generator=g) for _ in range(2 * c.n_layers)]
    control = [torch.randn(B, S, c.control_dim, generator=g)] if c.control_dim else []
    names_in = ["text_embedding", "tokens"] + (["control"] if control else [])
    names_out = ["logits"]
    for i in range(c.n_layers):
        names_in += [f"past_key_values.{i}.key", f"past_key_values.{i}.value"]
        names_out += [f"present.{i}.key", f"present.{i}.value"]
    batch, steps, plen = Dim("batch", min=1, max=1024), Dim("steps", min=1, max=4096), Dim("past", min=0, max=8192)
    # forward(text_embedding, tokens, *inputs): the varargs' shapes go as one tuple, the control first
    dyn = ({0: batch}, {0: batch, 1: steps},
           (({0: batch, 1: steps},) if control else ()) + tuple({0: batch, 2: plen} for _ in past))
    export_module(StepGraph(model), (text, tokens, *control, *past), path, names_in, names_out, dyn, opset,
                  metadata or {})
    expected = {"text_embedding": ["batch", c.text_dim], "tokens": ["batch", "steps", L],
                **({"control": ["batch", "steps", c.control_dim]} if control else {}),
                "logits": ["batch", "steps", L, c.codebook_size + 1]}
    for i in range(c.n_layers):
        for kv in ("key", "value"):
            expected[f"past_key_values.{i}.{kv}"] = ["batch", L * H, "past", hd]
            expected[f"present.{i}.{kv}"] = ["batch", L * H, "present", hd]
    return check_graph(path, _rename_present(path, expected))


def _rename_present(path: Path, expected: dict) -> dict:
    """The exporter names the present length after its expression (e.g. 'past + steps'); accept any symbol."""
    return {k: ([d if d != "present" else "any" for d in v]) for k, v in expected.items()}


def export_lookup(vq: MoSAVQ, path: Path, opset: int = DEFAULT_OPSET, metadata: dict | None = None) -> dict:
    """lookup.onnx. Input: tokens int64 [batch, tokens, L]. Output: latent float32 [batch, tokens, latent_dim]."""
    c = vq.cfg
    tokens = torch.randint(0, c.codebook_size, (2, 3, c.num_levels), generator=torch.Generator().manual_seed(0))
    dyn = ({0: Dim("batch", min=1, max=1024), 1: Dim("tokens", min=1, max=8192)},)
    export_module(LookupGraph(vq), (tokens,), path, ["tokens"], ["latent"], dyn, opset, metadata or {})
    return check_graph(path, {"tokens": ["batch", "tokens", c.num_levels], "latent": ["batch", "tokens", c.code_dim]})


def export_decoder(vq: MoSAVQ, mean, std, path: Path, opset: int = DEFAULT_OPSET, metadata: dict | None = None) -> dict:
    """decoder.onnx. Input: latent float32 [batch, tokens, latent_dim]. Output: features float32
    [batch, frames, feature_dim], de-normalised; frames = tokens * downsample."""
    c = vq.cfg
    latent = torch.randn(2, 3, c.code_dim, generator=torch.Generator().manual_seed(0))
    dyn = ({0: Dim("batch", min=1, max=1024), 1: Dim("tokens", min=1, max=8192)},)
    export_module(DecoderGraph(vq, mean, std), (latent,), path, ["latent"], ["features"], dyn, opset, metadata or {})
    return check_graph(path, {"latent": ["batch", "tokens", c.code_dim], "features": ["batch", "any", c.input_dim]})


def export_decoder_step(vq: MoSAVQ, mean, std, path: Path, opset: int = DEFAULT_OPSET,
                        metadata: dict | None = None) -> dict:
    """decoder_step.onnx. Inputs: latent float32 [batch, tokens, latent_dim]; decoder_state.{i} float32 [batch,
    reach_i, channels_i]. Outputs: features float32 [batch, frames, feature_dim], de-normalised, frames = tokens *
    downsample; next_decoder_state.{i}, the same shapes as the inputs."""
    c = vq.cfg
    module = DecoderStepGraph(vq, mean, std)
    g = torch.Generator().manual_seed(0)
    latent = torch.randn(2, 3, c.code_dim, generator=g)
    state = [torch.randn(2, r, ch, generator=g) for r, ch in module.state_shapes]
    names_in = ["latent"] + [f"decoder_state.{i}" for i in range(len(state))]
    names_out = ["features"] + [f"next_decoder_state.{i}" for i in range(len(state))]
    batch = Dim("batch", min=1, max=1024)
    dyn = ({0: batch, 1: Dim("tokens", min=1, max=8192)}, tuple({0: batch} for _ in state))
    export_module(module, (latent, *state), path, names_in, names_out, dyn, opset, metadata or {})
    expected = {"latent": ["batch", "tokens", c.code_dim], "features": ["batch", "any", c.input_dim]}
    for i, (r, ch) in enumerate(module.state_shapes):
        expected[f"decoder_state.{i}"] = expected[f"next_decoder_state.{i}"] = ["batch", r, ch]
    return check_graph(path, expected)
