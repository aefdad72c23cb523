"""Training: MoSA-VQ on motion windows, token extraction, then the RQHC-Transformer on (caption, tokens).

    python -m mogo_export.cli train --data data/procedural --out checkpoints/base --preset base

writes `vq.pt`, `tokens.npz`, `captions.npz` (cached caption embeddings) and `transformer.pt` into --out.
Each phase shows a progress bar (loss, throughput, ETA), validates periodically, checkpoints atomically, and
resumes from its checkpoint after an interruption (a kill -9 included: files are written as mogo_runtime/files.py
says, so the folder holds only whole files); a finished phase is skipped on the next run. A resumed run ends with
the same weights, bit for bit, as an uninterrupted one with the same torch thread count: the checkpoint holds the
optimiser and every RNG the next steps draw from (_train_state); tests/export/test_train_kill9.py checks it.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from mogo_runtime.features import recover_from_ric
from mogo_runtime.files import write_atomic
from mogo_runtime.skeleton import get_skeleton

from .checkpoint import build_from_checkpoint, read_checkpoint, save_checkpoint
from .data.dataset import MotionDataset
from .data.timelines import read_timelines
from .models import transformer as tmodel
from .models import vq as vqmodel
from .models.text_encoder import CachedTextEncoder, get_text_encoder
from .presets import DEFAULT, Schedule, get_preset  # Schedule stays importable as train.Schedule


def _set_lr(opt, lr):
    for g in opt.param_groups:
        g["lr"] = lr


def _resume(path: Path, kind: str, model, opt) -> tuple[int, np.random.Generator | None, dict | None]:
    """Restore model, optimiser and RNGs from an unfinished checkpoint; -> (next step, sampling rng, validation
    rng state or None: a checkpoint from before it was saved)."""
    if not path.exists():
        return 0, None, None
    payload = read_checkpoint(path, kind)
    model.load_state_dict(payload["model"])
    train = payload["train"]
    opt.load_state_dict(train["optimizer"])
    torch.set_rng_state(train["torch_rng"])
    rng = np.random.default_rng()
    rng.bit_generator.state = train["numpy_rng"]
    return int(train["step"]), rng, train.get("val_rng")


def _train_state(step, opt, rng, done: bool, val_rng: np.random.Generator | None = None) -> dict:
    """Everything the next steps depend on besides the weights: with it a resumed run takes the same steps, on
    the same batches, with the same validation batches, as one that was never interrupted (bit for bit, at the
    same torch thread count)."""
    state = {"step": step, "optimizer": opt.state_dict(), "torch_rng": torch.get_rng_state(),
             "numpy_rng": rng.bit_generator.state, "done": done}
    if val_rng is not None:
        state["val_rng"] = val_rng.bit_generator.state
    return state


def _is_done(path: Path, kind: str) -> bool:
    """A finished checkpoint is kept as it is: training skips it (and says so)."""
    done = path.exists() and bool(read_checkpoint(path, kind)["train"].get("done"))
    if done:
        print(f"{kind}: {path} is complete, skipping (delete it to retrain)")
    return done


# -----------------------------------------------------------------------------
# MoSA-VQ

def _crops(clips: list[np.ndarray], rng, batch: int, window: int) -> torch.Tensor:
    out = np.empty((batch, window, clips[0].shape[1]), np.float32)
    for i, c in enumerate(rng.integers(len(clips), size=batch)):
        clip = clips[c]
        start = rng.integers(len(clip) - window + 1)
        out[i] = clip[start:start + window]
    return torch.from_numpy(out)


@torch.no_grad()
def evaluate_vq(vq: vqmodel.MoSAVQ, clips: list[np.ndarray], mean: np.ndarray, std: np.ndarray,
                num_joints: int = 22) -> dict:
    """Reconstruction of whole clips: mean per-joint position error (mm) and normalised L1."""
    vq.eval()
    ds, errs, l1 = vq.cfg.downsample, [], []
    for clip in clips:
        T = len(clip) // ds * ds
        x = torch.from_numpy(clip[None, :T])
        recon = vq.decode_indices(vq.encode(x))[0].numpy()
        l1.append(np.abs(recon - clip[:T]).mean())
        gt = recover_from_ric(clip[:T] * std + mean, num_joints)
        pred = recover_from_ric(recon * std + mean, num_joints)
        errs.append(np.linalg.norm(gt - pred, axis=-1).mean() * 1000)
    return {"mpjpe_mm": float(np.mean(errs)), "l1": float(np.mean(l1))}


def train_vq(data: Path, out: Path, preset: str = DEFAULT, seed: int = 0, progress: bool = True,
             schedule: Schedule | None = None, **overrides) -> Path:
    """`preset`: a name in mogo_export.presets; `schedule` and `overrides` (VQConfig fields) replace its values."""
    path = out / "vq.pt"
    if _is_done(path, "vq"):
        return path
    pset = get_preset(preset)
    sched = schedule or pset.vq_schedule
    train_ds, val_ds = MotionDataset.load(data, "train"), MotionDataset.load(data, "val")
    num_joints = get_skeleton(train_ds.skeleton).num_joints
    cfg = pset.vq_config(input_dim=int(train_ds.mean.shape[0]), **overrides)
    mean, std = train_ds.mean, train_ds.std
    clips = [train_ds.normalize(it.features) for it in train_ds.items if len(it.features) >= sched.window]
    val_clips = [val_ds.normalize(it.features) for it in val_ds.items][:64]
    if not clips:
        raise ValueError(f"{data}: no training clip has {sched.window} frames or more")

    torch.manual_seed(seed)
    vq = vqmodel.MoSAVQ(cfg)
    opt = torch.optim.AdamW(vq.parameters(), lr=sched.lr, betas=(0.9, 0.99), weight_decay=0.0)
    start, rng, _ = _resume(path, "vq", vq, opt)      # VQ validation uses whole clips: no RNG
    rng = rng or np.random.default_rng(seed)
    # the fields checkpoint.load_trained requires (checkpoint.VQ_META), plus the run's own record
    meta = {"mean": mean.tolist(), "std": std.tolist(), "fps": train_ds.fps, "dataset": str(data), "preset": preset,
            "skeleton": train_ds.skeleton}
    bar = tqdm(range(start, sched.steps), initial=start, total=sched.steps, desc="vq", disable=not progress)
    t0, frames = time.perf_counter(), 0
    for step in bar:
        vq.train()
        _set_lr(opt, sched.lr_at(step))
        x = _crops(clips, rng, sched.batch_size, sched.window)
        _, terms = vq(x)
        opt.zero_grad(set_to_none=True)
        terms["loss"].backward()
        torch.nn.utils.clip_grad_norm_(vq.parameters(), 1.0)
        opt.step()
        frames += x.shape[0] * x.shape[1]
        bar.set_postfix(loss=f"{terms['loss'].item():.4f}", rec=f"{terms['recon'].item():.4f}",
                        ppl=f"{terms['perplexity'].mean().item():.0f}", fps=f"{frames / (time.perf_counter() - t0):.0f}")
        last = step + 1 == sched.steps
        if (step + 1) % sched.val_every == 0 or last:
            meta["val"] = evaluate_vq(vq, val_clips, mean, std, num_joints)
            bar.write(f"vq step {step + 1}: val MPJPE {meta['val']['mpjpe_mm']:.1f} mm, L1 {meta['val']['l1']:.4f}")
        if (step + 1) % sched.ckpt_every == 0 or last:
            save_checkpoint(path, "vq", cfg, vq, _train_state(step + 1, opt, rng, last), meta)
    return path


# -----------------------------------------------------------------------------
# tokens and captions

@torch.no_grad()
def extract_tokens(data: Path, out: Path, progress: bool = True) -> Path:
    """Run the trained VQ over every clip of every split once; the transformer trains on these."""
    path = out / "tokens.npz"
    vq, cfg, payload = build_from_checkpoint(out / "vq.pt", "vq", vqmodel.VQConfig, vqmodel.MoSAVQ)
    if path.exists():
        with np.load(path) as z:
            if str(z["vq_step"]) == str(payload["train"]["step"]):
                return path
    arrays = {}
    for split in ("train", "val", "test"):
        ds = MotionDataset.load(data, split)
        whole = [(f"timeline/{split}/{t.clip_id}", t.features) for t in read_timelines(data, split, ds.skeleton)]
        items = [(f"{split}/{it.clip_id}", it.features) for it in ds.items] + whole
        for key, features in tqdm(items, desc=f"tokens {split}", disable=not progress):
            T = len(features) // cfg.downsample * cfg.downsample
            x = torch.from_numpy(ds.normalize(features[:T]))[None]
            arrays[key] = vq.encode(x)[0].numpy().astype(np.int16)
    # a file object, so np.savez does not append ".npz" to the temporary name
    return write_atomic(path, lambda f: np.savez(f, vq_step=np.array(payload["train"]["step"]), **arrays))


def _caption_table(data: Path, out: Path, encoder_name: str):
    """All captions of all splits embedded once, cached on disk."""
    encoder = CachedTextEncoder(get_text_encoder(encoder_name), out / "captions.npz")
    table = {}
    for split in ("train", "val", "test"):
        for it in MotionDataset.load(data, split).items:
            table[(split, it.clip_id)] = it.captions
    flat = sorted({c for caps in table.values() for c in caps})
    emb = dict(zip(flat, encoder.encode(flat).numpy()))
    encoder.save()
    return table, emb, encoder.dim


# -----------------------------------------------------------------------------
# RQHC-Transformer

def _clip_examples(seqs, caps, emb, rng, n, cfg, by_length=None) -> list:
    """Whole clips: ([BOS, t...], [t..., END]) with one of the clip's captions. With `by_length` (indices sorted by
    length) the clips are a random run of similar lengths, so little compute goes to padding."""
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
        out.append((emb[c[rng.integers(len(c))]], tin, tgt))
    return out


def _window_examples(timelines, emb, rng, n, cfg, streaming) -> list:
    """Streaming windows, the contexts an endless stream refreshes to (mogo_runtime.decoding.EndlessLoop): the
    prompt prefix of one timed segment of a long sequence, then 1 to window + refresh of that segment's tokens,
    ending anywhere in it, so the context often begins mid-action rather than where a motion starts. All are
    targets; no END (the data's action does not end there, it changes). The stream keeps nothing across a prompt
    switch, so windows never reach into the previous segment."""
    out = []
    for _ in range(n):
        seq, segments = timelines[rng.integers(len(timelines))]
        first, stop, captions = segments[rng.integers(len(segments))]
        end = int(rng.integers(first, stop))                     # the last target
        start = max(first, end + 1 - int(rng.integers(1, streaming.window + streaming.refresh + 1)))
        tin = np.concatenate([np.full((1, cfg.num_levels), cfg.bos_id), seq[start:end]])
        out.append((emb[captions[rng.integers(len(captions))]], tin, seq[start:end + 1]))
    return out


def _pad(examples, cfg):
    """-> (text (B, text_dim), tokens_in (B, S, L), targets (B, S, L), lengths (B,)), PAD-filled on the right."""
    lengths = np.array([len(tgt) - 1 for _, _, tgt in examples])
    S, L = lengths.max() + 1, cfg.num_levels
    tin = np.full((len(examples), S, L), cfg.pad_id, np.int64)
    tgt = np.full((len(examples), S, L), cfg.pad_id, np.int64)
    for b, (_, i, t) in enumerate(examples):
        tin[b, :len(i)], tgt[b, :len(t)] = i, t
    text = np.stack([e for e, _, _ in examples]).astype(np.float32)
    return torch.from_numpy(text), torch.from_numpy(tin), torch.from_numpy(tgt), torch.from_numpy(lengths)


def _token_units(timeline, tokens: np.ndarray, downsample: int):
    """A timeline's segments in tokens: (tokens, [(first, stop, captions)]), segments shorter than a token dropped."""
    segs = [(seg.first // downsample, min(len(tokens), seg.stop // downsample), seg.captions)
            for seg in timeline.segments]
    return tokens, [(a, b, c) for a, b, c in segs if a < b]


def train_transformer(data: Path, out: Path, preset: str = DEFAULT, seed: int = 0, progress: bool = True,
                      schedule: Schedule | None = None, text_encoder: str | None = None, **overrides) -> Path:
    """`preset`: a name in mogo_export.presets; `schedule`, `text_encoder` and `overrides` (TransformerConfig
    fields) replace its values. Levels, codes and text_dim always come from the trained VQ and the encoder."""
    path = out / "transformer.pt"
    if _is_done(path, "transformer"):
        return path
    pset = get_preset(preset)
    sched = schedule or pset.transformer_schedule
    text_encoder = text_encoder or pset.text_encoder
    vq_payload = read_checkpoint(out / "vq.pt", "vq")
    vq_cfg = vq_payload["config"]
    table, emb, text_dim = _caption_table(data, out, text_encoder)
    with np.load(extract_tokens(data, out, progress)) as z:
        tokens = {k: z[k].astype(np.int64) for k in z.files if "/" in k}

    def split(name):
        keys = sorted(k for k in tokens if k.startswith(name + "/"))
        return [tokens[k] for k in keys], [table[(name, k.split("/", 1)[1])] for k in keys]

    seqs, caps = split("train")
    val_seqs, val_caps = split("val")
    streaming = pset.streaming
    timelines = [_token_units(t, tokens[f"timeline/train/{t.clip_id}"], vq_cfg["downsample"])
                 for t in read_timelines(data, "train")]
    timelines = [t for t in timelines if t[1]]
    n_window = streaming.windows if timelines else 0
    by_length = np.argsort([len(q) for q in seqs], kind="stable")
    max_tokens = max(len(s) for s in seqs)
    cfg = pset.transformer_config(num_levels=vq_cfg["num_levels"], codebook_size=vq_cfg["codebook_size"],
                                  text_dim=text_dim, **overrides)
    torch.manual_seed(seed)
    model = tmodel.RQHCTransformer(cfg)
    decay = [p for n, p in model.named_parameters() if p.dim() >= 2]
    no_decay = [p for n, p in model.named_parameters() if p.dim() < 2]
    opt = torch.optim.AdamW([{"params": decay, "weight_decay": 0.01}, {"params": no_decay, "weight_decay": 0.0}],
                            lr=sched.lr, betas=(0.9, 0.99))
    start, rng, val_state = _resume(path, "transformer", model, opt)
    rng = rng or np.random.default_rng(seed)
    val_rng = np.random.default_rng(seed + 1)
    if val_state is not None:      # else a fresh one: an old checkpoint resumes, its later val metrics differ
        val_rng.bit_generator.state = val_state
    # the fields checkpoint.load_trained requires (checkpoint.TRANSFORMER_META), plus the run's own record
    meta = {"text_encoder": text_encoder, "max_tokens": int(max_tokens * 1.25) + 1, "dataset": str(data),
            "preset": preset, "vq_step": vq_payload["train"]["step"],
            # trained for endless streams only when the data has timelines to learn prompt switches from
            **({"streaming": {"window": streaming.window, "refresh": streaming.refresh}} if n_window else {})}
    bar = tqdm(range(start, sched.steps), initial=start, total=sched.steps, desc="transformer", disable=not progress)
    t0, ntok = time.perf_counter(), 0
    for step in bar:
        model.train()
        _set_lr(opt, sched.lr_at(step))
        # clips and streaming windows as two batches: each is padded to its own longest example only
        batches = [_pad(_clip_examples(seqs, caps, emb, rng, sched.batch_size, cfg, by_length), cfg)]
        if n_window:
            batches.append(_pad(_window_examples(timelines, emb, rng, n_window, cfg, streaming), cfg))
        parts = [model.loss(*b) for b in batches]
        count = sum(st["count"] for _, st in parts)
        loss = sum(part * st["count"] for part, st in parts) / count          # the mean over every target
        stats = {"acc": sum(st["acc"] * st["count"] for _, st in parts) / count}
        lengths = torch.cat([b[3] for b in batches])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        ntok += int((lengths + 1).sum()) * cfg.num_levels
        bar.set_postfix(loss=f"{loss.item():.3f}", acc=f"{stats['acc'].item():.3f}",
                        tok_s=f"{ntok / (time.perf_counter() - t0):.0f}")
        last = step + 1 == sched.steps
        if ((step + 1) % sched.val_every == 0 or last) and val_seqs:
            model.eval()
            with torch.no_grad():
                vloss, vstats = model.loss(*_pad(_clip_examples(val_seqs, val_caps, emb, val_rng, 64, cfg), cfg))
            meta["val"] = {"loss": vloss.item(), "acc": vstats["acc"].item()}
            bar.write(f"transformer step {step + 1}: val loss {vloss.item():.3f}, acc {vstats['acc'].item():.3f}")
        if (step + 1) % sched.ckpt_every == 0 or last:
            save_checkpoint(path, "transformer", cfg, model, _train_state(step + 1, opt, rng, last, val_rng), meta)
    return path


def train_all(data: Path, out: Path, preset: str = DEFAULT, seed: int = 0, progress: bool = True) -> Path:
    get_preset(preset)  # an unknown name fails here, before any work
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    train_vq(data, out, preset, seed, progress)
    t1 = time.perf_counter()
    train_transformer(data, out, preset, seed, progress)
    t2 = time.perf_counter()
    print(f"trained {preset} in {out}: vq {t1 - t0:.0f} s, transformer {t2 - t1:.0f} s")
    return out
