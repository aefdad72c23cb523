"""Parity verifier: does a bundle compute what its checkpoints compute? Exits non-zero on any breach.

    mogo-export verify bundles/base --checkpoints checkpoints/base

1. graphs: each ONNX graph vs its torch module on fresh random inputs, several shapes, past lengths 0, 1 and
   beyond the relative-distance clip (fp32 bar 1e-4);
2. end to end: the torch generator and the onnxruntime loop on the same prompts and seeds, greedy: identical
   token sequences and decoded joints within 0.1 mm;
3. int8 vs fp32: token agreement, logit error, decoded-joint error, text-embedding cosine. Agreement is gated
   teacher-forced: both variants step through the fp32 greedy sequence, each with its own text encoder and
   cache, and we count the (step, level) pairs where their argmaxes agree: that is what int8 changes per step.
   Free-running greedy agreement (each variant follows its own tokens) is printed too, not gated: after the
   first differing token the two runs are different motions, so it measures chaos as much as quantization;
4. endless streams (bundles trained for them): torch and ORT fp32 through one 1,000-step stream with context
   rebuilds and prompt switches: identical greedy tokens (the count of steps before the first difference);
5. the portable variant (fixed-capacity step graph): the graph against the torch step at several batches and
   positions (the written slot, the untouched slots, the logits), then 2 and 4 as for fp32: greedy tokens and
   joints of the prompts, and the 1,000-step endless stream, identical to torch;
6. ORT-format variants: greedy tokens identical to the variant each was converted from.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from mogo_runtime.bundle.folder import Bundle
from mogo_runtime.bundle.manifest import COMPACT, INT8_FIXED
from mogo_runtime.bundle.sampling import GREEDY
from mogo_runtime.control import FollowPath, Steer, Steering, WalkTo
from mogo_runtime.control.plant import legs_of
from mogo_runtime.decoding import GenerationTask, decode_tokens
from mogo_runtime.engine import FixedCache, FixedCacheBackend, OrtBackend, open_backend
from mogo_runtime.kinematics.features import recover_from_ric

from .agreement import forced_logits, teacher_forced
from .agreement import greedy_tokens as _ort_tokens
from .export.graphs import DecoderGraph, StepGraph
from .reference import TorchGenerator

PROMPTS = ("a person walks forward", "a person waves with the right hand", "someone jumps in place twice",
           "a man kicks with his left leg", "a person walks forward and then jumps", "a person squats down slowly")


@dataclass
class Thresholds:
    fp32_abs: float = 1e-4           # graph outputs, max abs error
    joints_mm: float = 0.1           # end to end fp32, max joint error
    int8_token_agreement: float = 0.95  # teacher-forced: fraction of (step, level) argmaxes equal, same history
    int8_text_cosine: float = 0.98   # int8 vs fp32 text embedding
    compact_token_agreement: float = 0.98   # the compact variant (int8-stored weights), teacher-forced, as int8's


@dataclass
class Report:
    rows: list[tuple[str, str, str, bool]] = field(default_factory=list)   # check, measured, bar, ok

    def add(self, check: str, value: float, bar: str, ok: bool, fmt: str = "{:.2e}"):
        self.rows.append((check, fmt.format(value), bar, bool(ok)))

    @property
    def ok(self) -> bool:
        return all(r[3] for r in self.rows)

    def table(self) -> str:
        w = max(len(r[0]) for r in self.rows)
        lines = [f"| {'check'.ljust(w)} | measured | bar | |", f"|{'-' * (w + 2)}|---|---|---|"]
        lines += [f"| {c.ljust(w)} | {v} | {b} | {'ok' if ok else 'BREACH'} |" for c, v, b, ok in self.rows]
        return "\n".join(lines)


def _step_feed(c, batch, steps, past, seed):
    g = torch.Generator().manual_seed(seed)
    H, hd = c.n_heads, c.d_model // c.n_heads
    text = torch.randn(batch, c.text_dim, generator=g)
    text = text / text.norm(dim=-1, keepdim=True)
    tokens = torch.randint(0, c.codebook_size, (batch, steps, c.num_levels), generator=g)
    if past == 0:
        tokens[:, 0] = c.bos_id
    pasts = [torch.randn(batch, c.num_levels * H, past, hd, generator=g) for _ in range(2 * c.n_layers)]
    # a model with control reads one more input: random, half of it "present"
    control = [torch.randn(batch, steps, c.control_dim, generator=g)] if c.control_dim else []
    return text, tokens, control, pasts


def check_graphs(gen: TorchGenerator, ort_backend: OrtBackend, report: Report, th: Thresholds) -> None:
    tr, vq = gen.backend.transformer, gen.backend.vq
    c = tr.cfg
    worst = 0.0
    for batch, steps, past in [(1, 1, 0), (2, 1, 1), (1, 1, c.max_rel_dist + 5), (3, 4, 0), (2, 2, 7)]:
        text, tokens, control, pasts = _step_feed(c, batch, steps, past, seed=batch * 97 + steps * 7 + past)
        with torch.no_grad():
            want = StepGraph(tr)(text, tokens, *control, *pasts)
        logits, presents = ort_backend.step(text.numpy(), tokens.numpy(), [p.numpy() for p in pasts],
                                            *(x.numpy() for x in control))
        err = max(np.abs(logits - want[0].numpy()).max(),
                  max(np.abs(p - w.numpy()).max() for p, w in zip(presents, want[1:])))
        report.add(f"step graph b={batch} s={steps} past={past}", err, f"< {th.fp32_abs:g}", err < th.fp32_abs)
        worst = max(worst, err)
    for batch, T in [(1, 3), (2, 17)]:
        idx = torch.randint(0, c.codebook_size, (batch, T, c.num_levels), generator=torch.Generator().manual_seed(T))
        with torch.no_grad():
            latent = vq.quantizer.lookup(idx)
            feats = DecoderGraph(vq, gen.backend.mean, gen.backend.std)(latent)
        got = ort_backend.decode(idx.numpy())
        got_latent = ort_backend.lookup(idx.numpy())
        e1, e2 = np.abs(got_latent - latent.numpy()).max(), np.abs(got - feats.numpy()).max()
        report.add(f"lookup graph b={batch} tokens={T}", e1, f"< {th.fp32_abs:g}", e1 < th.fp32_abs)
        # features are de-normalised (metres and radians scale): compare relative to their magnitude
        rel = e2 / max(1.0, float(np.abs(feats.numpy()).max()))
        report.add(f"decoder graph b={batch} tokens={T} (rel)", rel, f"< {th.fp32_abs:g}", rel < th.fp32_abs)
    texts = list(PROMPTS[:3]) + ["a person " + "walks and turns around " * 40]   # > 128 tokens
    want = gen.backend.encode_text(texts)
    got = ort_backend.encode_text(texts)
    err = np.abs(got - want).max()
    report.add("text_encoder graph (4 prompts, one > 128 tokens)", err, f"< {th.fp32_abs:g}", err < th.fp32_abs)


def _agreement(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of (step, level) tokens equal, over the longer sequence (a length mismatch counts as disagreement)."""
    n = min(len(a), len(b))
    same = (a[:n] == b[:n]).sum()
    return float(same) / max(1, max(len(a), len(b)) * a.shape[1])


def _teacher_forced(fp32: OrtBackend, other, prompts: list[str], sequences) -> tuple[float, float]:
    """Both variants stepped through each fp32 greedy sequence (agreement.py) -> (fraction of (step, level) argmaxes
    equal, max abs logit difference)."""
    return teacher_forced(forced_logits(fp32, prompts, sequences), forced_logits(other, prompts, sequences))


def check_end_to_end(gen: TorchGenerator, fp32: OrtBackend, int8, report: Report,
                     th: Thresholds, prompts=PROMPTS) -> None:
    prompts = list(prompts)
    seeds = list(range(len(prompts)))
    J = gen.skeleton.num_joints
    torch_tokens = gen.generate_tokens(prompts, seeds)
    ort_tokens = _ort_tokens(fp32, prompts, seeds, gen.max_tokens)
    identical = sum(np.array_equal(a, b) for a, b in zip(torch_tokens, ort_tokens))
    report.add(f"greedy tokens identical, torch vs ORT fp32 ({len(prompts)} prompts)", identical,
               f"= {len(prompts)}", identical == len(prompts), fmt="{:.0f}")
    tj = [recover_from_ric(f, J) for f in decode_tokens(gen.backend, torch_tokens)]
    oj = [recover_from_ric(f, J) for f in decode_tokens(fp32, ort_tokens)]
    err_mm = max((np.abs(a - b).max() * 1000 if a.shape == b.shape else np.inf) for a, b in zip(tj, oj))
    report.add("decoded joints, torch vs ORT fp32 (mm)", err_mm, f"< {th.joints_mm:g}", err_mm < th.joints_mm)
    if int8 is None:
        return
    q_tokens = _ort_tokens(int8, prompts, seeds, gen.max_tokens)
    forced, logit_err = _teacher_forced(fp32, int8, prompts, ort_tokens)
    report.add("int8 vs fp32 argmax agreement, teacher-forced (step, level)", forced,
               f">= {th.int8_token_agreement:g}", forced >= th.int8_token_agreement, fmt="{:.3f}")
    free = float(np.mean([_agreement(a, b) for a, b in zip(ort_tokens, q_tokens)]))
    report.add("int8 vs fp32 greedy tokens, free-running, position by position", free, "report", True,
               fmt="{:.3f}")
    report.add("int8 vs fp32 step logits, max abs (teacher-forced)", logit_err, "report", True)
    qj = [recover_from_ric(f, J) for f in decode_tokens(int8, q_tokens)]
    errs = [np.linalg.norm(a[:min(len(a), len(b))] - b[:min(len(a), len(b))], axis=-1).mean() * 1000
            for a, b in zip(oj, qj)]
    report.add("int8 vs fp32 decoded joints, mean per-joint error (mm)", float(np.mean(errs)), "report", True,
               fmt="{:.1f}")
    cos = float((fp32.encode_text(prompts) * int8.encode_text(prompts)).sum(-1).min())
    report.add("int8 vs fp32 text embedding cosine (min)", cos, f">= {th.int8_text_cosine:g}",
               cos >= th.int8_text_cosine, fmt="{:.4f}")


class _CountedSteps:
    """A backend that counts its step calls: an endless stream makes one per token plus one per restart."""

    def __init__(self, backend):
        self.backend, self.dims, self.calls = backend, backend.dims, 0

    def __getattr__(self, name):
        return getattr(self.backend, name)

    def step(self, *args):
        self.calls += 1
        return self.backend.step(*args)


def endless_tokens(backend, skeleton, prompts: list[str], streaming, steps: int,
                   switch_every: int) -> tuple[np.ndarray, int]:
    """Greedy tokens of one endless stream that cycles through `prompts`, switching every `switch_every` tokens
    (a timeline): -> (tokens (steps, L), restarts). Exercises restarts at END, context refreshes and switches."""
    starts = list(range(0, steps, switch_every))
    counted = _CountedSteps(backend)
    embs = backend.encode_text([prompts[k % len(prompts)] for k in range(len(starts))])
    task = GenerationTask(counted, skeleton, GREEDY, steps, steps, streaming)
    return task.timeline(embs, starts, seed=0).tokens, counted.calls - steps


def check_endless(gen: TorchGenerator, backend, streaming, report: Report, steps: int = 1000,
                  switch_every: int = 97, name: str = "ORT fp32") -> None:
    """Torch and ORT (`name`) through the same endless stream: identical greedy tokens, step by step."""
    prompts = list(PROMPTS)
    a, restarts = endless_tokens(gen.backend, gen.skeleton, prompts, streaming, steps, switch_every)
    b, _ = endless_tokens(backend, gen.skeleton, prompts, streaming, steps, switch_every)
    same = np.all(a == b, axis=1)
    first = int(np.argmin(same)) if not same.all() else steps
    report.add(f"endless stream, greedy tokens identical torch vs {name} ({steps} steps, {restarts} restarts at "
               f"END, refresh after {streaming.window + streaming.refresh}, switch every {switch_every})", first,
               f"= {steps}", first == steps, fmt="{:.0f}")


def controlled_tokens(backend, skeleton, streaming, steps: int, change_every: int = 97) -> np.ndarray:
    """Greedy tokens (steps, L) of one controlled endless stream: a new request every `change_every` tokens (a goal,
    a path, a joystick, none), and a new prompt with every second one. The control of each
    token reads the frames of the tokens before it, so this holds the decoder and the loop's bookkeeping to the
    same numbers too."""
    prompts = list(PROMPTS)
    task = GenerationTask(backend, skeleton, GREEDY, steps, steps, streaming)
    emb = backend.encode_text(prompts[:1])
    loop = task.loop(emb, [0])
    steering = Steering(backend.control, backend.dims, loop.streams[0], legs_of(skeleton))
    rng = np.random.default_rng(0)
    requests = [lambda: WalkTo(rng.uniform(-6, 6, 2), rng.uniform(0.8, 3.0)),
                lambda: FollowPath(np.cumsum(rng.uniform(-3, 3, (5, 2)), axis=0), rng.uniform(0.8, 3.0)),
                lambda: Steer(rng.uniform(-2, 2, 2), rng.uniform(-1, 1, 2)), lambda: None]
    frames = task.stream(emb, 0, 1, loop, steering)
    tokens = []
    for t in range(steps):
        if t % change_every == 0:
            target = requests[(t // change_every) % len(requests)]()
            steering.request(lambda s: target)
            if (t // change_every) % 2:
                loop.set_prompt(backend.encode_text([prompts[(t // change_every) % len(prompts)]]))
        next(frames)
        tokens.append(loop.streams[0].last.copy())
    return np.stack(tokens)


def check_controlled(gen: TorchGenerator, backend, streaming, report: Report, steps: int = 1000,
                     name: str = "ORT fp32") -> None:
    """Torch and ORT (`name`) through the same controlled endless stream: identical greedy tokens."""
    a = controlled_tokens(gen.backend, gen.skeleton, streaming, steps)
    b = controlled_tokens(backend, gen.skeleton, streaming, steps)
    same = np.all(a == b, axis=1)
    first = int(np.argmin(same)) if not same.all() else steps
    report.add(f"controlled stream, greedy tokens identical torch vs {name} ({steps} steps, a goal, path, "
               f"joystick or none every 97, prompt switches)", first, f"= {steps}", first == steps, fmt="{:.0f}")


def check_portable_graph(gen: TorchGenerator, portable: FixedCacheBackend, report: Report, th: Thresholds) -> None:
    """The fixed-capacity step against the torch step whose past is the cache's first `position` slots: the
    logits, the slot it writes, and the slots after it, which it must hand back unchanged."""
    c = gen.backend.transformer.cfg
    cap = portable.capacity
    for batch, position in [(1, 0), (2, 1), (1, 7), (3, cap // 2), (2, cap - 1)]:
        text, tokens, control, full = _step_feed(c, batch, 1, cap, seed=batch * 131 + position)
        if position == 0:
            tokens[:, 0] = c.bos_id
        with torch.no_grad():
            want = StepGraph(gen.backend.transformer)(text, tokens, *control, *(p[:, :, :position] for p in full))
        # copies: the step writes its slot into the cache in place, and `full` is what the slots are checked against
        cache = FixedCache([p.numpy().copy() for p in full], position)
        logits, cache = portable.step(text.numpy(), tokens.numpy(), cache, *(x.numpy() for x in control))
        err = max(np.abs(logits - want[0].numpy()).max(),
                  max(np.abs(p[:, :, :position + 1] - w.numpy()).max() for p, w in zip(cache.arrays, want[1:])))
        kept = all(np.array_equal(p[:, :, position + 1:], f[:, :, position + 1:].numpy())
                   for p, f in zip(cache.arrays, full))
        report.add(f"portable step graph b={batch} position={position} of {cap}" + ("" if kept else
                   " (CHANGED the slots after position)"), err, f"< {th.fp32_abs:g}", err < th.fp32_abs and kept)


def check_portable(gen: TorchGenerator, portable: FixedCacheBackend, streaming, report: Report, th: Thresholds,
                   prompts=PROMPTS) -> None:
    check_portable_graph(gen, portable, report, th)
    prompts, seeds = list(prompts), list(range(len(prompts)))
    torch_tokens = gen.generate_tokens(prompts, seeds)
    tokens = _ort_tokens(portable, prompts, seeds, gen.max_tokens)
    identical = sum(np.array_equal(a, b) for a, b in zip(torch_tokens, tokens))
    report.add(f"greedy tokens identical, torch vs ORT portable ({len(prompts)} prompts)", identical,
               f"= {len(prompts)}", identical == len(prompts), fmt="{:.0f}")
    J = gen.skeleton.num_joints
    tj = [recover_from_ric(f, J) for f in decode_tokens(gen.backend, torch_tokens)]
    pj = [recover_from_ric(f, J) for f in decode_tokens(portable, tokens)]
    err_mm = max((np.abs(a - b).max() * 1000 if a.shape == b.shape else np.inf) for a, b in zip(tj, pj))
    report.add("decoded joints, torch vs ORT portable (mm)", err_mm, f"< {th.joints_mm:g}", err_mm < th.joints_mm)
    if streaming is not None:
        check_endless(gen, portable, streaming, report, name="ORT portable")
        if portable.control is not None:
            check_controlled(gen, portable, streaming, report, name="ORT portable")


def check_int8_fixed(fp32: OrtBackend, fixed, report: Report, th: Thresholds, prompts=PROMPTS) -> None:
    """The per-row int8 portable step: as close to fp32 as int8 must be (teacher-forced), and batch-invariant: the
    greedy tokens of all prompts in one batch equal each prompt's alone, bit for bit."""
    prompts, seeds = list(prompts), list(range(len(prompts)))
    forced, _ = _teacher_forced(fp32, fixed, prompts, _ort_tokens(fp32, prompts, seeds, fp32.dims.max_tokens))
    report.add("int8_fixed vs fp32 argmax agreement, teacher-forced (step, level)", forced,
               f">= {th.int8_token_agreement:g}", forced >= th.int8_token_agreement, fmt="{:.3f}")
    batched = _ort_tokens(fixed, prompts, seeds, fp32.dims.max_tokens)
    alone = [_ort_tokens(fixed, [p], [s], fp32.dims.max_tokens)[0] for p, s in zip(prompts, seeds)]
    identical = sum(np.array_equal(a, b) for a, b in zip(batched, alone))
    report.add(f"int8_fixed greedy tokens, batch of {len(prompts)} vs one prompt per call (identical)", identical,
               f"= {len(prompts)}", identical == len(prompts), fmt="{:.0f}")


def check_compact(fp32: OrtBackend, compact, report: Report, th: Thresholds, prompts=PROMPTS) -> None:
    """The compact variant (docs/bundle.md): as close to fp32 as its stored weights allow (teacher-forced), its text
    embeddings too, and batch-invariant like int8_fixed."""
    prompts, seeds = list(prompts), list(range(len(prompts)))
    forced, _ = _teacher_forced(fp32, compact, prompts, _ort_tokens(fp32, prompts, seeds, fp32.dims.max_tokens))
    report.add("compact vs fp32 argmax agreement, teacher-forced (step, level)", forced,
               f">= {th.compact_token_agreement:g}", forced >= th.compact_token_agreement, fmt="{:.3f}")
    a, b = fp32.encode_text(prompts), compact.encode_text(prompts)
    cos = float(((a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)).min())
    report.add("compact vs fp32 text embedding cosine (min)", cos, f">= {th.int8_text_cosine:g}",
               cos >= th.int8_text_cosine, fmt="{:.4f}")
    batched = _ort_tokens(compact, prompts, seeds, fp32.dims.max_tokens)
    alone = [_ort_tokens(compact, [p], [s], fp32.dims.max_tokens)[0] for p, s in zip(prompts, seeds)]
    identical = sum(np.array_equal(x, y) for x, y in zip(batched, alone))
    report.add(f"compact greedy tokens, batch of {len(prompts)} vs one prompt per call (identical)", identical,
               f"= {len(prompts)}", identical == len(prompts), fmt="{:.0f}")


def check_ort_variants(bundle: Bundle, report: Report, prompts=PROMPTS) -> None:
    """Each ORT-format variant gives the greedy tokens of the variant it was converted from."""
    prompts, seeds = list(prompts), list(range(len(prompts)))
    for variant, source in bundle.manifest.ort.variants.items():
        a, b = (_ort_tokens(open_backend(bundle, v, threads=2), prompts, seeds, bundle.dims.max_tokens)
                for v in (variant, source))
        identical = sum(np.array_equal(x, y) for x, y in zip(a, b))
        report.add(f"greedy tokens identical, {variant} vs {source} ({len(prompts)} prompts)", identical,
                   f"= {len(prompts)}", identical == len(prompts), fmt="{:.0f}")


def verify(bundle_path: str | Path, ckpt_dir: str | Path, th: Thresholds = Thresholds(), int8: bool = True,
           portable: bool = True, prompts=PROMPTS) -> Report:
    bundle = Bundle.load(bundle_path)
    gen = TorchGenerator.from_checkpoints(ckpt_dir)
    fp32 = OrtBackend(bundle, "fp32", threads=2)
    q = open_backend(bundle, "int8", threads=2) if int8 and "int8" in bundle.variants else None
    report = Report()
    check_graphs(gen, fp32, report, th)
    check_end_to_end(gen, fp32, q, report, th, prompts)
    streaming = bundle.manifest.streaming
    if streaming is not None:
        check_endless(gen, fp32, streaming, report)
        if bundle.manifest.control is not None:
            check_controlled(gen, fp32, streaming, report)
    if portable and "portable" in bundle.variants:
        check_portable(gen, open_backend(bundle, "portable", threads=2), streaming, report, th, prompts)
    if int8 and INT8_FIXED in bundle.variants:
        check_int8_fixed(fp32, open_backend(bundle, INT8_FIXED, threads=2), report, th, prompts)
    if int8 and COMPACT in bundle.variants:
        check_compact(fp32, open_backend(bundle, COMPACT, threads=2), report, th, prompts)
    if bundle.manifest.ort is not None:
        check_ort_variants(bundle, report, prompts)
    return report
