"""Checkpoints that carry their own config, are written atomically and are validated on load.

A checkpoint is one `torch.save` file holding plain data only (so `torch.load(weights_only=True)` reads it):
    {"format": "mogo-checkpoint", "version": 1, "kind": "vq" | "transformer" | ...,
     "config": {...dataclass fields...}, "model": state_dict, "train": {step, optimizer, rng, ...}, "meta": {...}}
"""
from __future__ import annotations

import dataclasses
import os
import tempfile
from pathlib import Path

import torch

FORMAT = "mogo-checkpoint"
VERSION = 1


class CheckpointError(ValueError):
    pass


def save_checkpoint(path: str | Path, kind: str, config, model: torch.nn.Module, train: dict | None = None,
                    meta: dict | None = None) -> Path:
    """Write atomically: a crash mid-write leaves the previous checkpoint, never a truncated one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "kind": kind,
        "config": dataclasses.asdict(config),
        "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "train": train or {},
        "meta": meta or {},
    }
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; a checkpoint is an ordinary file
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


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
