"""The control adapter: what a steered character learns that a text-only one must not (models/transformer.py,
ControlAdapter).

    train_adapter(Path("data/procedural"), Path("checkpoints/base"), "base")   # train_all's phase after distilling

A model that follows a future root trajectory learns to follow its speed, and to stop, only from data where the
caption does not already say so: walks and runs that stop or change pace while their caption names only the walk
(the dataset's control sequences, paths.CONTROL_KINDS). Trained into the transformer itself, even only ever with
their control, they made text-only walks stop unasked: a "walks forward" stream stood in 46-48% of its seconds
against 17-22% (benchmarks/NOTES.md, "stops and speed changes the caption does not name"). So the transformer and
its distillation never see them, and afterwards a small adapter after each block learns them, with every sample
shown its own future root and every other weight frozen: a step without control adds exactly zero, so text-only
streams keep their tokens bit for bit.

transformer.pt is replaced, atomically, by the model with its adapters and meta["adapter"]; a finished run is
skipped, an interrupted one starts over (681 s for `base` on a 2-core CPU).
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .checkpoint import build_from_checkpoint, read_checkpoint, save_checkpoint
from .data.dataset import read_control_only
from .distributed import native_bf16
from .examples import caption_table, clip_examples, load_token_data, pad_examples, to_model, window_examples
from .models import transformer as tmodel
from .presets import get_preset


def is_adapted(payload: dict) -> bool:
    return "adapter" in payload["meta"]


def train_adapter(data: Path, out: Path, preset: str, seed: int = 0, progress: bool = True,
                  device: torch.device | None = None) -> Path | None:
    """The preset's control adapter (None: it has none) on out/transformer.pt, on `device` (default: the CPU).
    Returns the path."""
    pset = get_preset(preset)
    plan, path = pset.adapter, out / "transformer.pt"
    if plan is None:
        return None
    base, cfg, payload = build_from_checkpoint(path, "transformer", tmodel.TransformerConfig, tmodel.RQHCTransformer)
    if is_adapted(payload):
        return path
    if not read_control_only(data):  # measured: without them the adapter reached fewer waypoints than none
        print(f"control adapter: {data} has no control sequences (dataset.json \"control_only\"), skipped")
        return None
    if not cfg.control_dim:
        raise ValueError(f"preset {preset!r}: a control adapter needs a model with control (control_horizon > 0)")
    if pset.distill is not None and "distilled" not in payload["meta"]:
        raise RuntimeError(f"{path}: not distilled yet; the adapter trains on the distilled model")
    cfg = dataclasses.replace(cfg, adapter_dim=plan.dim)
    torch.manual_seed(seed)
    model = tmodel.RQHCTransformer(cfg)
    missing, unexpected = model.load_state_dict(base.state_dict(), strict=False)
    assert not unexpected and all(k.startswith("adapters.") for k in missing), (missing, unexpected)
    model.to(device or torch.device("cpu"))
    model.eval()  # no dropout, no condition or control dropout: the frozen model as a sampler runs it
    for name, p in model.named_parameters():
        p.requires_grad_(name.startswith("adapters."))
    params = [p for p in model.parameters() if p.requires_grad]

    table, emb, _ = caption_table(data, out, payload["meta"]["text_encoder"], write=False)
    downsample = read_checkpoint(out / "vq.pt", "vq")["config"]["downsample"]
    d = load_token_data(data, out / "tokens.npz", table, emb, cfg, downsample, control_sequences=True)
    if not any(d.seq_control_only):
        raise ValueError(f"{data} has no control sequences in its train split (dataset.json \"control_only\"; "
                         f"the procedural generator writes them from version 6): the adapter has nothing to learn")
    if plan.control_repeat > 1:  # the control sequences drawn as often as control_repeat copies of them would be
        def more(items, marks):
            return items + [x for x, m in zip(items, marks) if m] * (plan.control_repeat - 1)
        d = dataclasses.replace(
            d, seqs=more(d.seqs, d.seq_control_only), caps=more(d.caps, d.seq_control_only),
            controls=more(d.controls, d.seq_control_only), timelines=more(d.timelines, d.timeline_control_only),
            timeline_controls=more(d.timeline_controls, d.timeline_control_only))
    dev = next(model.parameters()).device
    precision = "bf16" if plan.bf16 and native_bf16(dev) else "fp32"
    rng, by_length = np.random.default_rng(seed), d.by_length
    t0 = time.perf_counter()

    # every sample steered by its own future root. (A second phase guided toward the control, as the distillation
    # guides it, reached as many waypoints but cost the text: benchmarks/NOTES.md, "the sweep".)
    opt = torch.optim.AdamW(params, lr=plan.lr, betas=(0.9, 0.99), weight_decay=0.0)
    bar = tqdm(range(plan.steps), desc=f"control adapter ({precision})", disable=not progress)
    for step in bar:
        for g in opt.param_groups:  # 50 steps of warm-up, then a cosine to zero
            g["lr"] = plan.lr * min(1.0, (step + 1) / 50) * 0.5 * (1 + np.cos(np.pi * step / plan.steps))
        examples = clip_examples(d.seqs, d.caps, emb, rng, plan.batch_size, cfg, by_length, d.controls)
        if d.timelines and plan.windows:
            examples += window_examples(d.timelines, emb, rng, plan.windows, cfg, pset.streaming,
                                        d.timeline_controls)
        text, tokens_in, targets, lengths, control = (to_model(model, t) for t in pad_examples(examples, cfg))
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
            loss = model.loss(text, tokens_in, targets, lengths, control)[0]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        bar.set_postfix(loss=f"{loss.item():.3f}")
    meta = {**payload["meta"], "adapter": {**dataclasses.asdict(plan), "precision": precision}}
    saved = save_checkpoint(path, "transformer", cfg, model.cpu(), payload["train"], meta)
    if progress:
        print(f"trained the control adapter ({precision}) into {path} in {time.perf_counter() - t0:.0f} s")
    return saved
