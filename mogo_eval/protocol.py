"""The text-to-motion evaluation protocol of Guo et al. 2022 (the metrics of MOGO's Tables 2 and 3).

    mogo-eval train-evaluator --data data/procedural                  # -> data/procedural/evaluator.pt
    mogo-eval evaluate --data data/procedural --checkpoints checkpoints/base --bundle bundles/base \
        [--variant fp32 --variant int8] [--evaluator E] [--repeats 20] [--json outputs/eval.json] \
        [--vq-ablation scaling/vq.pt no-scaling/vq.pt]

Every metric is computed in the embedding space of a text-motion evaluator (`judges/evaluator.py`): Guo et
al.'s pretrained one where a user has its files, else a contrastive one trained here on the dataset folder
(unit-length embeddings, so its distances lie in [0, 2]: compare rows of one table, not with published numbers).
One repetition, for each source of motion (real, VQ reconstruction, torch generation, bundle fp32 / int8):

- the test items are shuffled and each gets one of its captions at random; real motions are cropped to a
  multiple of 4 frames at a random offset (T2M's evaluation dataset), twice: one draw is the FID reference, the
  other is the "real motion" row and the VQ's input;
- R-Precision top-1/2/3: in batches of 32 (the last, partial batch dropped), each caption ranks the batch's
  32 motions by Euclidean distance; a hit when its own motion is among the first k;
- MM-Dist: mean distance between a caption and its motion over those batches;
- FID: Frechet distance between Gaussians fitted to the reference's and the source's motion embeddings;
- Diversity: mean distance between 300 random pairs of the source's motions (fewer when there are fewer);
- MultiModality (generators only): `mm_generations` motions for each of the first `mm_captions` captions,
  mean distance of `mm_pairs` random pairs within a caption.
Each metric is repeated `repeats` times (20 in the literature) and reported as mean ± 1.96 * std / sqrt(repeats).
All sources of one repetition see the same captions, crops and seeds, so torch and the fp32 bundle must agree.

Deviations from Guo et al.'s code, forced by small test splits: FID and Diversity use every test item (not only
full batches); with fewer items than one batch, R-Precision uses one batch of them all (flagged in the output).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from mogo_runtime.bundle import read_manifest
from mogo_runtime.bundle.sampling import SamplingConfig
from mogo_runtime.outputs.files import write_atomic

from mogo_export.checkpoint import build_from_checkpoint, read_checkpoint, save_checkpoint
from mogo_export.data.dataset import MotionDataset, read_captions

from .judges.evaluator import (ContrastiveEvaluator, Evaluator, EvaluatorConfig, T2MEvaluator, TrainedEvaluator,
                               pad_motions)
from .quality import judged_variants

METRICS = ("top1", "top2", "top3", "fid", "mm_dist", "diversity", "multimodality")

# ---------------------------------------------------------------------------------------------------------
# The metrics (numpy), as Guo et al.'s utils/metrics.py computes them.


def euclidean_distance_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, D), (M, D) -> (N, M) distances; from the differences (not |a|^2 - 2ab + |b|^2, whose rounding
    makes equal points ~1e-4 apart in float32)."""
    return np.linalg.norm(a[:, None, :].astype(np.float64) - b[None, :, :], axis=-1)


def r_precision(text_emb: np.ndarray, motion_emb: np.ndarray, top_k: int = 3) -> tuple[np.ndarray, float]:
    """One batch: -> (hits (top_k,): how many captions find their own motion within the k nearest, summed
    distance of each caption to its own motion). Row i of both arrays is one pair."""
    dist = euclidean_distance_matrix(text_emb, motion_emb)                 # (B, B) caption rows
    rank = (dist < np.diag(dist)[:, None]).sum(1)                           # motions closer than the true one
    hits = np.array([(rank < k).sum() for k in range(1, top_k + 1)])
    return hits, float(np.trace(dist))


def activation_statistics(emb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return emb.mean(0), np.cov(emb, rowvar=False)


def _sqrt_psd(m: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh((m + m.T) / 2)
    return (v * np.sqrt(np.clip(w, 0, None))) @ v.T


def frechet_distance(mu1, sigma1, mu2, sigma2) -> float:
    """||mu1 - mu2||^2 + tr(S1 + S2 - 2 (S1 S2)^1/2). tr((S1 S2)^1/2) is computed as the sum of the square roots of
    the eigenvalues of S1^1/2 S2 S1^1/2 (same spectrum, symmetric), so singular covariances (fewer samples than
    dimensions) need no eps or scipy."""
    s1 = _sqrt_psd(sigma1)
    eig = np.linalg.eigvalsh(s1 @ sigma2 @ s1)
    tr_covmean = np.sqrt(np.clip(eig, 0, None)).sum()
    diff = mu1 - mu2
    return float(diff @ diff + np.trace(sigma1) + np.trace(sigma2) - 2 * tr_covmean)


def fid(emb_a: np.ndarray, emb_b: np.ndarray) -> float:
    """FID of two embedding sets (Gaussians with their sample means and covariances, ddof=1).

    With fewer samples than dimensions (100 test items in 512 dimensions) it is computed in sample space:
    for centred A (n_a, D), B (n_b, D), the non-zero eigenvalues of S_a S_b are the squared singular values of
    A B^T / sqrt((n_a - 1)(n_b - 1)), so tr((S_a S_b)^1/2) is that matrix's nuclear norm: exact, and an SVD of
    n_a x n_b instead of eigendecompositions of D x D.
    """
    a, b = np.asarray(emb_a, np.float64), np.asarray(emb_b, np.float64)
    if min(len(a), len(b)) > a.shape[1]:
        return frechet_distance(*activation_statistics(a), *activation_statistics(b))
    mu_a, mu_b = a.mean(0), b.mean(0)
    A, B = a - mu_a, b - mu_b
    ca, cb = len(a) - 1, len(b) - 1
    tr_covmean = np.linalg.svd(A @ B.T, compute_uv=False).sum() / math.sqrt(ca * cb)
    diff = mu_a - mu_b
    return float(diff @ diff + (A ** 2).sum() / ca + (B ** 2).sum() / cb - 2 * tr_covmean)


def diversity(emb: np.ndarray, times: int, rng: np.random.Generator) -> tuple[float, int]:
    """Mean distance of `times` random pairs (two draws without replacement); -> (value, pairs used)."""
    times = min(times, len(emb))
    a = rng.choice(len(emb), times, replace=False)
    b = rng.choice(len(emb), times, replace=False)
    return float(np.linalg.norm(emb[a] - emb[b], axis=1).mean()), times


def multimodality(emb: np.ndarray, times: int, rng: np.random.Generator) -> float:
    """emb (captions, generations, D): mean distance of `times` random generation pairs, same pairs per caption."""
    if emb.shape[1] < times:
        raise ValueError(f"MultiModality needs at least {times} generations per caption, got {emb.shape[1]}")
    a = rng.choice(emb.shape[1], times, replace=False)
    b = rng.choice(emb.shape[1], times, replace=False)
    return float(np.linalg.norm(emb[:, a] - emb[:, b], axis=2).mean())


def mean_confidence(values) -> tuple[float, float]:
    """-> (mean, 95% interval half-width 1.96 * std / sqrt(n)), std with ddof=0 as Guo et al.'s code."""
    v = np.asarray(values, np.float64)
    return float(v.mean()), float(1.96 * v.std() / math.sqrt(len(v)))


def guo_crop(features: np.ndarray, rng: np.random.Generator, unit: int = 4) -> np.ndarray:
    """T2M's evaluation crop: length T // unit * unit (2 times in 3) or one unit less, at a random offset."""
    T = len(features)
    units = T // unit - (1 if rng.random() < 1 / 3 and T // unit > 1 else 0)
    n = max(units, 1) * unit if T >= unit else T
    start = int(rng.integers(0, T - n + 1))
    return features[start:start + n]


# ---------------------------------------------------------------------------------------------------------
# Test items with their captions' word/POS tokens (only Guo et al.'s evaluator reads the tokens).


@dataclass
class EvalCase:
    clip_id: str
    features: np.ndarray           # (T, D) de-normalised
    captions: list[str]
    tokens: list[list[str]]        # `word/POS` per caption


def load_cases(data: Path, split: str = "test") -> list[EvalCase]:
    ds = MotionDataset.load(data, split)
    token_cache: dict[str, dict[str, list[str]]] = {}
    cases = []
    for it in ds.items:
        file_id = it.clip_id.split(":")[0]
        if file_id not in token_cache:
            token_cache[file_id] = {c.text: c.tokens for c in read_captions(Path(data) / "texts" / f"{file_id}.txt")}
        cases.append(EvalCase(it.clip_id, it.features, list(it.captions),
                              [token_cache[file_id].get(c, []) for c in it.captions]))
    return cases


# ---------------------------------------------------------------------------------------------------------
# Sources of motion: texts, real crops and seeds -> de-normalised (T, D) features.


@dataclass
class MotionSource:
    name: str
    make: Callable[[list[str], list[np.ndarray], list[int]], list[np.ndarray]]
    stochastic: bool = False       # generators: MultiModality is measured


def real_source(name: str = "Real motion") -> MotionSource:
    return MotionSource(name, lambda texts, real, seeds: list(real))


def vq_source(vq_path: Path, name: str = "VQ reconstruction") -> MotionSource:
    """Encode and decode each real crop with a MoSA-VQ checkpoint (normalised with the VQ's own statistics)."""
    from mogo_export.models.vq import MoSAVQ, VQConfig

    vq, cfg, payload = build_from_checkpoint(vq_path, "vq", VQConfig, MoSAVQ)
    mean = np.asarray(payload["meta"]["mean"], np.float32)
    std = np.asarray(payload["meta"]["std"], np.float32)

    @torch.no_grad()
    def make(texts, real, seeds):
        out = []
        for clip in real:
            n = max(len(clip) // cfg.downsample, 1) * cfg.downsample
            clip = clip[:n] if len(clip) >= n else np.concatenate([clip, np.repeat(clip[-1:], n - len(clip), 0)])
            x = torch.from_numpy(((clip - mean) / std).astype(np.float32))[None]
            out.append(vq.decode_indices(vq.encode(x))[0].numpy() * std + mean)
        return out

    return MotionSource(name, make)


def _by_length(generate, downsample: int, length: str, chunk: int):
    """Wrap generate(texts, seeds, num_tokens | None) -> features into a source's `make`, `chunk` prompts a call.

    length="gt": each prompt gets its real crop's length in tokens. Prompts are sorted by that length, each chunk
    generated at its longest one (END forbidden) and every motion cut to its own length: the transformer and the
    decoder are causal and every prompt draws from its own seeded generator, so the cut equals a generation of
    that length, in one batched call instead of one per length.
    """

    def make(texts, real, seeds):
        out: list[np.ndarray | None] = [None] * len(texts)
        if length == "gt":
            tokens = [max(1, round(len(r) / downsample)) for r in real]
            order = sorted(range(len(texts)), key=lambda i: tokens[i])
        else:
            order = list(range(len(texts)))
        for s in range(0, len(order), chunk):
            part = order[s:s + chunk]
            fixed = max(tokens[i] for i in part) if length == "gt" else None
            feats = generate([texts[i] for i in part], [seeds[i] for i in part], fixed)
            for i, f in zip(part, feats):
                out[i] = f[:tokens[i] * downsample] if length == "gt" else f
        return out

    return make


def torch_source(ckpt_dir: Path, sampling: SamplingConfig, length: str = "model", chunk: int = 32,
                 name: str = "MOGO (torch)") -> MotionSource:
    from mogo_export.reference import TorchGenerator

    from .features import torch_features

    fg = torch_features(TorchGenerator.from_checkpoints(ckpt_dir), sampling)
    return MotionSource(name, _by_length(fg.generate, fg.downsample, length, chunk), stochastic=True)


def bundle_source(bundle: Path, variant: str, sampling: SamplingConfig | None = None, length: str = "model",
                  chunk: int = 32, threads: int = 2, align: bool = False, name: str | None = None) -> MotionSource:
    """A bundle variant through the runtime (features.bundle_features); sampling None = the bundle's.
    `align`: condition on the TCA-aligned prompts (the paper's "w/ TCA" rows)."""
    from .features import bundle_features

    fg = bundle_features(bundle, variant, sampling, threads, align)
    name = name or f"MOGO bundle {variant}" + (" + TCA" if align else "")
    return MotionSource(name, _by_length(fg.generate, fg.downsample, length, chunk), stochastic=True)


def bundle_sampling(bundle: Path) -> SamplingConfig:
    """The sampling defaults a bundle ships (what its users get), for the torch row to sample alike."""
    return read_manifest(bundle).sampling_defaults


# ---------------------------------------------------------------------------------------------------------
# The protocol.


@dataclass
class ProtocolConfig:
    repeats: int = 20              # repetitions; mean ± 95% interval over them
    batch_size: int = 32           # R-Precision: one true caption among batch_size - 1 others
    top_k: int = 3
    diversity_times: int = 300     # random pairs for Diversity
    mm_captions: int = 32          # MultiModality: captions (Guo et al.: 100) ...
    mm_generations: int = 10       # ... motions generated for each (Guo et al.: 30) ...
    mm_pairs: int = 10             # ... pairs measured within each
    seed: int = 0
    split: str = "test"
    length: str = "model"          # "model": generators choose the length (END); "gt": the real crop's length


def _seed(*parts: int) -> int:
    return int(np.random.SeedSequence([int(p) for p in parts]).generate_state(1)[0])


def run_protocol(cases: list[EvalCase], evaluator: Evaluator, sources: list[MotionSource], cfg: ProtocolConfig,
                 progress: bool = True) -> dict:
    """-> {"rows": {source: {metric: {mean, conf, values}}}, "info": {...}}; MultiModality None for non-generators."""
    n = len(cases)
    if n < 2:
        raise ValueError(f"the {cfg.split} split has {n} item(s); the protocol needs at least 2")
    batch = min(cfg.batch_size, n)
    full = n // batch * batch
    values = {s.name: {m: [] for m in METRICS} for s in sources}
    seconds = {s.name: 0.0 for s in sources}
    unit = evaluator.unit_length
    div_pairs = 0
    bar = tqdm(total=cfg.repeats * len(sources), desc="evaluate", disable=not progress)
    for r in range(cfg.repeats):
        rng = np.random.default_rng([cfg.seed, r])
        picks = [cases[i] for i in rng.permutation(n)]
        which = [int(rng.integers(len(c.captions))) for c in picks]
        texts = [c.captions[k] for c, k in zip(picks, which)]
        tokens = [c.tokens[k] for c, k in zip(picks, which)]
        reference = [guo_crop(c.features, rng, unit) for c in picks]
        real = [guo_crop(c.features, rng, unit) for c in picks]
        seeds = [_seed(cfg.seed, r, 0, i) for i in range(n)]
        text_emb = evaluator.embed_texts(texts, tokens)
        ref_emb = evaluator.embed_motions(reference)
        k_mm = min(cfg.mm_captions, n)
        for source in sources:
            t0 = time.perf_counter()
            emb = evaluator.embed_motions(source.make(texts, real, seeds))
            hits, match = np.zeros(cfg.top_k), 0.0
            for b in range(0, full, batch):
                h, m = r_precision(text_emb[b:b + batch], emb[b:b + batch], cfg.top_k)
                hits, match = hits + h, match + m
            v = values[source.name]
            for k in range(cfg.top_k):
                v[f"top{k + 1}"].append(hits[k] / full)
            v["mm_dist"].append(match / full)
            v["fid"].append(fid(ref_emb, emb))
            d, div_pairs = diversity(emb, cfg.diversity_times, np.random.default_rng([cfg.seed, r, 1]))
            v["diversity"].append(d)
            if source.stochastic and k_mm and cfg.mm_generations:
                G = cfg.mm_generations
                mm = source.make([texts[i] for i in range(k_mm) for _ in range(G)],
                                 [real[i] for i in range(k_mm) for _ in range(G)],
                                 [_seed(cfg.seed, r, 1, i, g) for i in range(k_mm) for g in range(G)])
                mm_emb = evaluator.embed_motions(mm).reshape(k_mm, G, -1)
                v["multimodality"].append(multimodality(mm_emb, min(cfg.mm_pairs, G),
                                                        np.random.default_rng([cfg.seed, r, 2])))
            seconds[source.name] += time.perf_counter() - t0
            bar.update()
    bar.close()
    rows = {}
    for name, v in values.items():
        rows[name] = {}
        for m in METRICS:
            if v[m]:
                mean, conf = mean_confidence(v[m])
                rows[name][m] = {"mean": mean, "conf": conf, "values": [float(x) for x in v[m]]}
            else:
                rows[name][m] = None
    info = {"items": n, "batch_size": batch, "r_precision_items": full, "diversity_pairs": div_pairs,
            "mm_captions": k_mm, "seconds": {k: round(s, 2) for k, s in seconds.items()},
            "warning": (f"only {n} items: R-Precision ranks among {batch}, not {cfg.batch_size}"
                        if batch < cfg.batch_size else None)}
    return {"rows": rows, "info": info}


# ---------------------------------------------------------------------------------------------------------
# Tables in the paper's layouts.

TABLE2 = (("top1", "Top 1"), ("top2", "Top 2"), ("top3", "Top 3"), ("fid", "FID"), ("mm_dist", "MM-Dist"),
          ("diversity", "Diversity"), ("multimodality", "MultiModality"))
TABLE3 = (("fid", "FID"), ("top1", "Top1"), ("mm_dist", "MM-Dist"))


def format_table(rows: dict, columns=TABLE2, first: str = "Source") -> str:
    cell = lambda r: "-" if r is None else f"{r['mean']:.3f} ± {r['conf']:.3f}"     # noqa: E731
    width = max([len(first)] + [len(n) for n in rows]) + 2
    cols = [max(len(h), *(len(cell(r.get(k))) for r in rows.values())) + 2 for k, h in columns]
    lines = [first.ljust(width) + "".join(h.rjust(w) for (_, h), w in zip(columns, cols))]
    lines.append("-" * len(lines[0]))
    for name, r in rows.items():
        lines.append(name.ljust(width) + "".join(cell(r.get(k)).rjust(w) for (k, _), w in zip(columns, cols)))
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------------
# The default evaluator: train, save, load.


@dataclass
class EvaluatorSchedule:
    steps: int = 500
    batch_size: int = 64
    lr: float = 1e-3
    warmup: int = 50
    weight_decay: float = 0.01


def fit_evaluator(data: Path, cfg: EvaluatorConfig | None = None, schedule: EvaluatorSchedule | None = None,
                  seed: int = 0, progress: bool = True, text_encoder=None):
    """Train a ContrastiveEvaluator on the train split. -> (model, mean, std, losses per step)."""
    from mogo_export.models.text_encoder import get_text_encoder

    sched = schedule or EvaluatorSchedule()
    ds = MotionDataset.load(data, "train")
    enc = text_encoder or get_text_encoder((cfg or EvaluatorConfig()).text_encoder)
    cfg = cfg or EvaluatorConfig()
    cfg = EvaluatorConfig(**{**asdict(cfg), "input_dim": int(ds.mean.shape[0]), "text_dim": int(enc.dim),
                             "text_encoder": enc.name})
    captions = sorted({c for it in ds.items for c in it.captions})
    index = {c: i for i, c in enumerate(captions)}
    sentence = enc.encode(captions).float()                                # (C, text_dim), frozen
    clips = [ds.normalize(it.features) for it in ds.items]
    caption_ids = [[index[c] for c in it.captions] for it in ds.items]

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = ContrastiveEvaluator(cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=sched.lr, weight_decay=sched.weight_decay)

    def lr_at(step: int) -> float:                                         # linear warmup, cosine decay
        warm = min(1.0, (step + 1) / max(1, sched.warmup))
        return sched.lr * warm * 0.5 * (1 + math.cos(math.pi * step / sched.steps))

    batch = min(sched.batch_size, len(clips))
    losses = []
    bar = tqdm(range(sched.steps), desc="evaluator", disable=not progress)
    for step in bar:
        model.train()
        for g in opt.param_groups:
            g["lr"] = lr_at(step)
        idx = rng.choice(len(clips), batch, replace=False)
        caps = [caption_ids[i][int(rng.integers(len(caption_ids[i])))] for i in idx]
        x, lengths = pad_motions([guo_crop(clips[i], rng, cfg.unit_length) for i in idx], cfg.unit_length,
                                 cfg.max_frames)
        loss, acc = model.loss(x, lengths, sentence[caps], caps)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        losses.append(loss.item())
        bar.set_postfix(loss=f"{loss.item():.3f}", acc=f"{acc.item():.2f}")
    return model.eval(), ds.mean, ds.std, losses


def train_evaluator(data: Path, out: Path, schedule: EvaluatorSchedule | None = None, seed: int = 0,
                    cfg: EvaluatorConfig | None = None, progress: bool = True) -> Path:
    """Train, measure real-motion R-Precision on the val split (a sanity check of the evaluator), save."""
    data, out = Path(data), Path(out)
    sched = schedule or EvaluatorSchedule()
    t0 = time.perf_counter()
    model, mean, std, losses = fit_evaluator(data, cfg, sched, seed, progress)
    seconds = time.perf_counter() - t0
    evaluator = TrainedEvaluator(model, mean, std)
    val = None
    try:
        val_cases = load_cases(data, "val")
        res = run_protocol(val_cases, evaluator, [real_source()], ProtocolConfig(repeats=3, split="val",
                                                                                 mm_captions=0), progress=False)
        val = {k: res["rows"]["Real motion"][k]["mean"] for k in ("top1", "top2", "top3", "mm_dist")}
        val["batch_size"] = res["info"]["batch_size"]
    except (FileNotFoundError, ValueError) as e:                              # no usable val split: skip the check
        val = {"skipped": str(e)}
    meta = {"mean": mean.tolist(), "std": std.tolist(), "dataset": str(data), "val_real": val,
            "loss_first": float(np.mean(losses[:20])), "loss_last": float(np.mean(losses[-20:]))}
    save_checkpoint(out, "evaluator", model.cfg, model, {"step": sched.steps, "done": True,
                                                         "seconds": round(seconds, 1), **asdict(sched)}, meta)
    print(f"evaluator: {sched.steps} steps in {seconds:.0f} s, loss {meta['loss_first']:.3f} -> "
          f"{meta['loss_last']:.3f}; real motion on val: {val}; saved {out}")
    return out


def load_evaluator(path: Path | None, data: Path | None = None, glove: Path | None = None,
                   t2m_meta: Path | None = None, train_if_missing: bool = True, progress: bool = True) -> Evaluator:
    """A mogo evaluator checkpoint (.pt), or Guo et al.'s (a finest.tar or the t2m/kit folder; needs `glove` and
    `t2m_meta`). None -> `<data>/evaluator.pt`, trained first if missing."""
    if path is None:
        if data is None:
            raise ValueError("give an evaluator or a dataset folder to find/train one in")
        path = Path(data) / "evaluator.pt"
        if not path.exists():
            if not train_if_missing:
                raise FileNotFoundError(f"no evaluator at {path}; train one with `mogo-eval train-evaluator`")
            print(f"no evaluator at {path}: training one (mogo-eval train-evaluator)")
            train_evaluator(data, path, progress=progress)
    path = Path(path)
    if path.is_dir() or path.suffix == ".tar":
        if glove is None or t2m_meta is None:
            raise ValueError(f"{path} is Guo et al.'s evaluator: also give --glove (the glove/ folder) and "
                             f"--t2m-meta (the folder with the mean.npy/std.npy it was trained with)")
        return T2MEvaluator.from_files(path, glove, t2m_meta)
    model, cfg, payload = build_from_checkpoint(path, "evaluator", EvaluatorConfig, ContrastiveEvaluator)
    meta = payload["meta"]
    return TrainedEvaluator(model, np.asarray(meta["mean"], np.float32), np.asarray(meta["std"], np.float32),
                            name=f"contrastive:{path}")


def evaluator_info(path: Path | None, evaluator: Evaluator) -> dict:
    info = {"name": evaluator.name, "dim": evaluator.dim}
    if isinstance(evaluator, TrainedEvaluator) and path is not None and Path(path).is_file():
        payload = read_checkpoint(path, "evaluator")
        info.update(config=payload["config"], train={k: v for k, v in payload["train"].items()},
                    val_real=payload["meta"].get("val_real"))
    return info


# ---------------------------------------------------------------------------------------------------------
# One command: the Table 2 rows and the Table 3 ablation.


@dataclass
class EvaluateRequest:
    data: Path
    checkpoints: Path | None = None
    bundle: Path | None = None
    variants: list[str] | None = None          # None: every variant of the bundle
    evaluator: Path | None = None
    glove: Path | None = None
    t2m_meta: Path | None = None
    vq_ablation: list[Path] = field(default_factory=list)
    protocol: ProtocolConfig = field(default_factory=ProtocolConfig)
    threads: int = 2
    tca: bool = False                          # also each bundle variant with TCA-aligned prompts


def evaluate(req: EvaluateRequest, progress: bool = True) -> dict:
    t0 = time.perf_counter()
    cfg = req.protocol
    evaluator = load_evaluator(req.evaluator, req.data, req.glove, req.t2m_meta, progress=progress)
    ev_path = req.evaluator or Path(req.data) / "evaluator.pt"
    cases = load_cases(req.data, cfg.split)
    sampling = bundle_sampling(req.bundle) if req.bundle else None
    if sampling is None:                                                 # what an exported bundle would ship
        from mogo_export.checkpoint import read_checkpoint
        from mogo_export.export.bundle import SAMPLING_DEFAULTS, sampling_defaults
        sampling = (sampling_defaults(read_checkpoint(Path(req.checkpoints) / "transformer.pt", "transformer")["meta"])
                    if req.checkpoints else SAMPLING_DEFAULTS)
    sources = [real_source()]
    if req.checkpoints:
        sources.append(vq_source(Path(req.checkpoints) / "vq.pt"))
        sources.append(torch_source(req.checkpoints, sampling, cfg.length))
    if req.bundle:
        from mogo_runtime.bundle import Bundle

        available = list(Bundle.load(req.bundle).variants)
        for v in req.variants or judged_variants(available):
            if v not in available:
                raise ValueError(f"bundle {req.bundle} has no variant {v!r}; it has {', '.join(available)}")
            sources.append(bundle_source(req.bundle, v, sampling, cfg.length, threads=req.threads))
            if req.tca:
                sources.append(bundle_source(req.bundle, v, sampling, cfg.length, threads=req.threads, align=True))
    ablation_names, ablation_paths = [], {}
    for path in req.vq_ablation:
        payload = read_checkpoint(path, "vq")
        c = payload["config"]
        name = (f"{'w/' if c.get('learnable_scaling', True) else 'w/o'} learnable scaling, "
                f"{c['codebook_size']}×{c['code_dim']} x{c['num_levels']}")
        if name in ablation_names:
            name += f" ({Path(path).parent.name}/{Path(path).name})"
        ablation_names.append(name)
        ablation_paths[name] = str(path)
        sources.append(vq_source(Path(path), name=name))
    result = run_protocol(cases, evaluator, sources, cfg, progress)
    rows = result["rows"]
    report = {
        "table2": {k: v for k, v in rows.items() if k not in ablation_names},
        "table3": {k: rows[k] for k in ablation_names} or None,
        "protocol": {**asdict(cfg), **result["info"], "sampling": sampling.to_dict(), "data": str(req.data),
                     "checkpoints": str(req.checkpoints) if req.checkpoints else None,
                     "bundle": str(req.bundle) if req.bundle else None, "vq_ablation": ablation_paths or None},
        "evaluator": evaluator_info(ev_path, evaluator),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    return report


def print_report(report: dict) -> None:
    p = report["protocol"]
    print(f"Text-to-motion metrics (Guo et al. 2022 protocol) on {p['data']} [{p['split']}]: {p['items']} items, "
          f"{p['repeats']} repeats, mean ± 95% interval; evaluator {report['evaluator']['name']}")
    print(format_table(report["table2"]))
    if report.get("table3"):
        print("\nLearnable-scaling ablation (VQ reconstruction, as Table 3)")
        print(format_table(report["table3"], TABLE3, first="MoSA-VQ (codebook K×d x levels)"))
    if p.get("warning"):
        print(f"note: {p['warning']}")


def write_json(report: dict, path: Path) -> Path:
    text = json.dumps(report, indent=2)
    return write_atomic(Path(path), lambda f: f.write(text.encode()))
