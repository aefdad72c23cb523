"""Shared test set-up.

With MOGO_BLOCK_TORCH=1 (how `make test-runtime` runs), importing torch or mogo_export raises, so the
runtime's tests prove that mogo_runtime works on a machine without them.
"""
import importlib.abc
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT.parent / "shared" / "fixtures" / "humanml3d"


class _BlockTorch(importlib.abc.MetaPathFinder):
    blocked = ("torch", "mogo_export")

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in self.blocked:
            raise ImportError(f"{name} is blocked: the runtime must work without torch and mogo_export")
        return None


if os.environ.get("MOGO_BLOCK_TORCH") == "1":
    sys.meta_path.insert(0, _BlockTorch())


@pytest.fixture(scope="session")
def humanml3d_fixture() -> Path:
    """The real HumanML3D sample beside the repository (never copied into it)."""
    if not (FIXTURES / "Mean.npy").exists():
        raise FileNotFoundError(f"HumanML3D fixture missing at {FIXTURES}; tests expect ../shared beside the repo")
    return FIXTURES


@pytest.fixture(scope="session")
def tiny_bundle() -> Path:
    """A trained tiny bundle (see tests/tiny_bundle.py); built in a subprocess, so usable with torch blocked."""
    from tiny_bundle import ensure_tiny_bundle

    return ensure_tiny_bundle()[1]


@pytest.fixture(scope="session")
def tiny_checkpoints() -> Path:
    from tiny_bundle import ensure_tiny_bundle

    return ensure_tiny_bundle()[0]


@pytest.fixture
def one_torch_thread():
    """Tiny models: one thread is faster, and two OpenMP threads on a busy 2-core machine can be 10x slower."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
