"""Guidance distillation: the transformer's conditional row taught what classifier-free guidance gives, so a runtime
samples with one step row per token instead of two (docs/bundle.md, "Sampling").

    distill_transformer(Path("data/procedural"), Path("checkpoints/base"), "base")   # train_all's last phase

The teacher is the trained transformer (transformer.pt), frozen. On the training data's token sequences (whole
clips and streaming windows, teacher-forced, as training draws them: examples.py), every (step, level)
distribution of the student's conditional row is pulled to the teacher's guided one, softmax(l_u + g (l_c - l_u)),
by KL(guided || student), and its unconditional row (the all-zero text) to the teacher's own, so guidance on top of
the distilled model still sharpens what it did. A model with control sees its clip's own future root on a share of
the samples (none on the rest), and there the guided logits are also guided toward the control, as the text is:
G0 + g_c (Gc - G0), with Gc and G0 the text-guided logits with and without it. The teacher reads its control only
weakly, and guiding it so at sampling time needs a second row; distilled at g_c 3, the one row steers about as two
rows at 2 did (benchmarks/NOTES.md, "guidance toward the control"). The student starts as the teacher.
transformer.pt is then replaced, atomically, by the student with meta["distilled"] (the guidance it learned, its
steps); the teacher is kept as transformer.teacher.pt. An interrupted run starts over from the teacher (a few
minutes); a finished one is skipped.

Measured on base (67 families, held-out captions, int8, top_p 0.8, 1 seed; the preset's comments): guidance 1 on
the teacher 0.790 of whole clips; guidance 2 0.846 (two rows). Condition Contrastive Alignment (CCA: sequence
log-likelihood ratios, matched vs shuffled captions, beta 0.02, lambda 10, 100 steps) went down to 0.764, and
streams' spans worse; this distillation went up (preset).
"""
from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from mogo_runtime.outputs.files import write_atomic

from .checkpoint import build_from_checkpoint, read_checkpoint, save_checkpoint
from .distributed import native_bf16
from .examples import caption_table, clip_examples, load_token_data, pad_examples, to_model, window_examples
from .models import transformer as tmodel
from .presets import get_preset

TEACHER = "transformer.teacher.pt"


def guided_kl(student: tmodel.RQHCTransformer, teacher: tmodel.RQHCTransformer, text: torch.Tensor,
              tokens_in: torch.Tensor, lengths: torch.Tensor, guidance: float, uncond_weight: float,
              control: torch.Tensor | None = None, control_guidance: float = 1.0) -> torch.Tensor:
    """KL(teacher guided || student conditional) + uncond_weight x KL(teacher uncond || student uncond), averaged
    over the valid (step, level) pairs (the first length + 1 steps). Both rows read `control` (B, S, control_dim;
    None or a sample's all-zero rows: no control). A sample with control is guided toward it too: its target is
    G0 + control_guidance (Gc - G0), Gc and G0 the text-guided logits with and without its control."""
    B, S, L = tokens_in.shape
    valid = (torch.arange(S, device=tokens_in.device) <= lengths.unsqueeze(1)).unsqueeze(-1).expand(B, S, L)
    valid = valid.to(text.dtype)
    zero = torch.zeros_like(text)
    with torch.no_grad():
        full = tmodel.at_least_float32        # bf16 logits under autocast; the distributions in float32

        def text_guided(t, tokens, ctrl):
            """-> (the teacher's text-guided logits, its unconditional ones)."""
            cond, uncond = full(teacher(t, tokens, ctrl)), full(teacher(torch.zeros_like(t), tokens, ctrl))
            return uncond + guidance * (cond - uncond), uncond

        guided, uncond = text_guided(text, tokens_in, control)
        steered = control.abs().sum((1, 2)) > 0 if control is not None else None
        if control_guidance != 1.0 and steered is not None and steered.any():
            free, _ = text_guided(text[steered], tokens_in[steered], None)
            guided[steered] = free + control_guidance * (guided[steered] - free)
        targets = [torch.log_softmax(guided, -1)]
        if uncond_weight:
            targets.append(torch.log_softmax(uncond, -1))
    rows = [(text, targets[0], 1.0)] + ([(zero, targets[1], uncond_weight)] if uncond_weight else [])
    loss = text.new_zeros(())
    for t, target, weight in rows:
        kl = F.kl_div(torch.log_softmax(tmodel.at_least_float32(student(t, tokens_in, control)), -1), target,
                      log_target=True, reduction="none").sum(-1)
        loss = loss + weight * (kl * valid).sum() / valid.sum()
    return loss


def is_distilled(out: Path) -> bool:
    path = out / "transformer.pt"
    return path.exists() and "distilled" in read_checkpoint(path, "transformer")["meta"]


def distill_transformer(data: Path, out: Path, preset: str, seed: int = 0, progress: bool = True,
                        device: torch.device | None = None) -> Path | None:
    """The preset's guidance distillation (None: it has none) of out/transformer.pt, on `device` (default: the
    CPU). Returns the path."""
    plan = get_preset(preset).distill
    path = out / "transformer.pt"
    if plan is None:
        return None
    if is_distilled(out):
        return path
    teacher, cfg, payload = build_from_checkpoint(path, "transformer", tmodel.TransformerConfig, tmodel.RQHCTransformer)
    teacher.to(device or torch.device("cpu"))
    if not payload["train"].get("done"):
        raise RuntimeError(f"{path}: the transformer has not finished training; distil it once it has")
    write_atomic(out / TEACHER, lambda f: f.write(path.read_bytes()))     # never half a file, if killed
    vq_payload = read_checkpoint(out / "vq.pt", "vq")
    table, emb, _ = caption_table(data, out, payload["meta"]["text_encoder"], write=False)
    d = load_token_data(data, out / "tokens.npz", table, emb, cfg, vq_payload["config"]["downsample"])
    streaming = get_preset(preset).streaming
    student = copy.deepcopy(teacher)
    for p in teacher.parameters():
        p.requires_grad_(False)
    # eval mode: no condition dropout and no dropout, so both rows are the ones a sampler runs
    student.eval()
    opt = torch.optim.AdamW(student.parameters(), lr=plan.lr, betas=(0.9, 0.99), weight_decay=0.0)
    rng, by_length = np.random.default_rng(seed), d.by_length
    torch.manual_seed(seed)
    device = next(student.parameters()).device
    precision = "bf16" if plan.bf16 and native_bf16(device) else "fp32"
    what = f"guidance {plan.guidance:g}" + (f", control {plan.control_guidance:g}" if cfg.control_dim else "")
    bar = tqdm(range(plan.steps), desc=f"distil {what} ({precision})", disable=not progress)
    t0 = time.perf_counter()
    for _ in bar:
        examples = clip_examples(d.seqs, d.caps, emb, rng, plan.batch_size, cfg, by_length, d.controls)
        if d.timelines and plan.windows:
            examples += window_examples(d.timelines, emb, rng, plan.windows, cfg, streaming, d.timeline_controls)
        batch = pad_examples(examples, cfg)
        text, tokens_in, _, lengths = (to_model(student, t) for t in batch[:4])
        control = None
        if cfg.control_dim:     # each sample's own future root for a control_share of them, none for the rest
            steered = torch.from_numpy(rng.random(len(examples)) < plan.control_share).to(batch[4].dtype)
            control = to_model(student, batch[4] * steered[:, None, None])
        # the weights and the optimizer stay float32; autocast runs the matrix products in bf16
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
            loss = guided_kl(student, teacher, text, tokens_in, lengths, plan.guidance, plan.uncond_weight,
                             control, plan.control_guidance)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(student.parameters(), 1.0)
        opt.step()
        bar.set_postfix(kl=f"{loss.item():.4f}")
    # no timing in the meta: a resumed run must write the uninterrupted run's file (tests/export/test_train_kill9.py)
    meta = {**payload["meta"], "distilled": {"guidance": plan.guidance, "steps": plan.steps, "lr": plan.lr,
                                             "uncond_weight": plan.uncond_weight, "precision": precision,
                                             "control_guidance": plan.control_guidance,
                                             "control_share": plan.control_share}}
    saved = save_checkpoint(path, "transformer", cfg, student, payload["train"], meta)
    if progress:
        print(f"distilled {what} ({precision}) into {path} in {time.perf_counter() - t0:.0f} s")
    return saved
