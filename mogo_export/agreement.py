"""How close a bundle variant stays to another, torch-free (numpy and onnxruntime, through mogo_runtime): the
verifier's measures (verify.py), also run by benchmarks/cpu_kinds.py in processes under QEMU, where importing torch
would take minutes.

    seqs = greedy_tokens(fp32, prompts, seeds, max_tokens)
    agree, worst = teacher_forced(forced_logits(fp32, prompts, seqs), forced_logits(int8, prompts, seqs))
"""
from __future__ import annotations

import numpy as np

from mogo_runtime.bundle.sampling import GREEDY
from mogo_runtime.decoding import GenerationTask


def greedy_tokens(backend, texts: list[str], seeds: list[int], max_tokens: int) -> list[np.ndarray]:
    """Each text's greedy token sequence (T, L), as the runtime generates it."""
    return GenerationTask(backend, backend.bundle.skeleton, GREEDY, max_tokens).tokens(backend.encode_text(texts), seeds)


def forced_logits(backend, prompts: list[str], sequences: list[np.ndarray]) -> list[np.ndarray]:
    """The logits (T + 1, L, K + 1) of each prompt's step calls, one step at a time as the runtime steps, fed BOS and
    then the given sequence (so its END step too), whatever the backend would have picked itself."""
    bos, out = backend.dims.bos_id, []
    for text, seq in zip(prompts, sequences):
        feed = np.concatenate([np.full((1, seq.shape[1]), bos), seq]).astype(np.int64)     # (T + 1, L)
        emb, past, logits = backend.encode_text([text]), backend.empty_past(1), []
        for t in range(len(feed)):
            step, past = backend.step(emb, feed[None, t:t + 1], past)
            logits.append(step[0, 0])
        out.append(np.stack(logits))
    return out


def teacher_forced(reference: list[np.ndarray], other: list[np.ndarray]) -> tuple[float, float]:
    """-> (fraction of (step, level) argmaxes equal, max abs logit difference) of two forced_logits runs."""
    same = sum(int((a.argmax(-1) == b.argmax(-1)).sum()) for a, b in zip(reference, other))
    total = sum(a.shape[0] * a.shape[1] for a in reference)
    worst = max((float(np.abs(a - b).max()) for a, b in zip(reference, other)), default=0.0)
    return same / max(1, total), worst
