"""`mogo-export train` killed with kill -9, then resumed, ends exactly where an uninterrupted run ends: the checkpoint
folder never holds a stray temporary file or a file that does not load, and the resumed run's weights, optimiser
state, validation metrics and token files are bit for bit the uninterrupted run's.

One kill lands inside a checkpoint write for sure (torch.save is held half-way through in that run); the others at
seeded random moments (MOGO_TRAIN_KILL9_RUNS of them, default 3; MOGO_TRAIN_KILL9_SEED).
"""
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from mogo_export.checkpoint import read_checkpoint

ROOT = Path(__file__).resolve().parents[2]
RUNS = int(os.environ.get("MOGO_TRAIN_KILL9_RUNS", "3"))
SEED = int(os.environ.get("MOGO_TRAIN_KILL9_SEED", "0"))
FILES = ("captions.npz", "tokens.npz", "transformer.pt", "transformer.teacher.pt", "vq.pt")   # a finished run, no more

# Training with torch.save held mid-write: the first checkpoint's bytes are half written when `marker` appears,
# and the process waits there to be killed.
STALL_IN_SAVE = """
import io, sys, time
from pathlib import Path
import torch
real_save = torch.save
def save(obj, f, *a, **k):
    buf = io.BytesIO()
    real_save(obj, buf, *a, **k)
    data = buf.getvalue()
    f.write(data[:len(data) // 2])
    f.flush()
    Path(sys.argv[1]).write_text("writing")
    time.sleep(600)
torch.save = save
from mogo_export.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _env() -> dict:
    env = {k: v for k, v in os.environ.items() if k != "MOGO_BLOCK_TORCH"}
    env.update(TQDM_DISABLE="1", OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "runtime")]))
    return env


def _train_args(data: Path, out: Path) -> list[str]:
    return ["train", "--data", str(data), "--out", str(out), "--preset", "tiny", "--threads", "1"]


def _train(data: Path, out: Path) -> float:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "mogo_export.cli", *_train_args(data, out)], cwd=ROOT, env=_env(),
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return time.perf_counter() - start


def _check_folder(out: Path, when: str) -> str:
    """Only finished-format files, each of which loads; -> a short description of the training state."""
    names = sorted(os.listdir(out)) if out.exists() else []
    assert set(names) <= set(FILES), f"{when}: stray files {sorted(set(names) - set(FILES))}"
    state = []
    for kind in ("vq", "transformer"):
        if f"{kind}.pt" in names:
            train = read_checkpoint(out / f"{kind}.pt", kind)["train"]         # raises on a partial file
            state.append(f"{kind} step {train['step']}{' done' if train['done'] else ''}")
    for name in ("tokens.npz", "captions.npz"):
        if name in names:
            with np.load(out / name) as z:
                for k in z.files:
                    z[k]
            state.append(name)
    return ", ".join(state) or "empty"


def _snapshot(out: Path, name: str | None = None) -> list:
    """Names and modification times of the folder's files (of `name` only, if given): a change means a write. A
    temporary file renamed between the listing and its stat is left out (CI saw one go)."""
    snapshot = []
    for p in out.iterdir() if out.exists() else []:
        if name in (None, p.name):
            try:
                snapshot.append((p.name, p.stat().st_mtime_ns))
            except FileNotFoundError:
                pass
    return sorted(snapshot)


def _assert_same(a, b, where: str) -> None:
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), f"{where}: keys {sorted(a)} != {sorted(b)}"
        for k in a:
            _assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b or (a != a and b != b), f"{where}: {a!r} != {b!r}"     # NaN == NaN here


def test_kill9_during_training_resumes_to_the_uninterrupted_result(tmp_path):
    data = tmp_path / "data"
    subprocess.run([sys.executable, "-m", "mogo_export.cli", "dataset", str(data), "--clips", "60", "--seed", "0"],
                   cwd=ROOT, env=_env(), check=True, capture_output=True)
    ref, cut = tmp_path / "ref", tmp_path / "cut"
    full = _train(data, ref)

    # 1. killed while the first checkpoint (vq.pt, step 30) is half written
    marker = tmp_path / "writing"
    proc = subprocess.Popen([sys.executable, "-c", STALL_IN_SAVE, str(marker), *_train_args(data, cut)], cwd=ROOT,
                            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not marker.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "training never reached a checkpoint"
            time.sleep(0.02)
    finally:
        proc.kill()
        proc.wait()
    log = [f"killed inside the first checkpoint write: {_check_folder(cut, 'mid-write kill')}"]
    assert not (cut / "vq.pt").exists()          # the half-written checkpoint did not take the name

    # 2. killed at random moments, each run resuming from what the last one left: a random delay after a write
    # (the first run's after vq.pt's step-30 checkpoint, the second's after transformer.pt's, so that both models
    # resume mid-training; later runs after any write), short enough to land before the next stage
    rng = random.Random(SEED)
    # (file to watch, longest delay after it changes as a fraction of a whole run): 30 VQ steps take ~8% of a
    # run, 30 transformer steps ~25%
    plan = [("vq.pt", 0.02), ("transformer.pt", 0.05)][:RUNS] + [(None, 0.1)] * (RUNS - 2)
    states = []
    for i, (watch, longest) in enumerate(plan):
        before = _snapshot(cut, watch)
        err = tmp_path / f"run{i}.stderr"      # a run that ends on its own says why (the test's message shows it)
        with open(err, "w") as stderr:
            proc = subprocess.Popen([sys.executable, "-m", "mogo_export.cli", *_train_args(data, cut)], cwd=ROOT,
                                    env=_env(), stdout=subprocess.DEVNULL, stderr=stderr)
        while _snapshot(cut, watch) == before and proc.poll() is None:
            time.sleep(0.005)
        ended = proc.poll()
        delay = rng.uniform(0.0, longest * full)
        time.sleep(delay)
        proc.kill()
        code = proc.wait()
        states.append(_check_folder(cut, f"kill {i}"))
        log.append(f"killed {delay:.2f} s after writing {watch or 'a file'}{' (had finished)' if code == 0 else ''}"
                   f": {states[-1]}")
        assert ended in (None, 0), (f"run {i} ended on its own with code {ended} before writing "
                                    f"{watch or 'a file'}: {'; '.join(log)}\n{err.read_text()[-3000:]}")
    if RUNS >= 2:    # each model was killed mid-training, so each resumed from a checkpoint that was not its last
        assert states[0] == "vq step 30" and states[1].startswith("vq step 60 done, transformer step 30,"), states
    _train(data, cut)                            # resume to the end
    log.append(f"resumed to the end: {_check_folder(cut, 'final')}")
    print(f"\nuninterrupted run {full:.1f} s; " + "; ".join(log))

    assert sorted(os.listdir(cut)) == sorted(os.listdir(ref)) == sorted(FILES)
    for kind in ("vq", "transformer"):
        a, b = read_checkpoint(ref / f"{kind}.pt", kind), read_checkpoint(cut / f"{kind}.pt", kind)
        for part in ("model", "train", "config"):   # train: step, optimiser state, RNG states
            _assert_same(a[part], b[part], f"{kind}.{part}")
        meta_a, meta_b = dict(a["meta"]), dict(b["meta"])
        assert meta_a.pop("dataset") == meta_b.pop("dataset") == str(data)
        _assert_same(meta_a, meta_b, f"{kind}.meta")  # validation metrics included
    for name in ("tokens.npz", "captions.npz"):
        with np.load(ref / name) as za, np.load(cut / name) as zb:
            assert za.files == zb.files
            for k in za.files:
                assert np.array_equal(za[k], zb[k]), f"{name}: {k}"
