"""MoSA-VQ: a Conv1d motion VQ-VAE with a residual quantizer whose levels learn their own scaling (MOGO §2.1)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

# Layouts used throughout: motion features (B, T, D) with T frames; latents (B, T', code_dim) with
# T' = T // downsample tokens; indices (B, T', L) int64, level l in the last axis. Convs run channels-first
# internally and transpose at their edges, so callers only ever see time-major tensors.


@dataclass
class VQConfig:
    """Defaults are generic; the named sizes (tiny, base, paper) are in mogo_export/presets.py."""

    input_dim: int = 263                # motion feature size per frame (HumanML3D: 263, KIT-ML: 251)
    width: int = 256                    # channels of the conv stacks
    code_dim: int = 256                 # latent / codebook vector size d
    downsample: int = 4                 # frames per token: 1 (the paper's stride-1 design), 2 or 4
    depth: int = 3                      # dilated residual blocks per stage (dilations 1, 3, 9, ...)
    dilation_growth: int = 3            # dilation multiplier between consecutive residual blocks
    num_levels: int = 6                 # residual quantization levels L
    codebook_size: int = 512            # codes per level K
    learnable_scaling: bool = True      # eq. 1-3 scale/bias per level; False = plain RVQ (the ablation)
    beta: float = 0.02                  # weight of the commitment term of eq. 6
    gamma: float = 1e-4                 # weight of the scale/bias regulariser of eq. 6
    quantize_dropout_prob: float = 0.2  # chance per training batch to drop a random suffix of levels
    ema_decay: float = 0.99             # EMA decay of codebook counts and sums
    dead_code_threshold: float = 0.1    # a code whose EMA count < this x the level's mean count is reset
    vel_loss: float = 0.0               # weight of an L1 loss on frame-to-frame differences (0 = off)
    mse_loss: float = 0.0               # weight of a squared-error term added to the L1 reconstruction
    root_loss: float = 1.0              # the root's 4 channels' errors (HumanML3D/KIT layout) scaled by this,
                                        # as if their Std were this many times smaller (T2M's feat_bias)

    def __post_init__(self):
        assert self.downsample in (1, 2, 4), "downsample must be 1, 2 or 4"


# -----------------------------------------------------------------------------
# encoder (non-causal) and decoder (causal)

class CausalConv1d(nn.Conv1d):
    """Conv1d that pads (kernel-1)*dilation zeros on the left: output t sees inputs <= t only."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, dilation: int = 1):
        super().__init__(c_in, c_out, kernel_size, dilation=dilation)
        self.reach = (kernel_size - 1) * dilation  # how many past steps one output can see

    def forward(self, x):  # (B, C, T)
        return super().forward(F.pad(x, (self.reach, 0)))  # (B, C_out, T)


class ResBlock(nn.Module):
    """act -> dilated conv(k=3) -> act -> conv(k=1) -> + skip; causal pads the left only."""

    def __init__(self, width: int, dilation: int, causal: bool):
        super().__init__()
        if causal:
            self.conv1 = CausalConv1d(width, width, 3, dilation)
        else:
            self.conv1 = nn.Conv1d(width, width, 3, padding=dilation, dilation=dilation)
        self.conv2 = nn.Conv1d(width, width, 1)

    def forward(self, x):  # (B, C, T)
        return x + self.conv2(F.relu(self.conv1(F.relu(x))))  # (B, C, T)


class Upsample(nn.Module):
    """Nearest-neighbour repeat along time; frame f copies step f // factor, so causality survives."""

    def __init__(self, factor: int):
        super().__init__()
        self.factor = factor

    def forward(self, x):  # (B, C, T)
        return x.unsqueeze(-1).expand(-1, -1, -1, self.factor).flatten(2)  # (B, C, T*factor)


def _strides(downsample: int) -> list[int]:
    # one stage per factor of 2; a single stride-1 stage when there is no down-sampling
    return [2] * int(math.log2(downsample)) or [1]


def _dilations(cfg: VQConfig) -> list[int]:
    return [cfg.dilation_growth ** i for i in range(cfg.depth)]


class MotionEncoder(nn.Module):
    """(B, T, D) motion -> (B, T // downsample, code_dim) latent. Non-causal: it only runs on whole clips."""

    def __init__(self, cfg: VQConfig):
        super().__init__()
        w = cfg.width
        layers = [nn.Conv1d(cfg.input_dim, w, 3, 1, 1), nn.ReLU()]
        for stride in _strides(cfg.downsample):
            # k=4, s=2, p=1 halves an even length exactly; the stride-1 stage keeps the same shape
            layers.append(nn.Conv1d(w, w, 4, 2, 1) if stride == 2 else nn.Conv1d(w, w, 3, 1, 1))
            layers += [ResBlock(w, d, causal=False) for d in _dilations(cfg)]
        layers.append(nn.Conv1d(w, cfg.code_dim, 3, 1, 1))
        self.net = nn.Sequential(*layers)

    def forward(self, x):  # (B, T, D)
        return self.net(x.transpose(1, 2)).transpose(1, 2)  # (B, T', code_dim)


class MotionDecoder(nn.Module):
    """(B, T', code_dim) latent -> (B, T' * downsample, D) motion; frame f depends on tokens <= f // downsample."""

    def __init__(self, cfg: VQConfig):
        super().__init__()
        w = cfg.width
        self.downsample = cfg.downsample
        layers = [CausalConv1d(cfg.code_dim, w, 3), nn.ReLU()]
        for stride in _strides(cfg.downsample):
            layers += [ResBlock(w, d, causal=True) for d in reversed(_dilations(cfg))]
            if stride > 1:
                layers.append(Upsample(stride))
            layers.append(CausalConv1d(w, w, 3))
        layers += [CausalConv1d(w, w, 3), nn.ReLU(), CausalConv1d(w, cfg.input_dim, 3)]
        self.net = nn.Sequential(*layers)

    @property
    def receptive_field(self) -> int:
        """How many tokens before a frame's own token can still change that frame.

        Walks the layers backwards from the last frame of every phase (f mod downsample): a conv moves the
        oldest visible step `reach` steps back, an upsample maps steps to the coarser grid (floor divide).
        A streaming decoder needs this many tokens of left context to reproduce a full-clip decode exactly.
        """
        ops = [m for m in self.net.modules() if isinstance(m, (CausalConv1d, Upsample))]  # forward order
        far = 0
        for phase in range(self.downsample):
            frame = 1000 * self.downsample + phase  # far from 0, so floor division never meets the clip start
            lo, hi = frame, frame
            for m in reversed(ops):
                if isinstance(m, CausalConv1d):
                    lo -= m.reach
                else:
                    lo, hi = lo // m.factor, hi // m.factor
            far = max(far, hi - lo)
        return far

    def forward(self, z):  # (B, T', code_dim)
        return self.net(z.transpose(1, 2)).transpose(1, 2)  # (B, T, D)


# -----------------------------------------------------------------------------
# residual quantizer with learnable per-level scaling (eq. 1-5)

@dataclass
class QuantizerOutput:
    quantized: torch.Tensor   # (B, T', d) summed latent; straight-through gradient to the input
    indices: torch.Tensor     # (B, T', L) int64; levels dropped by quantize-dropout hold -1
    commit: torch.Tensor      # () sum over levels of mean ||r^l - sg[b^l]||^2
    reg: torch.Tensor         # () sum_l ||s^l - 1||^2 + ||b^l||^2 (0 without learnable scaling)
    perplexity: torch.Tensor  # (L,) exp(entropy) of this batch's code histogram per level (0 if dropped)
    usage: torch.Tensor       # (L,) fraction of codes used in this batch per level


class ResidualQuantizer(nn.Module):
    """L levels of VQ on successive residuals, each in its own learned scaled space, with EMA codebooks.

    Codebooks live in the scaled space of their level, as ONE 2-D buffer (L*K, d): row l*K + k is code k of
    level l, so a lookup is a single Gather on a 2-D table. Codebooks learn by EMA of the scaled residuals
    assigned to them (no gradient); codes whose EMA count falls below dead_code_threshold x the mean count
    are reset to random current residuals (MoMask's absolute threshold of 1 at 8 vectors per code is 0.125).

    Gradients: the encoder gets the straight-through gradient of the summed latent. The scale s^l and bias
    b^l get gradient through the inverse transform (q - b^l) / ||s^l|| of eq. 3, from the reconstruction
    and from the commitment of later levels (whose residuals subtract b^l). Note that ||s^l|| is one gain
    per level (eq. 1 writes the norm of the vector): a uniform gain and a shift do not change which code is
    nearest, so what learnable scaling buys is that every code of a level can move at once by gradient,
    between EMA updates. The regulariser pulls s^l to the all-ones vector, whose norm is sqrt(d): as
    written in eq. 6, "identity" is a gain of sqrt(d), which is harmless because codebooks live in the
    scaled space.
    """

    def __init__(self, cfg: VQConfig):
        super().__init__()
        self.cfg = cfg
        L, K, d = cfg.num_levels, cfg.codebook_size, cfg.code_dim
        if cfg.learnable_scaling:
            self.scale = nn.Parameter(torch.ones(L, d))  # s^l, one row per level
            self.bias = nn.Parameter(torch.zeros(L, d))  # b^l
        self.register_buffer("codebook", torch.randn(L * K, d))     # row l*K + k: code k of level l
        self.register_buffer("ema_count", torch.ones(L * K))        # EMA of how many vectors chose each code
        self.register_buffer("ema_sum", self.codebook.clone())      # EMA of the sum of those vectors
        self.register_buffer("initted", torch.zeros(L, dtype=torch.bool))  # codebook seeded from data yet
        self.register_buffer("level_offset", torch.arange(L) * K)  # (L,) row of code 0 of each level
        # Under DistributedDataParallel each process holds a slice of the batch; mogo_export.distributed sets
        # this to its Group, whose sum() and cat() make the codebook updates see the whole batch, identically
        # on every process (the same counts, sums and reset vectors as one process). None: one process.
        self.sync = None

    # --- the affine map of eq. 1 and its inverse, eq. 3; `levels` selects rows of s and b
    def _scaled(self, r, levels: slice):  # r (..., n, d) residual space -> scaled space
        if not self.cfg.learnable_scaling:
            return r
        return self.scale[levels].norm(dim=-1, keepdim=True) * r + self.bias[levels]

    def _unscaled(self, q, levels: slice):  # q (..., n, d) scaled space -> residual space
        if not self.cfg.learnable_scaling:
            return q
        return (q - self.bias[levels]) / self.scale[levels].norm(dim=-1, keepdim=True)

    def lookup(self, indices):
        """indices (B, T', n) int64 for levels 0..n-1 (n <= L) -> summed latent (B, T', d), eq. 3 + 5.

        The one function that turns tokens into a latent: the quantizer's own output is this, and the
        exported "quantizer lookup" graph is exactly this.
        """
        n = indices.shape[-1]
        q = F.embedding(indices + self.level_offset[:n], self.codebook)  # (B, T', n, d) scaled space
        return self._unscaled(q, slice(0, n)).sum(dim=2)  # (B, T', d)

    def _nearest(self, x, level: int):  # x (N, d) scaled residuals -> (N,) code index within the level
        K = self.cfg.codebook_size
        C = self.codebook[level * K:(level + 1) * K]  # (K, d)
        dist = x.pow(2).sum(-1, keepdim=True) - 2 * x @ C.t() + C.pow(2).sum(-1)  # (N, K)
        return dist.argmin(dim=-1)  # (N,)

    def _whole(self, x):  # x (N, d) this process's rows -> the whole batch's rows, in one process's order
        return x if self.sync is None else self.sync.cat(x)

    @torch.no_grad()
    def _seed(self, x, level: int):  # codebook of `level` <- random rows of x (N, d), with replacement
        K = self.cfg.codebook_size
        rows = slice(level * K, (level + 1) * K)
        x = self._whole(x)
        self.codebook[rows] = x[torch.randint(0, x.shape[0], (K,), device=x.device)]
        self.ema_sum[rows] = self.codebook[rows].clone()
        self.ema_count[rows] = 1.0
        self.initted[level] = True

    @torch.no_grad()
    def _ema_update(self, x, idx, level: int):  # x (N, d) scaled residuals, idx (N,) their codes
        cfg = self.cfg
        K, decay = cfg.codebook_size, cfg.ema_decay
        rows = slice(level * K, (level + 1) * K)
        onehot = F.one_hot(idx, K).type_as(x)  # (N, K)
        used, added = onehot.sum(0), (1 - decay) * onehot.t() @ x  # (K,), (K, d)
        if self.sync is not None:
            used, added = self.sync.sum(used), self.sync.sum(added)
        self.ema_count[rows] = decay * self.ema_count[rows] + (1 - decay) * used
        self.ema_sum[rows] = decay * self.ema_sum[rows] + added
        count = self.ema_count[rows]
        # Laplace smoothing keeps rarely used codes from dividing by ~0
        n = count.sum()
        smoothed = (count + 1e-5) / (n + K * 1e-5) * n  # (K,)
        self.codebook[rows] = self.ema_sum[rows] / smoothed.unsqueeze(1)
        # dead codes restart from random current residuals, and their EMA state with them; the floor is
        # relative to the mean count, so the rule does not depend on how many vectors a batch holds.
        # Codes this batch used are spared: the loop is about to read them for this batch's residuals.
        floor = cfg.dead_code_threshold * n / K
        dead = (count < floor) & (used == 0)  # (K,)
        n_dead = int(dead.sum())
        if n_dead:
            x = self._whole(x)
            fresh = x[torch.randint(0, x.shape[0], (n_dead,), device=x.device)]  # (n_dead, d)
            self.codebook[rows][dead] = fresh  # basic slicing gives views, so these write the buffers
            self.ema_sum[rows][dead] = fresh * floor
            self.ema_count[rows][dead] = floor

    def _quantize(self, z, n_active: int, update: bool):
        """Residual loop of Algorithm 1 over levels 0..n_active-1 -> (indices (B, T', n_active), commit)."""
        B, T, d = z.shape
        residual = z  # r^0
        commit = z.new_zeros(())
        indices = []
        for l in range(n_active):
            lv = slice(l, l + 1)
            r_scaled = self._scaled(residual.reshape(-1, 1, d), lv).squeeze(1)  # (N, d) eq. 1
            if update and not bool(self.initted[l]):
                self._seed(r_scaled.detach(), l)
            idx = self._nearest(r_scaled.detach(), l)  # (N,) eq. 2
            if update:
                self._ema_update(r_scaled.detach(), idx, l)
            code = self.codebook[idx + l * self.cfg.codebook_size]  # (N, d) scaled space
            b_l = self._unscaled(code.unsqueeze(1), lv).reshape(B, T, d)  # (B, T', d) eq. 3
            commit = commit + F.mse_loss(residual, b_l.detach())  # eq. 6, second term
            residual = residual - b_l  # eq. 4
            indices.append(idx.reshape(B, T))
        return torch.stack(indices, dim=-1), commit  # (B, T', n_active), ()

    def encode(self, z):
        """z (B, T', d) -> indices (B, T', L), all levels, no side effects (no EMA, no dropout)."""
        with torch.no_grad():
            return self._quantize(z, self.cfg.num_levels, update=False)[0]

    def forward(self, z) -> QuantizerOutput:  # z (B, T', d)
        cfg = self.cfg
        B, T, d = z.shape
        L, K = cfg.num_levels, cfg.codebook_size
        n_active = L
        if self.training and L > 1 and float(torch.rand(())) < cfg.quantize_dropout_prob:
            # drop a random suffix: the decoder learns to work from the coarse levels alone
            n_active = int(torch.randint(1, L, ()))
        indices, commit = self._quantize(z, n_active, update=self.training)  # (B, T', n_active)
        # value = lookup(indices) exactly; gradient = identity to z (straight-through), plus s and b via eq. 3
        quantized = self.lookup(indices) + (z - z.detach())  # (B, T', d)
        if cfg.learnable_scaling:
            reg = (self.scale - 1).pow(2).sum() + self.bias.pow(2).sum()
        else:
            reg = z.new_zeros(())
        with torch.no_grad():
            counts = F.one_hot(indices, K).sum(dim=(0, 1)).float()  # (n_active, K)
            if self.training and self.sync is not None:
                counts = self.sync.sum(counts)  # statistics of the whole batch
            p = counts / counts.sum(-1, keepdim=True)
            perplexity = torch.exp(-(p * torch.log(p.clamp_min(1e-10))).sum(-1))  # (n_active,)
            usage = (counts > 0).float().mean(-1)  # (n_active,)
            pad = L - n_active
            perplexity, usage = F.pad(perplexity, (0, pad)), F.pad(usage, (0, pad))
        indices = F.pad(indices, (0, L - n_active), value=-1)  # (B, T', L)
        return QuantizerOutput(quantized, indices, commit, reg, perplexity, usage)


# -----------------------------------------------------------------------------
# the VQ-VAE

class MoSAVQ(nn.Module):
    """Encoder + residual quantizer + causal decoder, trained with the loss of eq. 6."""

    def __init__(self, cfg: VQConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = MotionEncoder(cfg)
        self.quantizer = ResidualQuantizer(cfg)
        self.decoder = MotionDecoder(cfg)

    @property
    def receptive_field(self) -> int:
        return self.decoder.receptive_field

    def param_count(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def _check_length(self, x):
        assert x.shape[1] % self.cfg.downsample == 0, f"T={x.shape[1]} is not a multiple of {self.cfg.downsample}"

    def forward(self, x):
        """x (B, T, D) normalised motion -> recon (B, T, D), dict of loss terms and codebook stats."""
        self._check_length(x)
        cfg = self.cfg
        q = self.quantizer(self.encoder(x))
        recon = self.decoder(q.quantized)  # (B, T, D)
        err = recon - x
        if cfg.root_loss != 1.0:
            # the root is 4 of 263 channels but all of where a body goes: a sidestep without its root velocity
            # reconstructs as standing still (judged shaking the head)
            w = torch.ones(x.shape[-1], dtype=x.dtype, device=x.device)
            w[:4] = cfg.root_loss
            err = err * w
        rec = err.abs().mean()
        loss = rec + cfg.beta * q.commit + cfg.gamma * q.reg
        if cfg.mse_loss > 0:
            # L1 alone is a median fit: a pose held by few clips (one raised arm) is many std away and
            # cheap to ignore; the squared term makes large errors pull hard
            loss = loss + cfg.mse_loss * err.pow(2).mean()
        vel = x.new_zeros(())
        if cfg.vel_loss > 0:
            vel = F.l1_loss(recon[:, 1:] - recon[:, :-1], x[:, 1:] - x[:, :-1])
            loss = loss + cfg.vel_loss * vel
        terms = dict(loss=loss, recon=rec.detach(), commit=q.commit.detach(), reg=q.reg.detach(),
                     vel=vel.detach(), perplexity=q.perplexity, usage=q.usage)
        return recon, terms

    def encode(self, x):
        """x (B, T, D) -> indices (B, T // downsample, L) int64."""
        self._check_length(x)
        return self.quantizer.encode(self.encoder(x))

    def decode_indices(self, indices):
        """indices (B, T', L) -> motion features (B, T' * downsample, D)."""
        return self.decoder(self.quantizer.lookup(indices))
