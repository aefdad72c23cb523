"""Training: MoSA-VQ on motion windows, token extraction, then the RQHC-Transformer on (caption, tokens).

    python -m mogo_export.cli train --data data/procedural --out checkpoints/base --preset base

writes `vq.pt`, `tokens.npz`, `captions.npz` (cached caption embeddings) and `transformer.pt` into --out.
Each phase shows a progress bar (loss, throughput, ETA), validates periodically, checkpoints atomically, and
resumes from its checkpoint after an interruption (a kill -9 included: files are written as mogo_runtime/files.py
says, so the folder holds only whole files); a finished phase is skipped on the next run. A resumed run ends with
the same weights, bit for bit, as an uninterrupted one with the same torch thread count: the checkpoint holds the
optimiser and every RNG the next steps draw from (_train_state); tests/export/test_train_kill9.py checks it.

Under torchrun the same functions train data-parallel on several processes or GPUs (mogo_export/distributed.py:
each process trains on its slice of the same global batch; rank 0 validates, prints and writes files), and a
checkpoint does not depend on the number of processes that wrote it; tests/export/test_distributed.py checks it.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from mogo_runtime.control.vector import root_poses
from mogo_runtime.kinematics.features import recover_from_ric
from mogo_runtime.kinematics.skeleton import get_skeleton
from mogo_runtime.outputs.files import write_atomic

from .checkpoint import build_from_checkpoint, read_checkpoint, save_checkpoint
from .data.dataset import MotionDataset
from .data.timelines import read_timelines
from .adapter import train_adapter
from .distill import distill_transformer
from .distributed import SINGLE, Group, native_bf16
from .examples import (ROOT, caption_table, clip_examples, load_token_data, pad_examples, to_model,
                       window_examples)
from .models import transformer as tmodel
from .models import vq as vqmodel
from .presets import DEFAULT, Schedule, get_preset  # Schedule stays importable as train.Schedule


def _set_lr(opt, lr):
    for g in opt.param_groups:
        g["lr"] = lr


def _device(opt) -> torch.device:
    return opt.param_groups[0]["params"][0].device


def _cpu(obj):
    if isinstance(obj, torch.Tensor):
        return obj.cpu()
    if isinstance(obj, dict):
        return {k: _cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_cpu(v) for v in obj)
    return obj


def _log_step(path: Path | None, group: Group, **fields) -> None:
    """One JSON line per optimiser step, by rank 0: the global batch's loss and metrics (`--loss-log`)."""
    if path is not None and group.is_main:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        with open(path, "a") as f:
            f.write(json.dumps(fields) + "\n")


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
    if "cuda_rng" in train and _device(opt).type == "cuda":
        torch.cuda.set_rng_state(train["cuda_rng"], _device(opt))
    rng = np.random.default_rng()
    rng.bit_generator.state = train["numpy_rng"]
    return int(train["step"]), rng, train.get("val_rng")


def _train_state(step, opt, rng, done: bool, val_rng: np.random.Generator | None = None) -> dict:
    """Everything the next steps depend on besides the weights: with it a resumed run takes the same steps, on
    the same batches, with the same validation batches, as one that was never interrupted (bit for bit, at the
    same torch thread count)."""
    state = {"step": step, "optimizer": opt.state_dict(), "torch_rng": torch.get_rng_state(),
             "numpy_rng": rng.bit_generator.state, "done": done}
    if _device(opt).type == "cuda":
        # the optimiser's state comes to the CPU, so the checkpoint loads anywhere; on a GPU the VQ's codebook
        # seeding and resets (and dropout) draw from its own RNG
        state["optimizer"] = _cpu(state["optimizer"])
        state["cuda_rng"] = torch.cuda.get_rng_state(_device(opt))
    if val_rng is not None:
        state["val_rng"] = val_rng.bit_generator.state
    return state


def _is_done(path: Path, kind: str, group: Group = SINGLE) -> bool:
    """A finished checkpoint is kept as it is: training skips it (and says so)."""
    done = path.exists() and bool(read_checkpoint(path, kind)["train"].get("done"))
    if done and group.is_main:
        print(f"{kind}: {path} is complete, skipping (delete it to retrain)")
    return done


# -----------------------------------------------------------------------------
# MoSA-VQ

def _crops(clips: list[np.ndarray], rng, batch: int, window: int, rows: slice = slice(None)) -> torch.Tensor:
    """`batch` random crops are drawn; -> those of `rows` (a process's slice of the global batch)."""
    keep = range(batch)[rows]
    out = np.empty((len(keep), window, clips[0].shape[1]), np.float32)
    for i, c in enumerate(rng.integers(len(clips), size=batch)):
        clip = clips[c]
        start = rng.integers(len(clip) - window + 1)
        if i in keep:
            out[i - keep.start] = clip[start:start + window]
    return torch.from_numpy(out)


@torch.no_grad()
def evaluate_vq(vq: vqmodel.MoSAVQ, clips: list[np.ndarray], mean: np.ndarray, std: np.ndarray,
                num_joints: int = 22) -> dict:
    """Reconstruction of whole clips: mean per-joint position error (mm) and normalised L1."""
    vq.eval()
    ds, errs, l1 = vq.cfg.downsample, [], []
    for clip in clips:
        T = len(clip) // ds * ds
        x = to_model(vq, torch.from_numpy(clip[None, :T]))
        recon = vq.decode_indices(vq.encode(x))[0].cpu().numpy()
        l1.append(np.abs(recon - clip[:T]).mean())
        gt = recover_from_ric(clip[:T] * std + mean, num_joints)
        pred = recover_from_ric(recon * std + mean, num_joints)
        errs.append(np.linalg.norm(gt - pred, axis=-1).mean() * 1000)
    return {"mpjpe_mm": float(np.mean(errs)), "l1": float(np.mean(l1))}


def train_vq(data: Path, out: Path, preset: str = DEFAULT, seed: int = 0, progress: bool = True,
             schedule: Schedule | None = None, group: Group = SINGLE, loss_log: Path | None = None,
             **overrides) -> Path:
    """`preset`: a name in mogo_export.presets; `schedule` and `overrides` (VQConfig fields) replace its values.
    `group`: this process's place in a torchrun run (mogo_export.distributed); `loss_log`: a JSON-lines file that
    each step's loss is appended to."""
    path = out / "vq.pt"
    if _is_done(path, "vq", group):
        return path
    pset = get_preset(preset)
    sched = schedule or pset.vq_schedule
    rows = group.shard(sched.batch_size, "vq batch")
    train_ds, val_ds = MotionDataset.load(data, "train"), MotionDataset.load(data, "val")
    num_joints = get_skeleton(train_ds.skeleton).num_joints
    cfg = pset.vq_config(input_dim=int(train_ds.mean.shape[0]), **overrides)
    mean, std = train_ds.mean, train_ds.std
    clips = [train_ds.normalize(it.features) for it in train_ds.items if len(it.features) >= sched.window]
    val_clips = [val_ds.normalize(it.features) for it in val_ds.items][:64]
    if not clips:
        raise ValueError(f"{data}: no training clip has {sched.window} frames or more")

    torch.manual_seed(seed)
    vq = vqmodel.MoSAVQ(cfg).to(group.device)
    opt = torch.optim.AdamW(vq.parameters(), lr=sched.lr, betas=(0.9, 0.99), weight_decay=0.0)
    start, rng, _ = _resume(path, "vq", vq, opt)      # VQ validation uses whole clips: no RNG
    rng = rng or np.random.default_rng(seed)
    vq.quantizer.sync = group if group.world > 1 else None
    net = group.wrap(vq)
    # the fields checkpoint.load_trained requires (checkpoint.VQ_META), plus the run's own record
    meta = {"mean": mean.tolist(), "std": std.tolist(), "fps": train_ds.fps, "dataset": str(data), "preset": preset,
            "skeleton": train_ds.skeleton}
    bar = tqdm(range(start, sched.steps), initial=start, total=sched.steps, desc="vq",
               disable=not (progress and group.is_main))
    t0, frames = time.perf_counter(), 0
    for step in bar:
        net.train()
        _set_lr(opt, sched.lr_at(step))
        x = to_model(vq, _crops(clips, rng, sched.batch_size, sched.window, rows))
        _, terms = net(x)
        opt.zero_grad(set_to_none=True)
        # each process's loss is the mean over its slice, and the slices are the same size: the gradients that
        # DistributedDataParallel averages are those of the global batch's mean
        terms["loss"].backward()
        torch.nn.utils.clip_grad_norm_(vq.parameters(), 1.0)
        opt.step()
        frames += sched.batch_size * x.shape[1]
        loss, rec = group.mean(torch.stack([terms["loss"].detach(), terms["recon"]])).tolist()
        _log_step(loss_log, group, phase="vq", step=step + 1, loss=loss, recon=rec)
        bar.set_postfix(loss=f"{loss:.4f}", rec=f"{rec:.4f}", ppl=f"{terms['perplexity'].mean().item():.0f}",
                        fps=f"{frames / (time.perf_counter() - t0):.0f}")
        last = step + 1 == sched.steps
        if group.is_main and ((step + 1) % sched.val_every == 0 or last):
            meta["val"] = evaluate_vq(vq, val_clips, mean, std, num_joints)
            bar.write(f"vq step {step + 1}: val MPJPE {meta['val']['mpjpe_mm']:.1f} mm, L1 {meta['val']['l1']:.4f}")
        if (step + 1) % sched.ckpt_every == 0 or last:
            if group.is_main:    # every process holds the same weights, optimiser and RNG states
                save_checkpoint(path, "vq", cfg, vq, _train_state(step + 1, opt, rng, last), meta)
            group.barrier()      # nobody reads or resumes from a checkpoint still being written
    return path


# -----------------------------------------------------------------------------
# tokens and captions

TOKENS_FORMAT = 2    # 2: each clip's root poses beside its tokens (ROOT + key), for control


@torch.no_grad()
def extract_tokens(data: Path, out: Path, progress: bool = True, device: torch.device | None = None) -> Path:
    """Run the trained VQ over every clip of every split once; the transformer trains on these tokens, and on
    each clip's root poses (its control targets)."""
    path = out / "tokens.npz"
    vq, cfg, payload = build_from_checkpoint(out / "vq.pt", "vq", vqmodel.VQConfig, vqmodel.MoSAVQ)
    if path.exists():
        with np.load(path) as z:
            if str(z["vq_step"]) == str(payload["train"]["step"]) and "format" in z.files \
                    and int(z["format"]) == TOKENS_FORMAT:
                return path
    vq.to(device or torch.device("cpu"))
    arrays = {}
    for split in ("train", "val", "test"):
        ds = MotionDataset.load(data, split, control_sequences=True)     # the control adapter's tokens too
        whole = [(f"timeline/{split}/{t.clip_id}", t.features)
                 for t in read_timelines(data, split, ds.skeleton, control_sequences=True)]
        items = [(f"{split}/{it.clip_id}", it.features) for it in ds.items] + whole
        for key, features in tqdm(items, desc=f"tokens {split}", disable=not progress):
            T = len(features) // cfg.downsample * cfg.downsample
            x = to_model(vq, torch.from_numpy(ds.normalize(features[:T]))[None])
            arrays[key] = vq.encode(x)[0].cpu().numpy().astype(np.int16)
            arrays[ROOT + key] = root_poses(features[:T]).astype(np.float32)    # what control is trained on
    # a file object, so np.savez does not append ".npz" to the temporary name
    return write_atomic(path, lambda f: np.savez(f, vq_step=np.array(payload["train"]["step"]),
                                                 format=np.array(TOKENS_FORMAT), **arrays))


# -----------------------------------------------------------------------------
# RQHC-Transformer

class _BatchLosses(torch.nn.Module):
    """The model's loss on each batch of a step in one forward call: DistributedDataParallel reduces the
    gradients of what one forward computed."""

    def __init__(self, model: tmodel.RQHCTransformer):
        super().__init__()
        self.model = model

    def forward(self, batches):
        return [self.model.loss(*b) for b in batches]


def train_transformer(data: Path, out: Path, preset: str = DEFAULT, seed: int = 0, progress: bool = True,
                      schedule: Schedule | None = None, text_encoder: str | None = None, group: Group = SINGLE,
                      loss_log: Path | None = None, **overrides) -> Path:
    """`preset`: a name in mogo_export.presets; `schedule`, `text_encoder` and `overrides` (TransformerConfig
    fields) replace its values. Levels, codes and text_dim always come from the trained VQ and the encoder.
    `group` and `loss_log` as in train_vq."""
    path = out / "transformer.pt"
    if _is_done(path, "transformer", group):
        return path
    pset = get_preset(preset)
    sched = schedule or pset.transformer_schedule
    rows = group.shard(sched.batch_size, "transformer batch")
    text_encoder = text_encoder or pset.text_encoder
    vq_payload = read_checkpoint(out / "vq.pt", "vq")
    vq_cfg = vq_payload["config"]
    with group.main_first():     # rank 0 embeds and extracts; the others read its files
        table, emb, text_dim = caption_table(data, out, text_encoder, write=group.is_main)
        tokens_path = extract_tokens(data, out, progress and group.is_main, group.device)
    cfg = pset.transformer_config(num_levels=vq_cfg["num_levels"], codebook_size=vq_cfg["codebook_size"],
                                  text_dim=text_dim, **overrides)
    d = load_token_data(data, tokens_path, table, emb, cfg, vq_cfg["downsample"])
    seqs, caps, seq_controls = d.seqs, d.caps, d.controls
    val_seqs, val_caps, val_controls = d.val_seqs, d.val_caps, d.val_controls
    timelines, timeline_controls = d.timelines, d.timeline_controls
    streaming = pset.streaming
    n_window = streaming.windows if timelines else 0
    # the loss weighs each slice by its targets, so slices of windows need not be the same size
    window_rows = group.part(n_window)
    by_length = d.by_length
    max_tokens = max(len(s) for s in seqs)
    torch.manual_seed(seed)
    model = tmodel.RQHCTransformer(cfg).to(group.device)
    decay = [p for n, p in model.named_parameters() if p.dim() >= 2]
    no_decay = [p for n, p in model.named_parameters() if p.dim() < 2]
    opt = torch.optim.AdamW([{"params": decay, "weight_decay": 0.01}, {"params": no_decay, "weight_decay": 0.0}],
                            lr=sched.lr, betas=(0.9, 0.99))
    start, rng, val_state = _resume(path, "transformer", model, opt)
    rng = rng or np.random.default_rng(seed)
    val_rng = np.random.default_rng(seed + 1)
    if val_state is not None:      # else a fresh one: an old checkpoint resumes, its later val metrics differ
        val_rng.bit_generator.state = val_state
    group.fork_torch_rng(seed, start)
    net = group.wrap(_BatchLosses(model))
    # the fields checkpoint.load_trained requires (checkpoint.TRANSFORMER_META), plus the run's own record
    meta = {"text_encoder": text_encoder, "max_tokens": int(max_tokens * 1.25) + 1, "dataset": str(data),
            "preset": preset, "vq_step": vq_payload["train"]["step"],
            # trained for endless streams only when the data has timelines to learn prompt switches from
            **({"streaming": {"window": streaming.window, "refresh": streaming.refresh}} if n_window else {})}
    precision = meta["train_precision"] = "bf16" if sched.bf16 and native_bf16(group.device) else "fp32"
    bar = tqdm(range(start, sched.steps), initial=start, total=sched.steps, desc=f"transformer ({precision})",
               disable=not (progress and group.is_main))
    t0, ntok = time.perf_counter(), 0
    for step in bar:
        net.train()
        _set_lr(opt, sched.lr_at(step))
        # clips and streaming windows as two batches: each is padded to its own longest example only (of this
        # process's slice)
        clips = clip_examples(seqs, caps, emb, rng, sched.batch_size, cfg, by_length, seq_controls)[rows]
        batches = [pad_examples(clips, cfg)]
        if n_window:
            windows = window_examples(timelines, emb, rng, n_window, cfg, streaming, timeline_controls)[window_rows]
            if windows:
                batches.append(pad_examples(windows, cfg))
        batches = [tuple(to_model(model, t) for t in b) for b in batches]
        with torch.autocast(group.device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
            parts = net(batches)
        # the mean over every target of the global batch (of this process's slice: its share of that mean)
        count = group.sum(sum(st["count"] for _, st in parts))
        loss = sum(part * st["count"] for part, st in parts) / count
        stats = {"acc": group.sum(sum(st["acc"] * st["count"] for _, st in parts)) / count}
        lengths = torch.cat([b[3] for b in batches])
        opt.zero_grad(set_to_none=True)
        # slices hold different numbers of targets: DistributedDataParallel averages the gradients of the shares,
        # so world x share makes that average the gradient of the global mean
        (loss * group.world if group.world > 1 else loss).backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        ntok += int((lengths + 1).sum()) * cfg.num_levels * group.world      # for the bar: an estimate
        shown = group.sum(loss.detach()).item(), stats["acc"].item()
        _log_step(loss_log, group, phase="transformer", step=step + 1, loss=shown[0], acc=shown[1])
        bar.set_postfix(loss=f"{shown[0]:.3f}", acc=f"{shown[1]:.3f}", tok_s=f"{ntok / (time.perf_counter() - t0):.0f}")
        last = step + 1 == sched.steps
        if group.is_main and ((step + 1) % sched.val_every == 0 or last) and val_seqs:
            model.eval()
            with torch.no_grad():
                val_batch = pad_examples(clip_examples(val_seqs, val_caps, emb, val_rng, 64, cfg,
                                                       controls=val_controls), cfg)
                vloss, vstats = model.loss(*(to_model(model, t) for t in val_batch))
            meta["val"] = {"loss": vloss.item(), "acc": vstats["acc"].item()}
            bar.write(f"transformer step {step + 1}: val loss {vloss.item():.3f}, acc {vstats['acc'].item():.3f}")
        if (step + 1) % sched.ckpt_every == 0 or last:
            if group.is_main:
                save_checkpoint(path, "transformer", cfg, model, _train_state(step + 1, opt, rng, last, val_rng),
                                meta)
            group.barrier()
    return path


def train_all(data: Path, out: Path, preset: str = DEFAULT, seed: int = 0, progress: bool = True,
              group: Group = SINGLE, loss_log: Path | None = None) -> Path:
    pset = get_preset(preset)  # an unknown name fails here, before any work, and so does a batch of another size
    for what, sched in (("vq", pset.vq_schedule), ("transformer", pset.transformer_schedule)):
        group.shard(sched.batch_size, f"preset {preset!r}, {what}")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    train_vq(data, out, preset, seed, progress, group=group, loss_log=loss_log)
    t1 = time.perf_counter()
    train_transformer(data, out, preset, seed, progress, group=group, loss_log=loss_log)
    t2 = time.perf_counter()
    if group.is_main:    # one process: a few hundred steps on the trained model
        distill_transformer(data, out, preset, seed, progress, group.device)
        t_distill = time.perf_counter()
        train_adapter(data, out, preset, seed, progress, group.device)
    group.barrier()
    t3 = time.perf_counter()
    if group.is_main:
        print(f"trained {preset} in {out}: vq {t1 - t0:.0f} s, transformer {t2 - t1:.0f} s"
              + (f", guidance distillation {t_distill - t2:.0f} s" if pset.distill else "")
              + (f", control adapter {t3 - t_distill:.0f} s" if pset.adapter else "")
              + (f" on {group.world} processes ({group.device.type})" if group.world > 1 else ""))
    return out
