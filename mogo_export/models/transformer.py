"""RQHC-Transformer: one causal relative-attention transformer emits all RVQ levels of a step at once (MOGO §2.2)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

from mogo_runtime.bundle.sections import SpecialTokens
from mogo_runtime.control.vector import control_dim

# Tokens: ids 0..K-1 are codes, END = K ends the motion (the head predicts K+1 classes), BOS = K+1 marks
# "the PnQ prefix goes here" (input only), PAD = K+2 pads batches (input only).
#
# Levels as a batch: the L level streams of a sample run as L rows (row b*L + l) of one shared causal
# transformer. Stream l at step j >= 1 reads the sum of the level-0..l embeddings of step j-1 (eq. 8 and the
# `Reduce` of Algorithm 2), at step 0 the prefix cond_proj(text) + q_emb[l] (PnQ, eq. 7). So one forward
# pass predicts the tokens of all L levels of the next step.
#
# Classifier-free guidance: training replaces the text embedding by zeros with probability cond_drop_prob,
# so the all-zero text embedding is the null condition; a sampler runs the unconditional branch with zeros.
#
# Control (a model with control_horizon > 0): each step also reads a control vector, where the root should go over
# the next control_horizon tokens (mogo_runtime/control/vector.py), projected and added to every level stream of
# that step. Training shows a clip's own future root, or all zeros ("no control") with control_drop_prob, and the
# guidance's null text keeps the control: guidance sharpens the action, the control is obeyed in both branches.
#
# Control adapter (adapter_dim > 0): after each block, a bottleneck MLP of the stream and the control vector adds
# to the steps whose control is present (its flag, element 0, times the MLP), trained after the rest with the rest
# frozen (mogo_export/adapter.py). A step without control adds exactly zero, so a text-only stream makes the
# tokens of the model before it bit for bit, while a controlled one learns stops and speeds its caption leaves
# out (data that, trained into the transformer itself, made text-only walks stop unasked: benchmarks/NOTES.md).


@dataclass
class TransformerConfig(SpecialTokens):
    """Defaults are generic; the named sizes (tiny, base, paper) are in mogo_export/presets.py."""

    num_levels: int = 6          # RVQ levels L (must match the VQ)
    codebook_size: int = 512     # codes per level K (must match the VQ)
    text_dim: int = 384          # size of the sentence embedding (all-MiniLM-L6-v2: 384)
    d_model: int = 256           # residual stream width
    n_layers: int = 4            # transformer blocks
    n_heads: int = 4             # attention heads; d_model must be a multiple
    ff_mult: int = 4             # MLP hidden size = ff_mult * d_model
    dropout: float = 0.1         # dropout on attention weights and residual branches (training only)
    max_rel_dist: int = 64       # relative distances are clipped to this; phi has max_rel_dist + 1 rows
    cond_drop_prob: float = 0.1  # chance per training sample to replace the text by the null (zero) text
    control_horizon: int = 0     # tokens of wanted root trajectory per step (mogo_runtime/control); 0: no control
    control_drop_prob: float = 0.5  # chance per training sample to see no control (all zeros: "go as you like")
    adapter_dim: int = 0         # the control adapter's bottleneck width (0: none; needs control_horizon > 0)

    @property
    def vocab_size(self) -> int:  # rows per level of the embedding table
        return self.codebook_size + 3

    @property
    def control_dim(self) -> int:
        return control_dim(self.control_horizon) if self.control_horizon else 0


class RelativeSelfAttention(nn.Module):
    """Causal self-attention with Transformer-XL relative positions (eq. 9) and a KV cache.

    score(i, j) = (q_i + u) . k_j + (q_i + v) . phi[min(i - j, max_rel_dist)], scaled by 1/sqrt(head_dim).
    Query i of a call sits at step P + i where P = past length; key j at step j. Nothing else carries
    position, so the same weights serve any context; endless streams bound theirs by compacting it (prefix + recent
    steps kept as computed, measured before it was made the loop) and now and then rebuilding it (docs/bundle.md).
    """

    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        assert cfg.d_model % cfg.n_heads == 0
        self.n_heads, self.head_dim, self.max_rel_dist = cfg.n_heads, cfg.d_model // cfg.n_heads, cfg.max_rel_dist
        self.qkv = nn.Linear(cfg.d_model, 3 * cfg.d_model)
        self.proj = nn.Linear(cfg.d_model, cfg.d_model)
        self.u = nn.Parameter(torch.zeros(cfg.n_heads, self.head_dim))  # content bias per head
        self.v = nn.Parameter(torch.zeros(cfg.n_heads, self.head_dim))  # position bias per head
        self.phi = nn.Parameter(torch.randn(cfg.max_rel_dist + 1, cfg.d_model) * 0.02)  # learned phi_{i-j}
        # block-diagonal head selector: lets every head score against the 2-D phi with ONE 2-D MatMul
        # (a per-head 3-D view of phi would become a 3-D constant weight, which per-channel int8 cannot run)
        self.register_buffer("head_mask", torch.eye(cfg.n_heads).repeat_interleave(self.head_dim, dim=1),
                             persistent=False)  # (H, d_model)
        self.attn_drop = nn.Dropout(cfg.dropout)
        self.resid_drop = nn.Dropout(cfg.dropout)

    def forward(self, x, past_k, past_v):
        """x (N, S, C); past_k/v (N, H, P, hd) -> y (N, S, C), present k/v (N, H, P+S, hd).

        The cache may also come in any layout (R, N*H/R, P, hd) that folds the same rows, e.g. the bundle's
        [batch, L*H, P, hd]; presents come back in the caller's layout. Concatenating there matters for the
        exported step: the Concat result is the graph output itself, where a Reshape after it would copy
        the whole cache once more per step.
        """
        N, S, C = x.shape
        H, hd = self.n_heads, self.head_dim
        P = past_k.shape[2]
        q, k, v = self.qkv(x).split(C, dim=2)
        q = q.view(N, S, H, hd).transpose(1, 2)  # (N, H, S, hd)
        rows = past_k.shape[0]
        present_k = torch.cat([past_k, k.view(N, S, H, hd).transpose(1, 2).reshape(rows, -1, S, hd)], dim=2)
        present_v = torch.cat([past_v, v.view(N, S, H, hd).transpose(1, 2).reshape(rows, -1, S, hd)], dim=2)
        k = present_k.reshape(N, H, P + S, hd)
        v = present_v.reshape(N, H, P + S, hd)

        content = (q + self.u.unsqueeze(1)) @ k.transpose(-2, -1)  # (N, H, S, P+S)
        qv = (q + self.v.unsqueeze(1)).unsqueeze(3) * self.head_mask.view(1, H, 1, H, hd)  # (N, H, S, H, hd)
        pos_all = qv.flatten(3) @ self.phi.t()  # (N, H, S, R): head h against its slice of every phi row
        dist = (torch.arange(S, device=x.device) + P).unsqueeze(1) - torch.arange(P + S, device=x.device)  # (S, P+S)
        rel = dist.clamp(0, self.max_rel_dist)  # future keys get a valid index, then the mask removes them
        pos = pos_all.gather(3, rel.expand(N, H, S, P + S))  # (N, H, S, P+S)

        att = (content + pos) * (1.0 / math.sqrt(hd))  # (N, H, S, P+S)
        att = att.masked_fill(dist < 0, float("-inf")).softmax(dim=-1)
        y = self.attn_drop(att) @ v  # (N, H, S, hd)
        y = y.transpose(1, 2).reshape(N, S, C)  # (N, S, C)
        return self.resid_drop(self.proj(y)), present_k, present_v


class MLP(nn.Module):

    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        self.fc = nn.Linear(cfg.d_model, cfg.ff_mult * cfg.d_model)
        self.proj = nn.Linear(cfg.ff_mult * cfg.d_model, cfg.d_model)
        self.drop = nn.Dropout(cfg.dropout)

    def forward(self, x):  # (N, S, C)
        return self.drop(self.proj(F.gelu(self.fc(x))))  # (N, S, C)


class ControlAdapter(nn.Module):
    """x + present * up(gelu(down(ln(x)) + ctrl(control))): zero at initialisation (`up` starts at zero) and
    wherever the control's present flag is 0."""

    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        self.ln = nn.LayerNorm(cfg.d_model)
        self.down = nn.Linear(cfg.d_model, cfg.adapter_dim)
        self.ctrl = nn.Linear(cfg.control_dim, cfg.adapter_dim, bias=False)
        self.up = nn.Linear(cfg.adapter_dim, cfg.d_model)

    def forward(self, x, control):  # x (N, S, C), control broadcastable to (N, S, control_dim)
        return x + control[..., :1] * self.up(F.gelu(self.down(self.ln(x)) + self.ctrl(control)))


class Block(nn.Module):
    """Pre-LN transformer block."""

    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        self.ln_1 = nn.LayerNorm(cfg.d_model)
        self.attn = RelativeSelfAttention(cfg)
        self.ln_2 = nn.LayerNorm(cfg.d_model)
        self.mlp = MLP(cfg)

    def forward(self, x, past_k, past_v):  # x (N, S, C)
        a, k, v = self.attn(self.ln_1(x), past_k, past_v)
        x = x + a
        x = x + self.mlp(self.ln_2(x))
        return x, k, v  # (N, S, C), (N, H, P+S, hd) x 2


def at_least_float32(x: torch.Tensor) -> torch.Tensor:
    """Logits made under bf16 autocast, as float32 for their softmax and loss; float32 and float64 (the tests'
    exact runs) stay as they are."""
    return x.float() if x.dtype in (torch.bfloat16, torch.float16) else x


class RQHCTransformer(nn.Module):

    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        self.cfg = cfg
        L, C = cfg.num_levels, cfg.d_model
        # one table for all levels, row level*(K+3) + token: 2-D so a Gather on it can be int8-quantized
        self.tok_emb = nn.Embedding(L * cfg.vocab_size, C)
        self.q_emb = nn.Parameter(torch.randn(L, C) * 0.02)  # q_emb[l]: which level a stream predicts
        self.cond_proj = nn.Linear(cfg.text_dim, C)
        self.ctrl_proj = nn.Linear(cfg.control_dim, C) if cfg.control_dim else None
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList([Block(cfg) for _ in range(cfg.n_layers)])
        if cfg.adapter_dim and not cfg.control_dim:
            raise ValueError("adapter_dim needs a model with control (control_horizon > 0)")
        self.adapters = nn.ModuleList([ControlAdapter(cfg) for _ in range(cfg.n_layers)]) if cfg.adapter_dim else None
        self.ln_f = nn.LayerNorm(C)
        self.head = nn.Linear(C, cfg.codebook_size + 1)  # K codes + END
        self.register_buffer("level_offset", torch.arange(L) * cfg.vocab_size, persistent=False)
        self.apply(self._init_weights)
        for a in self.adapters or []:
            nn.init.zeros_(a.up.weight)
        for name, p in self.named_parameters():
            if name.endswith("proj.weight") and not name.startswith("cond_proj"):
                # GPT-2: scale residual projections by depth so the residual stream starts small
                nn.init.normal_(p, mean=0.0, std=0.02 / math.sqrt(2 * cfg.n_layers))

    @staticmethod
    def _init_weights(m):
        if isinstance(m, (nn.Linear, nn.Embedding)):
            nn.init.normal_(m.weight, mean=0.0, std=0.02)
            if isinstance(m, nn.Linear) and m.bias is not None:
                nn.init.zeros_(m.bias)

    def param_count(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def empty_past(self, batch: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """A zero-length cache for `batch` samples: per layer (key, value), each (batch*L, H, 0, hd)."""
        cfg = self.cfg
        z = self.tok_emb.weight.new_zeros(batch * cfg.num_levels, cfg.n_heads, 0, cfg.d_model // cfg.n_heads)
        return [(z, z) for _ in range(cfg.n_layers)]

    def _inputs(self, text_emb, tokens, control=None):
        """text_emb (B, text_dim), tokens (B, S, L), control (B, S, control_dim) or None (no control) -> (stream
        inputs (B*L, S, C), eq. 7-8 plus the control's projection; the control as read: `_control`'s, or None)."""
        cfg = self.cfg
        B, S, L = tokens.shape
        if self.training and cfg.cond_drop_prob > 0:
            keep = (torch.rand(B, 1, device=text_emb.device) >= cfg.cond_drop_prob).to(text_emb.dtype)
            text_emb = text_emb * keep  # dropped samples see the null (all-zero) text
        prefix = self.cond_proj(text_emb)[:, None, None, :] + self.q_emb  # (B, 1, L, C) PnQ
        is_bos = (tokens == cfg.bos_id).unsqueeze(-1)  # (B, S, L, 1)
        emb = self.tok_emb(tokens + self.level_offset)  # (B, S, L, C)
        # stream l reads the sum of levels 0..l: the residual latent as far as level l has refined it
        cum = emb.masked_fill(is_bos, 0.0).cumsum(dim=2)  # (B, S, L, C)
        x = torch.where(is_bos, prefix, cum)  # (B, S, L, C)
        if self.ctrl_proj is not None:
            control = self._control(control, B, S, text_emb)  # after the text's draw, as before the adapter
            x = x + self.ctrl_proj(control).unsqueeze(2)  # (B, S, 1, C) to every level
        return x.transpose(1, 2).reshape(B * L, S, -1), control  # (B*L, S, C), row b*L + l

    def _control(self, control, B, S, like):
        """The control as the model reads it: zeros for None; in training, zeros for a control_drop_prob share."""
        if control is None:
            return like.new_zeros(B, S, self.cfg.control_dim)
        if self.training and self.cfg.control_drop_prob > 0:
            keep = (torch.rand(B, 1, 1, device=control.device) >= self.cfg.control_drop_prob).to(control.dtype)
            control = control * keep
        return control

    def step(self, text_emb, tokens, past, control=None):
        """One call of the decoder with a KV cache; serves full sequences, prefill, chunks and single steps.

        text_emb (B, text_dim) float; tokens (B, S, L) int64 (BOS where the PnQ prefix goes, i.e. step 0);
        control (B, S, control_dim) float or None (no control; a model without control takes None only);
        past: per layer (key, value), each (B*L, n_heads, P, head_dim), P >= 0 (see `empty_past`), or the same
        rows folded as (B, L*n_heads, P, head_dim) (the bundle's layout).
        Returns logits (B, S, L, K+1) and presents: per layer (key, value) in the layout of `past`, length P+S.
        """
        B, S, L = tokens.shape
        if control is not None and self.ctrl_proj is None:
            raise ValueError("this model was trained without control (control_horizon 0)")
        given = control is not None
        x, control = self._inputs(text_emb, tokens, control)
        x = self.drop(x)  # (B*L, S, C)
        # each level stream reads its sample's control: (B, S, D) -> (B*L, S, D), row b*L + l; none given adds 0
        rows = control.unsqueeze(1).expand(B, L, S, -1).reshape(B * L, S, -1).to(x.dtype) \
            if given and self.adapters is not None else None
        presents = []
        for i, (block, (pk, pv)) in enumerate(zip(self.blocks, past)):
            x, k, v = block(x, pk, pv)
            if rows is not None:
                x = self.adapters[i](x, rows)
            presents.append((k, v))
        logits = self.head(self.ln_f(x))  # (B*L, S, K+1)
        return logits.view(B, L, S, -1).transpose(1, 2), presents  # (B, S, L, K+1)

    def forward(self, text_emb, tokens, control=None):
        """Full sequence, no cache: text_emb (B, text_dim), tokens (B, S, L) -> logits (B, S, L, K+1)."""
        return self.step(text_emb, tokens, self.empty_past(tokens.shape[0]), control)[0]

    def loss(self, text_emb, tokens_in, targets, lengths, control=None):
        """Cross-entropy of eq. 11, averaged over the valid (step, level) pairs, and accuracy.

        tokens_in (B, S, L): [BOS, t_0, ..., t_{T-1}, PAD...]; targets (B, S, L): [t_0, ..., t_{T-1}, END, PAD...];
        lengths (B,): T, the motion length in tokens, so the first T + 1 steps (END included) count; control
        (B, S, control_dim): the control each input step reads (None: none).
        Returns (loss, {"acc": (), "acc_per_level": (L,), "count": () the (step, level) pairs averaged over}).
        """
        B, S, L = tokens_in.shape
        logits = at_least_float32(self(text_emb, tokens_in, control))  # (B, S, L, K+1)
        valid = torch.arange(S, device=tokens_in.device) <= lengths.unsqueeze(1)  # (B, S)
        valid = valid.unsqueeze(-1).expand(B, S, L)  # (B, S, L)
        tgt = targets.masked_fill(~valid, 0)  # PAD is not a class of the head
        ce = F.cross_entropy(logits.flatten(0, 2), tgt.flatten(), reduction="none").view(B, S, L)
        n = valid.sum()
        loss = (ce * valid).sum() / n
        with torch.no_grad():
            hit = (logits.argmax(-1) == tgt) & valid  # (B, S, L)
            acc = hit.sum() / n
            acc_per_level = hit.sum(dim=(0, 1)) / valid.sum(dim=(0, 1))  # (L,)
        return loss, {"acc": acc, "acc_per_level": acc_per_level, "count": n}
