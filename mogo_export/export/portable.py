"""The portable variant's step graph: the transformer over a KV cache of fixed capacity (docs/bundle.md, "The
portable variant"). The rules every portable graph meets, and opsets below 17, are in opset.py.

    export_portable_step(transformer, "bundle/step.portable.onnx", capacity=63)

Why a second step graph: Unity Sentis imports no DynamicQuantizeLinear/MatMulInteger and older versions accept
opsets 7-15 only; onnxruntime-web's WebGPU graph capture and Triton's implicit state want tensors whose shapes never
change between calls. So the cache is one buffer of `capacity` slots that the graph writes at `position` and hands
back whole (the sherpa-onnx whisper decoder's pattern):

    text_embedding  float32 [batch, text_dim]
    tokens          int64   [batch, 1, L]           one time step per call
    control         float32 [batch, 1, control_dim] (a model with control only: mogo_runtime/control)
    position        int64   [batch]                 the slot this step writes = steps already cached
    past_key_values.{i}.key/.value  float32 [batch, L*n_heads, capacity, head_dim]
 -> logits          float32 [batch, 1, L, K+1]
    present.{i}.key/.value          float32 [batch, L*n_heads, capacity, head_dim]

Slots after `position` are masked out of attention; they only need to hold finite numbers (zeros at the start).
Besides `batch`, every dim is a number. Inside, the graph avoids what would pin a newer opset or a dynamic shape:
no Shape (attention runs in the cache's own [batch, L*n_heads, ...] layout, where a position broadcasts over
heads), no Split (the qkv projection is sliced), relative positions by a one-hot MatMul (exact: one term is
non-zero) instead of a GatherElements whose index would have to be expanded to the batch. The new key and value
go in with ScatterND, each (row, head) a slice of head_dim numbers (`scatter_nd_writes`): with the cache bound as
both past and present (mogo_runtime/engine.py) nothing else of it is touched. torch exports ScatterElements, which
onnxruntime runs element by element: 5.5 ms per cache array at batch 256 on base, 58% of the crowd's step, against
0.08 ms for ScatterND (a Where over the whole cache was slower still). A position past the capacity is an error
either way, never a write to nowhere.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import onnx
import torch
import torch.nn as nn
from torch.export import Dim

from mogo_runtime.bundle.sections import PORTABLE_OPSET

from onnx import helper, numpy_helper

from ..models.transformer import RQHCTransformer
from .graphs import check_graph, export_module


class FixedCacheStepGraph(nn.Module):
    """`RQHCTransformer.step` for one time step, over a cache of `capacity` slots per layer (same weights).

    Equal to the dynamic step with past = the first `position` slots (tests/export/test_portable.py); only the
    softmax's sum runs over the masked slots too (exact zeros), which moves logits by a few 1e-6 (4e-6 on base).
    """

    def __init__(self, model: RQHCTransformer, capacity: int):
        super().__init__()
        self.model, self.capacity = model, capacity
        c = model.cfg
        self.levels, self.heads, self.head_dim = c.num_levels, c.n_heads, c.d_model // c.n_heads
        self.register_buffer("slots", torch.arange(capacity), persistent=False)
        self.register_buffer("distances", torch.arange(c.max_rel_dist + 1), persistent=False)
        # + position: the scatter index of every (row, head, channel) of the new step, without a Shape op
        self.register_buffer("slot_index", torch.zeros(1, c.num_levels * c.n_heads, 1, self.head_dim,
                                                       dtype=torch.int64), persistent=False)

    def forward(self, text_embedding, tokens, *inputs):
        m, c = self.model, self.model.cfg
        control, position, past_flat = ((inputs[0], inputs[1], inputs[2:]) if c.control_dim
                                        else (None, inputs[0], inputs[1:]))
        L, H, hd, C = self.levels, self.heads, self.head_dim, c.d_model
        LH = L * H
        x = self._inputs(text_embedding, tokens, control)                         # (B, L, C)
        write = position[:, None, None, None] + self.slot_index                   # (B, LH, 1, hd)
        dist = (position.unsqueeze(1) - self.slots)[:, None, None, :]             # (B, 1, 1, cap)
        future = dist < 0                                                         # slots not yet written
        # one-hot of the clipped distance of every slot: pos @ onehot^T picks phi's score at that distance
        rel = dist.clamp(0, c.max_rel_dist).transpose(2, 3) == self.distances     # (B, 1, cap, R+1)
        rel = rel.to(x.dtype)
        presents = []
        for i, block in enumerate(m.blocks):
            a = block.attn
            qkv = a.qkv(block.ln_1(x))                                            # (B, L, 3C)
            # rows b*L + l, heads h -> the cache's layout [B, L*H, 1, hd] (row l*H + h), a pure reshape
            q, k, v = (qkv[..., j * C:(j + 1) * C].reshape(-1, LH, 1, hd) for j in range(3))
            present_k = past_flat[2 * i].scatter(2, write, k)                     # (B, LH, cap, hd)
            present_v = past_flat[2 * i + 1].scatter(2, write, v)
            u = a.u.repeat(L, 1).unsqueeze(1)                                     # (LH, 1, hd): head l*H+h -> u[h]
            pv = a.v.repeat(L, 1).unsqueeze(1)
            content = (q + u) @ present_k.transpose(2, 3)                         # (B, LH, 1, cap)
            mask = a.head_mask.view(H, H, hd).repeat(L, 1, 1).unsqueeze(1)        # (LH, 1, H, hd)
            qv = ((q + pv).unsqueeze(3) * mask).flatten(3)                        # (B, LH, 1, C)
            pos_all = qv @ a.phi.t()                                              # (B, LH, 1, R+1)
            pos = pos_all @ rel.transpose(2, 3)                                   # (B, LH, 1, cap)
            att = (content + pos) * (1.0 / math.sqrt(hd))
            att = att.masked_fill(future, float("-inf")).softmax(dim=-1)
            y = (att @ present_v).reshape(-1, L, C)                               # (B, L, C)
            x = x + a.proj(y)
            x = x + block.mlp(block.ln_2(x))
            if m.adapters is not None:
                x = m.adapters[i](x, control)                                     # (B, 1, D) onto (B, L, C)
            presents += [present_k, present_v]
        logits = m.head(m.ln_f(x)).unsqueeze(1)                                   # (B, 1, L, K+1)
        return (logits, *presents)

    def _inputs(self, text_emb, tokens, control):
        """`RQHCTransformer._inputs` for one step, in (B, L, C): stream l of a BOS slot is the PnQ prefix, else
        the sum of the embeddings of levels 0..l; plus the control's projection (B, 1, control_dim) on every level."""
        m, c = self.model, self.model.cfg
        tok = tokens[:, 0]                                                        # (B, L)
        prefix = m.cond_proj(text_emb).unsqueeze(1) + m.q_emb                     # (B, L, C)
        is_bos = (tok == c.bos_id).unsqueeze(-1)                                  # (B, L, 1)
        emb = m.tok_emb(tok + m.level_offset)                                     # (B, L, C)
        x = torch.where(is_bos, prefix, emb.masked_fill(is_bos, 0.0).cumsum(dim=1))
        return x if control is None else x + m.ctrl_proj(control)                 # (B, 1, C) onto (B, L, C)


def export_portable_step(model: RQHCTransformer, path: Path, capacity: int, opset: int = PORTABLE_OPSET,
                         metadata: dict | None = None) -> dict:
    """step.portable.onnx (I/O in the module docstring); returns its I/O description."""
    c = model.cfg
    L, H, hd = c.num_levels, c.n_heads, c.d_model // c.n_heads
    B = 2  # batch is the one dynamic dim: traced at >= 2 (a dim traced at 1 is silently fixed)
    g = torch.Generator().manual_seed(0)
    text = torch.randn(B, c.text_dim, generator=g)
    tokens = torch.randint(0, c.codebook_size, (B, 1, L), generator=g)
    position = torch.tensor([3, 5]) % capacity
    past = [torch.randn(B, L * H, capacity, hd, generator=g) for _ in range(2 * c.n_layers)]
    control = [torch.randn(B, 1, c.control_dim, generator=g)] if c.control_dim else []
    names_in = ["text_embedding", "tokens"] + (["control"] if control else []) + ["position"]
    names_out, fixed = ["logits"], len(names_in)
    for i in range(c.n_layers):
        names_in += [f"past_key_values.{i}.key", f"past_key_values.{i}.value"]
        names_out += [f"present.{i}.key", f"present.{i}.value"]
    batch = Dim("batch", min=1, max=1024)
    dyn = ({0: batch}, {0: batch}, tuple({0: batch} for _ in names_in[2:]))   # forward(text, tokens, *inputs)
    export_module(FixedCacheStepGraph(model, capacity), (text, tokens, *control, position, *past), path, names_in,
                  names_out, dyn, opset, metadata or {})
    onnx.save(scatter_nd_writes(onnx.load(str(path)), L * H, hd), str(path))
    cache = ["batch", L * H, capacity, hd]
    expected = {"text_embedding": ["batch", c.text_dim], "tokens": ["batch", 1, L],
                **({"control": ["batch", 1, c.control_dim]} if control else {}), "position": ["batch"],
                "logits": ["batch", 1, L, c.codebook_size + 1],
                **{name: cache for name in names_in[fixed:] + names_out[1:]}}
    return check_graph(path, expected)


def scatter_nd_writes(model: onnx.ModelProto, heads: int, head_dim: int) -> onnx.ModelProto:
    """Each cache write (ScatterElements on axis 2 of [batch, heads, capacity, head_dim], the same index on every
    channel) as a ScatterND of one [head_dim] slice per (row, head) at (row, head, position); the same numbers in
    the same places. The indices are built from `position` without a Shape op (the row number is a CumSum of ones);
    what fed only the old index is removed."""
    g = model.graph
    writes = [n for n in g.node if n.op_type == "ScatterElements"]
    if not writes or any(next((a.i for a in n.attribute if a.name == "axis"), 0) != 2 for n in writes):
        raise RuntimeError("the portable step's cache writes are not the ScatterElements on axis 2 it was built with")
    consts = {"nd_zero": np.array(0, np.int64), "nd_one": np.array(1, np.int64), "nd_axis0": np.array(0, np.int64),
              "nd_axes12": np.array([1, 2], np.int64), "nd_heads": np.zeros((1, heads, 1), np.int64),
              "nd_head": np.arange(heads, dtype=np.int64).reshape(1, heads, 1),
              "nd_updates_shape": np.array([-1, heads, head_dim], np.int64)}
    made = [helper.make_node("Mul", ["position", "nd_zero"], ["nd_zeros"]),             # [batch] zeros
            helper.make_node("Add", ["nd_zeros", "nd_one"], ["nd_ones"]),
            helper.make_node("CumSum", ["nd_ones", "nd_axis0"], ["nd_counts"]),
            helper.make_node("Sub", ["nd_counts", "nd_one"], ["nd_row"]),                # 0 .. batch - 1
            helper.make_node("Unsqueeze", ["nd_row", "nd_axes12"], ["nd_row3"]),          # [batch, 1, 1]
            helper.make_node("Unsqueeze", ["position", "nd_axes12"], ["nd_pos3"]),
            helper.make_node("Unsqueeze", ["nd_zeros", "nd_axes12"], ["nd_zeros3"]),
            helper.make_node("Add", ["nd_row3", "nd_heads"], ["nd_i0"]),                  # [batch, heads, 1]
            helper.make_node("Add", ["nd_zeros3", "nd_head"], ["nd_i1"]),
            helper.make_node("Add", ["nd_pos3", "nd_heads"], ["nd_i2"]),
            helper.make_node("Concat", ["nd_i0", "nd_i1", "nd_i2"], ["nd_indices"], axis=2)]   # [batch, heads, 3]
    for i, n in enumerate(writes):
        made += [helper.make_node("Reshape", [n.input[2], "nd_updates_shape"], [f"nd_updates_{i}"]),
                 helper.make_node("ScatterND", [n.input[0], "nd_indices", f"nd_updates_{i}"], list(n.output),
                                  name=f"cache_write_{i}")]
    nodes = [n for n in g.node if n.op_type != "ScatterElements"]
    del g.node[:]
    g.node.extend(made[:11] + nodes + made[11:])
    g.initializer.extend(numpy_helper.from_array(v, k) for k, v in consts.items())
    _remove_dead(g)
    onnx.checker.check_model(model, full_check=True)
    return model


def _remove_dead(g: onnx.GraphProto) -> None:
    """Drop the nodes and initializers nothing reads (the old scatter index), and order the nodes topologically."""
    needed = {o.name for o in g.output}
    keep = []
    for n in reversed(g.node):
        if any(o in needed for o in n.output):
            keep.append(n)
            needed.update(n.input)
    known = {i.name for i in g.input} | {t.name for t in g.initializer} | {""}
    ordered, pending = [], list(reversed(keep))
    while pending:
        ready = [n for n in pending if all(i in known for i in n.input)]
        if not ready:
            raise RuntimeError("the portable step has a node whose inputs are never made")
        for n in ready:
            ordered.append(n)
            known.update(n.output)
        done = {id(n) for n in ready}
        pending = [n for n in pending if id(n) not in done]
    del g.node[:]
    g.node.extend(ordered)
    for field, kept in ((g.initializer, [t for t in g.initializer if t.name in needed]),
                        (g.value_info, [v for v in g.value_info if v.name in known])):
        del field[:]
        field.extend(kept)
