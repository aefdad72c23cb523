"""The transformer's training examples, from the VQ's tokens (tokens.npz) and the embedded captions: whole clips
and streaming windows, padded into batches. Shared by training (train.py) and guidance distillation (distill.py).

    table, emb, text_dim = caption_table(data, out, "all-MiniLM-L6-v2")
    d = load_token_data(data, out / "tokens.npz", table, emb, cfg, downsample)
    batch = pad_examples(clip_examples(d.seqs, d.caps, emb, rng, 32, cfg, d.by_length, d.controls), cfg)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mogo_runtime.control.vector import token_controls

from .data.dataset import MotionDataset, read_control_only
from .data.timelines import read_timelines
from .models.text_encoder import CachedTextEncoder, get_text_encoder

ROOT = "root:"       # tokens.npz: ROOT + key holds clip `key`'s root poses, beside its tokens


def caption_table(data: Path, out: Path, encoder_name: str, write: bool = True):
    """All captions of all splits embedded once, cached on disk. `write=False`: for a process that finds every
    caption cached by rank 0 and must leave the file alone."""
    encoder = CachedTextEncoder(get_text_encoder(encoder_name), out / "captions.npz")
    table = {}
    for split in ("train", "val", "test"):
        for it in MotionDataset.load(data, split, control_sequences=True).items:
            table[(split, it.clip_id)] = it.captions
    flat = sorted({c for caps in table.values() for c in caps})
    emb = dict(zip(flat, encoder.encode(flat).numpy()))
    if write:
        encoder.save()
    return table, emb, encoder.dim


def to_model(model: torch.nn.Module, t: torch.Tensor) -> torch.Tensor:
    """`t` on the model's device, and in its dtype if floating point: float32, unless torch's default dtype was
    another when the model was built (tests/export/test_distributed.py trains in float64)."""
    p = next(model.parameters())
    return t.to(p.device, p.dtype) if t.is_floating_point() else t.to(p.device)


@dataclass
class TokenData:
    """The training split's clips (tokens, captions, controls), the validation split's, and the training split's
    timelines cut into timed segments (for streaming windows); controls are None for a model without control."""
    seqs: list
    caps: list
    controls: list | None
    val_seqs: list
    val_caps: list
    val_controls: list | None
    timelines: list
    timeline_controls: list | None
    # per training clip and timeline: is it one of the dataset's control sequences (all False without them)
    seq_control_only: list
    timeline_control_only: list

    @property
    def by_length(self) -> np.ndarray:
        return np.argsort([len(q) for q in self.seqs], kind="stable")


def load_token_data(data: Path, tokens_path: Path, table: dict, emb: dict, cfg, downsample: int,
                    control_sequences: bool = False) -> TokenData:
    """tokens.npz (train.extract_tokens) and the caption table -> TokenData for transformer config `cfg`; the
    dataset's control sequences (dataset.json "control_only") only with `control_sequences` (the control adapter's
    data): left out before anything is drawn, the transformer trains exactly as on a dataset without them."""
    control_only = read_control_only(data)
    skip = frozenset() if control_sequences else control_only

    def clip(key):  # "train/<id>", "train/<id>:<first>-<stop>", "timeline/train/<id>" -> <id>
        return key.rsplit("/", 1)[1].split(":")[0]

    with np.load(tokens_path) as z:
        tokens = {k: z[k].astype(np.int64) for k in z.files if "/" in k and not k.startswith(ROOT)
                  and clip(k) not in skip}
        controls = {k: token_controls(z[ROOT + k], downsample, cfg.control_horizon)
                    for k in tokens} if cfg.control_dim else None

    def split(name):
        keys = sorted(k for k in tokens if k.startswith(name + "/"))
        return ([tokens[k] for k in keys], [table[(name, k.split("/", 1)[1])] for k in keys],
                None if controls is None else [controls[k] for k in keys])

    lines = read_timelines(data, "train", control_sequences=control_sequences)
    missing = [t.clip_id for t in lines if f"timeline/train/{t.clip_id}" not in tokens]
    if missing:
        raise ValueError(f"{tokens_path} holds no tokens for {len(missing)} sequences of {data} (e.g. "
                         f"{missing[0]}): it was extracted from another version of the dataset; delete it")
    timelines = [(t.clip_id, token_units(t, tokens[f"timeline/train/{t.clip_id}"], downsample),
                  None if controls is None else controls[f"timeline/train/{t.clip_id}"]) for t in lines]
    timelines = [t for t in timelines if t[1][1]]
    train_keys = sorted(k for k in tokens if k.startswith("train/"))
    return TokenData(*split("train"), *split("val"), [t for _, t, _ in timelines],
                     None if controls is None else [c for _, _, c in timelines],
                     [clip(k) in control_only for k in train_keys], [i in control_only for i, _, _ in timelines])


def clip_examples(seqs, caps, emb, rng, n, cfg, by_length=None, controls=None) -> list:
    """Whole clips: ([BOS, t...], [t..., END]) with one of the clip's captions, and the clip's controls (T + 1,
    control_dim) when the model has control. With `by_length` (indices sorted by length) the clips are a random run
    of similar lengths, so little compute goes to padding."""
    if by_length is not None and len(by_length) > n:
        start = rng.integers(len(by_length) - n + 1)
        idx = by_length[start:start + n]
    else:
        idx = rng.integers(len(seqs), size=n)
    out = []
    for i in idx:
        seq, c = seqs[i], caps[i]
        tin = np.concatenate([np.full((1, cfg.num_levels), cfg.bos_id), seq])
        tgt = np.concatenate([seq, np.full((1, cfg.num_levels), cfg.end_id)])
        out.append((emb[c[rng.integers(len(c))]], tin, tgt, None if controls is None else controls[i]))
    return out


def window_examples(timelines, emb, rng, n, cfg, streaming, controls=None) -> list:
    """Streaming windows, the contexts an endless stream refreshes to (mogo_runtime.decoding.EndlessLoop): the
    prompt prefix of one timed segment of a long sequence, then 1 to window + refresh of that segment's tokens,
    ending anywhere in it, so the context often begins mid-action rather than where a motion starts (with `controls`,
    each timeline's per-token controls, as for clips). All are targets; no END (the data's action does not end
    there, it changes). The stream keeps nothing across a prompt switch, so windows never reach into the previous
    segment."""
    out = []
    for _ in range(n):
        t = rng.integers(len(timelines))
        seq, segments = timelines[t]
        first, stop, captions = segments[rng.integers(len(segments))]
        end = int(rng.integers(first, stop))                     # the last target
        start = max(first, end + 1 - int(rng.integers(1, streaming.window + streaming.refresh + 1)))
        tin = np.concatenate([np.full((1, cfg.num_levels), cfg.bos_id), seq[start:end]])
        # the control of each step: BOS picks token `start`, as an endless stream's rebuilt context does
        out.append((emb[captions[rng.integers(len(captions))]], tin, seq[start:end + 1],
                    None if controls is None else controls[t][start:end + 1]))
    return out


def pad_examples(examples, cfg):
    """-> (text (B, text_dim), tokens_in (B, S, L), targets (B, S, L), lengths (B,)[, control (B, S, control_dim)]),
    PAD-filled (the control zero-filled) on the right; the control only for a model with control."""
    lengths = np.array([len(tgt) - 1 for _, _, tgt, _ in examples])
    S, L = lengths.max() + 1, cfg.num_levels
    tin = np.full((len(examples), S, L), cfg.pad_id, np.int64)
    tgt = np.full((len(examples), S, L), cfg.pad_id, np.int64)
    for b, (_, i, t, _) in enumerate(examples):
        tin[b, :len(i)], tgt[b, :len(t)] = i, t
    text = np.stack([e for e, _, _, _ in examples]).astype(np.float32)
    batch = torch.from_numpy(text), torch.from_numpy(tin), torch.from_numpy(tgt), torch.from_numpy(lengths)
    if not cfg.control_dim:
        return batch
    control = np.zeros((len(examples), S, cfg.control_dim), np.float32)
    for b, (_, i, _, c) in enumerate(examples):
        control[b, :len(i)] = c[:len(i)]
    return (*batch, torch.from_numpy(control))


def token_units(timeline, tokens: np.ndarray, downsample: int):
    """A timeline's segments in tokens: (tokens, [(first, stop, captions)]), segments shorter than a token dropped."""
    segs = [(seg.first // downsample, min(len(tokens), seg.stop // downsample), seg.captions)
            for seg in timeline.segments]
    return tokens, [(a, b, c) for a, b, c in segs if a < b]


