"""Checkpoints that carry their own config, are written atomically and are validated on load.

A checkpoint is one `torch.save` file holding plain data only (so `torch.load(weights_only=True)` reads it):
    {"format": "mogo-checkpoint", "version": 1, "kind": "vq" | "transformer" | ...,
     "config": {...dataclass fields...}, "model": state_dict, "train": {step, optimizer, rng, ...}, "meta": {...}}

A trained folder (what `mogo-export train` writes: vq.pt + transformer.pt) is read by `load_trained`, the one
place that knows which meta fields a checkpoint carries; it requires them rather than guessing defaults.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mogo_runtime.bundle.sections import ModelDims
from mogo_runtime.outputs.files import write_atomic

from .models.transformer import RQHCTransformer, TransformerConfig
from .models.vq import MoSAVQ, VQConfig

FORMAT = "mogo-checkpoint"
VERSION = 1


class CheckpointError(ValueError):
    pass


def save_checkpoint(path: str | Path, kind: str, config, model: torch.nn.Module, train: dict | None = None,
                    meta: dict | None = None) -> Path:
    """Write atomically: a crash mid-write leaves the previous checkpoint, never a truncated one."""
    path = Path(path)
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "kind": kind,
        "config": dataclasses.asdict(config),
        "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "train": train or {},
        "meta": meta or {},
    }
    # fsynced before the rename: the checkpoint survives a power cut; an ordinary file (umask permissions)
    return write_atomic(path, lambda f: torch.save(payload, f))


def read_checkpoint(path: str | Path, kind: str) -> dict:
    """Load and check the envelope; model weights are checked against the config in `build_from_checkpoint`."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # truncated, not a torch file, or holds non-tensor objects
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(e).__name__}: {e})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a mogo checkpoint (format field is {payload.get('format')!r})"
                              if isinstance(payload, dict) else f"{path}: not a mogo checkpoint")
    if payload.get("version") != VERSION:
        raise CheckpointError(f"{path}: checkpoint version {payload.get('version')} is not supported "
                              f"(this code reads version {VERSION})")
    if payload.get("kind") != kind:
        raise CheckpointError(f"{path}: holds a {payload.get('kind')!r} model, expected {kind!r}")
    for field in ("config", "model"):
        if not isinstance(payload.get(field), dict):
            raise CheckpointError(f"{path}: field {field!r} is missing or malformed")
    return payload


def build_from_checkpoint(path: str | Path, kind: str, config_cls, model_cls):
    """-> (model in eval mode, config, payload). Every tensor's name and shape must match the config."""
    payload = read_checkpoint(path, kind)
    names = {f.name for f in dataclasses.fields(config_cls)}
    unknown = set(payload["config"]) - names
    if unknown:
        raise CheckpointError(f"{path}: config has unknown fields {sorted(unknown)} for {config_cls.__name__}")
    config = config_cls(**payload["config"])
    model = model_cls(config)
    expected = model.state_dict()
    got = payload["model"]
    missing, extra = sorted(set(expected) - set(got)), sorted(set(got) - set(expected))
    if missing or extra:
        raise CheckpointError(f"{path}: weights do not match the config: missing {missing[:5]}, unexpected {extra[:5]}")
    for name, tensor in expected.items():
        if tuple(got[name].shape) != tuple(tensor.shape):
            raise CheckpointError(f"{path}: weight {name!r} has shape {tuple(got[name].shape)}, "
                                  f"config implies {tuple(tensor.shape)}")
    model.load_state_dict(got)
    model.eval()
    return model, config, payload


# -----------------------------------------------------------------------------
# a trained folder: vq.pt + transformer.pt as `mogo_export.train` writes them

# The meta fields `mogo_export.train` writes and every reader needs: name -> (accepted types, meaning). A field that
# is missing or of another type is an error naming the file and the field; nothing is filled in by default.
VQ_META = {
    "mean": (list, "per-feature mean of the training split (de-normalises the decoder's output)"),
    "std": (list, "per-feature standard deviation of the training split"),
    "fps": ((int, float), "frames per second of the motion"),
    "skeleton": (str, "skeleton name, for mogo_runtime.skeleton.get_skeleton"),
    "preset": (str, "name of the preset it was trained with (mogo_export.presets)"),
}
TRANSFORMER_META = {
    "text_encoder": (str, "name of the sentence encoder it was trained with, for get_text_encoder"),
    "max_tokens": (int, "generation stops here if the model has not ended the motion"),
}
# Also written by training, checked for type when present: they describe the training run, and a folder
# assembled by hand (tests/export/test_export.py) may leave them out.
OPTIONAL_META = {
    "dataset": (str, "the dataset folder on the training machine (the default for export's caption index)"),
    "preset": (str, "name of the preset it was trained with"),
    "vq_step": (int, "the VQ step whose tokens the transformer trained on"),
    "val": (dict, "validation metrics at the last checkpoint"),
    "streaming": (dict, "{window, refresh}: the context policy of endless streams it was trained for (presets.py)"),
}


@dataclass(frozen=True)
class TrainedModels:
    """Everything a trained checkpoint folder holds, typed; from `load_trained`. Models are in eval mode."""
    folder: Path
    vq: MoSAVQ
    vq_config: VQConfig
    transformer: RQHCTransformer
    transformer_config: TransformerConfig
    text_encoder_name: str     # get_text_encoder(text_encoder_name) embeds captions as in training
    mean: np.ndarray           # (input_dim,) float32: features = decoder output * std + mean
    std: np.ndarray            # (input_dim,) float32
    fps: float
    max_tokens: int
    skeleton: str
    preset: str
    dataset: str | None        # None when the checkpoint does not record it
    streaming: dict | None     # {window, refresh} when trained for endless streams (presets.Streaming), else None
    vq_step: int               # optimiser steps each model was trained for
    transformer_step: int
    # each file's envelope without the weights and the optimiser/RNG state: "config", "train" ({step, done}),
    # "meta" (checked as above; also validation metrics), for what is not a field above
    vq_payload: dict
    transformer_payload: dict


def _type_names(types) -> str:
    return " or ".join(t.__name__ for t in (types if isinstance(types, tuple) else (types,)))


def _field(path: Path, where: str, d: dict, name: str, types, required: bool = True):
    if name not in d:
        if required:
            raise CheckpointError(f"{path}: {where} field {name!r} is missing (mogo_export.train writes it; a "
                                  f"checkpoint from an older version must be retrained)")
        return None
    value = d[name]
    if isinstance(value, bool) or not isinstance(value, types):  # bool is an int to isinstance
        raise CheckpointError(f"{path}: {where} field {name!r} must be {_type_names(types)}, "
                              f"got {type(value).__name__} {value!r:.60}")
    return value


def _check_meta(path: Path, meta, required: dict) -> dict:
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path}: field 'meta' is missing or malformed")
    for name, (types, _) in required.items():
        _field(path, "meta", meta, name, types)
    for name, (types, _) in OPTIONAL_META.items():
        if name not in required:
            _field(path, "meta", meta, name, types, required=False)
    return meta


def _vector(path: Path, meta: dict, name: str, dim: int) -> np.ndarray:
    try:
        v = np.asarray(meta[name], np.float32)
    except (TypeError, ValueError):
        raise CheckpointError(f"{path}: meta field {name!r} must be a list of numbers") from None
    if v.shape != (dim,):
        raise CheckpointError(f"{path}: meta field {name!r} has shape {v.shape}, the VQ's input_dim is {dim}")
    if not np.isfinite(v).all():
        raise CheckpointError(f"{path}: meta field {name!r} holds non-finite values")
    return v


def load_trained(folder: str | Path) -> TrainedModels:
    """Read a trained checkpoint folder (vq.pt + transformer.pt) and check that its parts fit together: every
    meta field readers need is present and typed, mean/std match the VQ's input size, and the transformer's
    levels x codes are the VQ's. Raises CheckpointError naming the file and the field."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CheckpointError(f"{folder}: checkpoint folder not found")
    vq_path, tr_path = folder / "vq.pt", folder / "transformer.pt"
    vq, vq_cfg, vq_payload = build_from_checkpoint(vq_path, "vq", VQConfig, MoSAVQ)
    tr, tr_cfg, tr_payload = build_from_checkpoint(tr_path, "transformer", TransformerConfig, RQHCTransformer)
    vq_meta = _check_meta(vq_path, vq_payload.get("meta"), VQ_META)
    tr_meta = _check_meta(tr_path, tr_payload.get("meta"), TRANSFORMER_META)
    steps = []
    for path, payload in ((vq_path, vq_payload), (tr_path, tr_payload)):
        if not isinstance(payload.get("train"), dict):
            raise CheckpointError(f"{path}: field 'train' is missing or malformed")
        steps.append(_field(path, "train", payload["train"], "step", int))
    if (tr_cfg.num_levels, tr_cfg.codebook_size) != (vq_cfg.num_levels, vq_cfg.codebook_size):
        raise CheckpointError(f"{tr_path}: config has {tr_cfg.num_levels} levels x {tr_cfg.codebook_size} codes, "
                              f"{vq_path} has {vq_cfg.num_levels} x {vq_cfg.codebook_size}")
    fps = float(vq_meta["fps"])
    if not (math.isfinite(fps) and fps > 0):
        raise CheckpointError(f"{vq_path}: meta field 'fps' must be positive, got {fps}")
    if tr_meta["max_tokens"] < 1:
        raise CheckpointError(f"{tr_path}: meta field 'max_tokens' must be at least 1, got {tr_meta['max_tokens']}")
    return TrainedModels(
        folder=folder, vq=vq, vq_config=vq_cfg, transformer=tr, transformer_config=tr_cfg,
        text_encoder_name=tr_meta["text_encoder"],
        mean=_vector(vq_path, vq_meta, "mean", vq_cfg.input_dim),
        std=_vector(vq_path, vq_meta, "std", vq_cfg.input_dim),
        fps=fps, max_tokens=tr_meta["max_tokens"], skeleton=vq_meta["skeleton"], preset=vq_meta["preset"],
        dataset=vq_meta.get("dataset"), streaming=tr_meta.get("streaming"), vq_step=steps[0],
        transformer_step=steps[1],
        vq_payload=_envelope(vq_payload), transformer_payload=_envelope(tr_payload))


_TRAINING_STATE = ("optimizer", "torch_rng", "numpy_rng", "val_rng")


def _envelope(payload: dict) -> dict:
    """The payload without what only resuming training needs (weights live on in the built model)."""
    out = {k: v for k, v in payload.items() if k != "model"}
    out["train"] = {k: v for k, v in payload["train"].items() if k not in _TRAINING_STATE}
    return out


def model_dims(vq, transformer, fps: float, max_tokens: int) -> ModelDims:
    """The bundle manifest's `model` section, from the trained modules: what the exporter writes and what the
    torch reference backend reports, from one place."""
    t, v = transformer.cfg, vq.cfg
    return ModelDims(num_levels=t.num_levels, codebook_size=t.codebook_size, n_layers=t.n_layers,
                     n_heads=t.n_heads, head_dim=t.d_model // t.n_heads, text_dim=t.text_dim,
                     max_rel_dist=t.max_rel_dist, downsample=v.downsample, fps=float(fps),
                     receptive_field=vq.receptive_field, feature_dim=v.input_dim, latent_dim=v.code_dim,
                     max_tokens=int(max_tokens))
