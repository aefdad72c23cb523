"""The device install: `pip install ./runtime` into a fresh venv is numpy + onnxruntime + the runtime, at most
200 MB, generates from a bundle, names the extra a preview needs, and leaves the source tree as it was.

About 2 minutes (pip unpacks and compiles numpy and onnxruntime); the wheels come from pip's index as in `make
setup`, so this needs what `make setup` needs.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from toy_bundle import toy_bundle  # noqa: F401  (a fixture)

RUNTIME = Path(__file__).resolve().parents[2] / "runtime"
CORE_MB = 200


def _tree(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if "__pycache__" not in p.parts}


def _size_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink()) / 2 ** 20


def test_a_fresh_venv_gets_the_core_runtime_only(tmp_path, toy_bundle):  # noqa: F811
    before = _tree(RUNTIME)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    subprocess.run([str(py), "-m", "pip", "install", "-q", str(RUNTIME)], check=True, env=env)
    assert _tree(RUNTIME) == before, "a non-editable install wrote into the source tree"

    listed = subprocess.run([str(py), "-m", "pip", "list", "--format", "freeze"], check=True, env=env,
                            capture_output=True, text=True).stdout
    installed = {line.split("==")[0].lower() for line in listed.split()}
    assert {"mogo-runtime", "numpy", "onnxruntime"} <= installed, listed
    assert not installed & {"tokenizers", "huggingface-hub", "pillow", "imageio-ffmpeg", "pygltflib", "torch"}, listed
    size = _size_mb(venv)
    print(f"fresh venv with mogo-runtime: {size:.0f} MB ({', '.join(sorted(installed))})")
    assert size <= CORE_MB, f"the core install is {size:.0f} MB, over {CORE_MB} MB"

    mogo = venv / "bin" / "mogo"
    out = tmp_path / "walk.npy"
    run = subprocess.run([str(mogo), "generate", "a person walks forward", "-o", str(out), "--bundle",
                          str(toy_bundle), "--seconds", "1", "--seed", "1"], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert np.load(out).ndim == 3
    for name, extra in (("walk.gif", "preview"), ("walk.mp4", "video"), ("walk.glb", "gltf")):
        run = subprocess.run([str(mogo), "generate", "a person walks forward", "-o", str(tmp_path / name),
                              "--bundle", str(toy_bundle), "--seconds", "1"], env=env, capture_output=True, text=True)
        assert run.returncode != 0 and not (tmp_path / name).exists()
        assert f'pip install "mogo-runtime[{extra}]"' in run.stderr and "Traceback" not in run.stderr, run.stderr
