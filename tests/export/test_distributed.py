"""`mogo-export train` under torchrun (mogo_export/distributed.py): 2 processes (gloo, CPU) train on the loss curve of
one process with the same global batch, a run killed on one process count resumes on another and continues that
curve, and a global batch that does not divide among the processes is a clear error.

The curves are compared in a test configuration (DRIVER): the tiny preset, with
- no dropout and no condition dropout: they draw a mask per element, and a process's slice of the batch gets
  other masks than the whole batch would;
- one streaming window per batch instead of 4, so that with 2 processes one trains on a window and the other on
  none (windows, unlike clips, need not divide among the processes);
- float64. Splitting the batch changes the order in which gradients and codebook statistics are summed, and in
  float32 the VQ's nearest-code choices and Adam's per-weight normalisation grow that rounding into loss
  differences of 1e-3 within 60 steps. One process with 2 torch threads instead of 1 drifts the same way (VQ
  loss 6e-8 apart at step 1, 4e-5 at step 30, 3e-4 at step 60, for 2 threads and for 2 processes alike). In
  float64 the curves agree to about 1e-15, which shows that the split itself is exact.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from mogo_export.checkpoint import read_checkpoint
from mogo_export.distill import TEACHER
from mogo_export.distributed import Group

ROOT = Path(__file__).resolve().parents[2]
FILES = ["captions.npz", "tokens.npz", "transformer.pt", TEACHER, "vq.pt"]
TOLERANCE = 1e-5          # per-step loss, the bar
WEIGHTS = 1e-9            # every weight and buffer at the end (float64)

# `mogo-export train` in the test configuration. With STALL_AT="N:marker" each process stops before its N-th
# optimiser step (VQ steps are 1-60, transformer steps 61-120), writes its pid to marker.RANK and waits to be killed.
DRIVER = """
import dataclasses, os, sys, time
from pathlib import Path
import torch
from mogo_export import presets, train
from mogo_export.cli import main

torch.set_default_dtype(torch.float64)
tiny = presets.PRESETS["tiny"]
presets.PRESETS["tiny"] = dataclasses.replace(
    tiny, transformer={**tiny.transformer, "dropout": 0.0, "cond_drop_prob": 0.0, "control_drop_prob": 0.0},
    streaming=dataclasses.replace(tiny.streaming, windows=1))
if os.environ.get("STALL_AT"):
    at, marker = os.environ["STALL_AT"].split(":", 1)
    calls, set_lr = [0], train._set_lr

    def stall(opt, lr):
        calls[0] += 1
        if calls[0] == int(at):
            Path(f"{marker}.{os.environ.get('RANK', '0')}").write_text(str(os.getpid()))
            time.sleep(600)
        set_lr(opt, lr)

    train._set_lr = stall
sys.exit(main(sys.argv[1:]))
"""


def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("MOGO_BLOCK_TORCH", "STALL_AT")}
    env.update(TQDM_DISABLE="1", OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "runtime")]),
               **extra)
    return env


def _command(procs: int, script: list[str]) -> list[str]:
    """One plain process, or torchrun with `procs` processes on this machine."""
    if procs == 1:
        return [sys.executable, *script]
    return [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(procs), *script]


def _start(tmp: Path, procs: int, data: Path, out: Path, log: Path, stall: str | None = None) -> subprocess.Popen:
    driver = tmp / "driver.py"
    if not driver.exists():
        driver.write_text(DRIVER)
    args = ["train", "--data", str(data), "--out", str(out), "--preset", "tiny", "--threads", "1",
            "--loss-log", str(log)]
    console = open(log.with_suffix(".console"), "w")
    # its own session, so that a kill reaches torchrun and not pytest
    proc = subprocess.Popen(_command(procs, [str(driver), *args]), cwd=ROOT, stdout=console, stderr=subprocess.STDOUT,
                            env=_env(**({"STALL_AT": stall} if stall else {})), start_new_session=True)
    console.close()
    return proc


def _train(tmp: Path, procs: int, data: Path, out: Path, log: Path) -> float:
    start = time.perf_counter()
    proc = _start(tmp, procs, data, out, log)
    assert proc.wait(timeout=300) == 0, log.with_suffix(".console").read_text()[-3000:]
    return time.perf_counter() - start


def _curve(log: Path) -> dict:
    """(phase, step) -> the global batch's loss, as rank 0 logged it; every step exactly once."""
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    curve = {(r["phase"], r["step"]): r["loss"] for r in rows}
    assert len(curve) == len(rows), f"{log}: a step was logged twice (by two processes?)"
    return curve


def _worst(curve: dict, ref: dict) -> dict:
    """Largest |loss - reference loss| per phase over the steps `curve` holds."""
    worst = {}
    for (phase, step), loss in curve.items():
        worst[phase] = max(worst.get(phase, 0.0), abs(loss - ref[phase, step]))
    return worst


def _compare_final(out: Path, ref: Path) -> float:
    """The finished checkpoints: same steps and RNG states (rank-independent), weights within WEIGHTS; -> the
    largest weight difference."""
    assert sorted(os.listdir(out)) == FILES
    worst = 0.0
    for kind in ("vq", "transformer"):
        a, b = read_checkpoint(out / f"{kind}.pt", kind), read_checkpoint(ref / f"{kind}.pt", kind)
        assert a["train"]["done"] and a["train"]["step"] == b["train"]["step"] == 60
        assert torch.equal(a["train"]["torch_rng"], b["train"]["torch_rng"]), kind
        for rng in ("numpy_rng", "val_rng"):
            assert a["train"].get(rng) == b["train"].get(rng), (kind, rng)
        assert a["model"].keys() == b["model"].keys()
        for name, t in a["model"].items():
            assert t.dtype == b["model"][name].dtype == (torch.float64 if t.is_floating_point() else t.dtype)
            worst = max(worst, (t.double() - b["model"][name].double()).abs().max().item() if t.numel() else 0.0)
    assert worst <= WEIGHTS, worst
    return worst


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The dataset, and the test configuration trained uninterrupted by 1 process and by 2."""
    from mogo_export.data.procedural import build_dataset

    tmp = tmp_path_factory.mktemp("distributed")
    data = build_dataset(tmp / "data", num_clips=60, seed=0, progress=False)
    seconds = {n: _train(tmp, n, data, tmp / f"p{n}", tmp / f"p{n}.jsonl") for n in (1, 2)}
    return {"tmp": tmp, "data": data, "seconds": seconds}


def test_two_processes_train_on_the_curve_of_one(runs):
    tmp = runs["tmp"]
    one, two = _curve(tmp / "p1.jsonl"), _curve(tmp / "p2.jsonl")
    assert sorted(one) == sorted(two) and len(one) == 120          # 60 VQ steps, 60 transformer steps
    worst = _worst(two, one)
    weights = _compare_final(tmp / "p2", tmp / "p1")
    print(f"\n1 process {runs['seconds'][1]:.1f} s, 2 processes {runs['seconds'][2]:.1f} s; largest loss difference "
          f"per step: vq {worst['vq']:.2g}, transformer {worst['transformer']:.2g}; weights {weights:.2g}")
    assert max(worst.values()) <= TOLERANCE, worst
    # the losses moved: the comparison is of a curve, not of a constant
    assert one["transformer", 60] < one["transformer", 1] - 0.5


def _wait_for_markers(proc: subprocess.Popen, marker: Path, procs: int) -> list[int]:
    deadline = time.monotonic() + 180
    files = [Path(f"{marker}.{rank}") for rank in range(procs)]
    while not all(f.exists() and f.read_text() for f in files):
        assert proc.poll() is None, "training ended before the step it should stall at"
        assert time.monotonic() < deadline, "training never reached the step it should stall at"
        time.sleep(0.05)
    return [int(f.read_text()) for f in files]


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _kill9(proc: subprocess.Popen, pids: list[int]) -> None:
    """SIGKILL to torchrun's process group and to every worker's: torch elastic starts each worker in a session
    of its own, so the group of torchrun alone would leave them training."""
    for pid in dict.fromkeys([proc.pid, *pids]):
        try:
            os.killpg(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    proc.wait(timeout=30)
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in pids):
        assert time.monotonic() < deadline, "a worker survived SIGKILL"
        time.sleep(0.05)


@pytest.mark.parametrize("first,then,stall_at,state", [
    (2, 1, 100, ("transformer", 30)),     # killed at transformer step 40; resumed by one process
    (1, 2, 40, ("vq", 30)),               # killed at VQ step 40; resumed by two, who also train the transformer
])
def test_killed_run_resumes_on_another_process_count(runs, first, then, stall_at, state):
    tmp, data = runs["tmp"], runs["data"]
    ref = _curve(tmp / "p1.jsonl")
    case = tmp / f"killed_{first}_then_{then}"
    out, marker = case / "out", case / "stalled"
    case.mkdir()
    proc = _start(tmp, first, data, out, case / "first.jsonl", stall=f"{stall_at}:{marker}")
    try:
        pids = _wait_for_markers(proc, marker, first)
    finally:
        _kill9(proc, [int(p.read_text()) for p in case.glob("stalled.*") if p.read_text()])
    assert len(pids) == first and all(not _alive(p) for p in pids)

    kind, step = state
    ckpt = read_checkpoint(out / f"{kind}.pt", kind)["train"]
    assert ckpt["step"] == step and not ckpt["done"]                 # killed after a checkpoint, mid-phase
    # whole files only (the teacher's copy comes with the distillation, after the transformer has finished)
    assert sorted(os.listdir(out)) == ([f for f in FILES if f != TEACHER] if kind == "transformer" else ["vq.pt"])
    killed = _curve(case / "first.jsonl")
    assert max(s for p, s in killed if p == kind) == 39             # steps 31-39 ran and are lost

    seconds = _train(tmp, then, data, out, case / "resumed.jsonl")
    resumed = _curve(case / "resumed.jsonl")
    # it continued from the checkpoint, to the end
    assert set(resumed) == {(p, s) for p, s in ref if (p == kind and s > step) or (kind, p) == ("vq", "transformer")}
    worst_killed, worst_resumed = _worst(killed, ref), _worst(resumed, ref)
    weights = _compare_final(out, tmp / "p1")
    print(f"\n{first} process(es) killed at {kind} step 40, {then} resumed from step {step} ({seconds:.1f} s): "
          f"largest loss difference to the uninterrupted run before the kill {max(worst_killed.values()):.2g}, "
          f"after {max(worst_resumed.values()):.2g}; weights {weights:.2g}")
    assert max(worst_killed.values()) <= TOLERANCE and max(worst_resumed.values()) <= TOLERANCE


def test_the_tiny_preset_as_it_is_trains_under_torchrun(runs, tmp_path):
    """The command a user runs (float32, dropout on): it trains, rank 0 alone writes and prints, the result loads;
    the VQ's batches were one process's (its numpy RNG state is the 1-process run's: the test configuration
    differs in the transformer only)."""
    from mogo_export.checkpoint import load_trained

    out, log = tmp_path / "out", tmp_path / "loss.jsonl"
    args = ["-m", "mogo_export.cli", "train", "--data", str(runs["data"]), "--out", str(out), "--preset", "tiny",
            "--threads", "1", "--loss-log", str(log)]
    for attempt in ("train", "again"):
        done = subprocess.run(_command(2, args), cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
        said = done.stdout + done.stderr
        if attempt == "train":
            assert said.count("trained tiny in") == 1 and "on 2 processes (cpu)" in said
        else:     # a finished folder is skipped, and said so once
            assert said.count("is complete, skipping") == 2 and "trained tiny in" in said
    curve = _curve(log)
    assert len(curve) == 120 and curve["transformer", 60] < curve["transformer", 1] - 0.5
    assert sorted(os.listdir(out)) == FILES
    models = load_trained(out)
    assert models.vq_step == models.transformer_step == 60
    a, b = (read_checkpoint(folder / "vq.pt", "vq")["train"] for folder in (out, runs["tmp"] / "p1"))
    assert a["numpy_rng"] == b["numpy_rng"]


def test_a_batch_that_does_not_divide_among_the_processes_is_a_clear_error(runs, tmp_path):
    assert [Group(rank=r, world=4).shard(8, "batch") for r in range(4)] == [slice(0, 2), slice(2, 4), slice(4, 6),
                                                                            slice(6, 8)]
    assert Group().shard(8, "batch") == slice(0, 8)
    # streaming windows are split unevenly where they must be
    assert [Group(rank=r, world=3).part(4) for r in range(3)] == [slice(0, 2), slice(2, 3), slice(3, 4)]
    assert [Group(rank=r, world=2).part(1) for r in range(2)] == [slice(0, 1), slice(1, 1)]
    with pytest.raises(ValueError, match="vq batch: the global batch of 8 does not divide among 3 processes"):
        Group(rank=0, world=3).shard(8, "vq batch")

    out = tmp_path / "out"
    args = ["-m", "mogo_export.cli", "train", "--data", str(runs["data"]), "--out", str(out), "--preset", "tiny"]
    done = subprocess.run(_command(3, args), cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert ("mogo-export: error: preset 'tiny', vq: the global batch of 8 does not divide among 3 processes"
            in done.stdout + done.stderr), done.stderr[-3000:]
    assert not out.exists()                       # refused before any work
