"""A tiny trained bundle for end-to-end tests, built once per source version and shared by both test processes.

Built in a subprocess (the runtime's test process never imports torch): 60 procedural clips, the `tiny` preset
trained for a few dozen steps, exported with int8 variants. Cached under .cache/ keyed by a hash of the
source files, so `make test` pays for it once.
"""
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _source_key() -> str:
    h = hashlib.sha256()
    for folder in (ROOT / "mogo_export", ROOT / "runtime" / "mogo_runtime", ROOT / "tests" / "tiny_bundle.py"):
        files = [folder] if folder.is_file() else sorted(folder.rglob("*.py"))
        for f in files:
            h.update(f.relative_to(ROOT).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:12]


_BUILT: dict[str, tuple[Path, Path]] = {}


def ensure_tiny_bundle() -> tuple[Path, Path]:
    """-> (checkpoint folder, bundle folder), building them if this source version has none yet."""
    if "tiny" not in _BUILT:
        _BUILT["tiny"] = _build()
    return _BUILT["tiny"]


def _build() -> tuple[Path, Path]:
    cache = ROOT / ".cache"
    root = cache / f"tiny-{_source_key()}"
    ckpt, bundle = root / "checkpoints", root / "bundle"
    if (bundle / "manifest.json").exists():
        return ckpt, bundle
    if cache.exists():
        for old in cache.glob("tiny-*"):
            shutil.rmtree(old, ignore_errors=True)
    env = {k: v for k, v in os.environ.items() if k != "MOGO_BLOCK_TORCH"}
    env["TQDM_DISABLE"] = "1"
    cli = [sys.executable, "-m", "mogo_export.cli"]
    for args in (["dataset", str(root / "data"), "--clips", "60", "--seed", "0"],
                 ["train", "--data", str(root / "data"), "--out", str(ckpt), "--preset", "tiny"],
                 ["export", str(ckpt), "--out", str(bundle)]):
        done = subprocess.run(cli + args, env=env, cwd=ROOT, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"building the tiny bundle failed at `mogo-export {' '.join(args)}`:\n"
                               f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    return ckpt, bundle
