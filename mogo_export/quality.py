"""Quality on the procedural data: VQ reconstruction, action accuracy of generated motion, diversity, GIFs.

    mogo-export quality --data data/procedural --checkpoints checkpoints/base [--gif outputs/families.gif]

A motion classifier trained on the training split (labels ship with the dataset) judges whether a motion
generated from a held-out caption shows the right action family.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from mogo_runtime.features import recover_from_ric
from mogo_runtime.sampling import SamplingConfig

from .checkpoint import build_from_checkpoint, save_checkpoint
from .data.dataset import MotionDataset
from .generate import TorchGenerator
from .models.classifier import ClassifierConfig, MotionClassifier
from .models.vq import MoSAVQ, VQConfig
from .train import evaluate_vq


def single_family(label: str | None) -> str | None:
    return None if label is None or label.startswith("seq:") else label


def _pad(clips: list[np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    T = max(len(c) for c in clips)
    x = np.zeros((len(clips), T, clips[0].shape[1]), np.float32)
    for i, c in enumerate(clips):
        x[i, :len(c)] = c
    return torch.from_numpy(x), torch.tensor([len(c) for c in clips])


def train_classifier(data: Path, out: Path, steps: int = 400, seed: int = 0, progress: bool = True) -> Path:
    """Train (once) the family classifier on single-action training clips; -> checkpoint path."""
    path = out / "classifier.pt"
    if path.exists():
        return path
    ds = MotionDataset.load(data, "train")
    items = [(ds.normalize(it.features), single_family(it.label)) for it in ds.items if single_family(it.label)]
    families = sorted({f for _, f in items})
    cfg = ClassifierConfig(input_dim=int(ds.mean.shape[0]), num_classes=len(families))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = MotionClassifier(cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3, weight_decay=0.01)
    bar = tqdm(range(steps), desc="classifier", disable=not progress)
    for _ in bar:
        model.train()
        idx = rng.integers(len(items), size=32)
        clips = []
        for i in idx:  # random crops of at least 2 s, so the judge does not rely on clip length
            c = items[i][0]
            n = int(rng.integers(min(40, len(c)), len(c) + 1))
            s = int(rng.integers(0, len(c) - n + 1))
            clips.append(c[s:s + n])
        x, lengths = _pad(clips)
        labels = torch.tensor([families.index(items[i][1]) for i in idx])
        loss, acc = model.loss(x, lengths, labels)
        opt.zero_grad()
        loss.backward()
        opt.step()
        bar.set_postfix(loss=f"{loss.item():.3f}", acc=f"{acc.item():.2f}")
    save_checkpoint(path, "classifier", cfg, model, {"step": steps, "done": True}, {"families": families})
    return path


def load_classifier(path: Path):
    model, cfg, payload = build_from_checkpoint(path, "classifier", ClassifierConfig, MotionClassifier)
    return model, payload["meta"]["families"]


@torch.no_grad()
def classify(model, families, clips_norm: list[np.ndarray]) -> tuple[list[str], np.ndarray]:
    x, lengths = _pad(clips_norm)
    model.eval()
    emb = model.embedding(x, lengths)
    pred = model.head(emb).argmax(-1).tolist()
    return [families[p] for p in pred], emb.numpy()


def diversity(embeddings: np.ndarray, pairs: int = 300, seed: int = 0) -> float:
    """Mean distance between random pairs of motion embeddings (the field's Diversity)."""
    rng = np.random.default_rng(seed)
    a, b = rng.integers(len(embeddings), size=(2, pairs))
    keep = a != b
    return float(np.linalg.norm(embeddings[a[keep]] - embeddings[b[keep]], axis=-1).mean())


def generation_quality(gen: TorchGenerator, data: Path, classifier_path: Path, splits=("test", "val"),
                       sampling: SamplingConfig = SamplingConfig(temperature=1.0, top_p=0.95), seed: int = 0,
                       batch: int = 16, progress: bool = True) -> dict:
    """Generate from held-out captions, classify, report per-family and overall accuracy and diversity."""
    model, families = load_classifier(classifier_path)
    ds = MotionDataset.load(data, splits[0])
    cases = []
    for split in splits:
        for it in MotionDataset.load(data, split).items:
            fam = single_family(it.label)
            if fam in families:
                cases.append((it.captions[0], fam))
    preds, embs = [], []
    for i in tqdm(range(0, len(cases), batch), desc="generate+classify", disable=not progress):
        chunk = cases[i:i + batch]
        motions = gen.generate([c for c, _ in chunk], seed=[seed + i + j for j in range(len(chunk))],
                               sampling=sampling)
        p, e = classify(model, families, [ds.normalize(m.features) if len(m.features) else
                                          np.zeros((4, ds.mean.shape[0]), np.float32) for m in motions])
        preds += p
        embs.append(e)
    truth = [f for _, f in cases]
    per_family = {f: float(np.mean([p == t for p, t in zip(preds, truth) if t == f])) for f in sorted(set(truth))}
    gt_clips = [ds.normalize(it.features) for it in ds.items]
    _, gt_emb = classify(model, families, gt_clips)
    return {"overall_accuracy": float(np.mean([p == t for p, t in zip(preds, truth)])),
            "per_family": per_family, "cases": len(cases),
            "diversity": diversity(np.concatenate(embs)), "diversity_real": diversity(gt_emb)}


def classifier_accuracy_on_real(data: Path, classifier_path: Path, split: str = "test") -> float:
    model, families = load_classifier(classifier_path)
    ds = MotionDataset.load(data, split)
    items = [(ds.normalize(it.features), single_family(it.label)) for it in ds.items
             if single_family(it.label) in families]
    preds, _ = classify(model, families, [c for c, _ in items])
    return float(np.mean([p == f for p, (_, f) in zip(preds, items)]))


def vq_reconstruction(data: Path, vq_path: Path, split: str = "test") -> dict:
    vq, _, _ = build_from_checkpoint(vq_path, "vq", VQConfig, MoSAVQ)
    ds = MotionDataset.load(data, split)
    return evaluate_vq(vq, [ds.normalize(it.features) for it in ds.items], ds.mean, ds.std)


def family_gif(gen: TorchGenerator, families: list[str], captions: dict[str, str], path: Path, seed: int = 0) -> Path:
    from mogo_runtime.preview import render_grid_gif

    texts = [captions[f] for f in families]
    motions = gen.generate(texts, seed=seed, sampling=SamplingConfig(temperature=1.0, top_p=0.95))
    return render_grid_gif(path, [(f"{f}: {t}", m.joints) for f, t, m in zip(families, texts, motions)],
                           fps=gen.backend.dims.fps)


def quality_report(data: Path, ckpt_dir: Path, gif: Path | None = None, progress: bool = True) -> dict:
    t0 = time.perf_counter()
    clf = train_classifier(data, ckpt_dir, progress=progress)
    gen = TorchGenerator.from_checkpoints(ckpt_dir)
    report = {"vq_test": vq_reconstruction(data, ckpt_dir / "vq.pt"),
              "classifier_accuracy_real_test": classifier_accuracy_on_real(data, clf),
              "generation": generation_quality(gen, data, clf, progress=progress)}
    if gif is not None:
        ds = MotionDataset.load(data, "test")
        captions = {}
        for it in ds.items:
            fam = single_family(it.label)
            if fam and fam not in captions:
                captions[fam] = it.captions[0]
        report["gif"] = str(family_gif(gen, sorted(captions), captions, gif))
    report["seconds"] = time.perf_counter() - t0
    (ckpt_dir / "quality.json").write_text(json.dumps(report, indent=2))
    return report
