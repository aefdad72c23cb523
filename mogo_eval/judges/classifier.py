"""A small motion classifier (action family from features): the judge of generation quality on our data."""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F


@dataclass
class ClassifierConfig:
    input_dim: int = 263      # motion features per frame
    width: int = 128          # conv channels
    embed_dim: int = 64       # motion embedding (used for diversity)
    num_classes: int = 21     # action families
    dropout: float = 0.1


class MotionClassifier(nn.Module):
    """Conv1d over time, masked mean+max pooling, then a motion embedding and class logits."""

    def __init__(self, cfg: ClassifierConfig):
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        self.convs = nn.Sequential(
            nn.Conv1d(cfg.input_dim, w, 5, padding=2), nn.GELU(),
            nn.Conv1d(w, w, 5, padding=4, dilation=2), nn.GELU(),
            nn.Conv1d(w, w, 5, padding=8, dilation=4), nn.GELU(),
        )
        self.embed = nn.Sequential(nn.Dropout(cfg.dropout), nn.Linear(2 * w, cfg.embed_dim), nn.GELU())
        self.head = nn.Linear(cfg.embed_dim, cfg.num_classes)

    def embedding(self, x, lengths):
        """x (B, T, D) normalised features, lengths (B,) -> (B, embed_dim)."""
        B, T, _ = x.shape
        h = self.convs(x.transpose(1, 2))                                       # (B, w, T)
        mask = (torch.arange(T, device=x.device)[None] < lengths[:, None])[:, None]  # (B, 1, T)
        mean = (h * mask).sum(-1) / mask.sum(-1).clamp(min=1)                   # (B, w)
        mx = h.masked_fill(~mask, float("-inf")).amax(-1)                       # (B, w)
        return self.embed(torch.cat([mean, mx], dim=-1))

    def forward(self, x, lengths):
        return self.head(self.embedding(x, lengths))                           # (B, num_classes)

    def loss(self, x, lengths, labels):
        logits = self(x, lengths)
        return F.cross_entropy(logits, labels), (logits.argmax(-1) == labels).float().mean()
