"""Each variant of a bundle on other CPUs, emulated by QEMU as a user on another machine would run it: does it stay
as close to fp32 there, and does it compute the numbers it computes here?

    .venv/bin/python -m benchmarks.cpu_kinds --bundle bundles/base [--prompts 8] [--kinds native,haswell,nehalem,arm64]

Kinds: `native` (this machine), `haswell` (qemu-x86_64 -cpu Haswell: AVX2, no VNNI, as most gaming PCs in use),
`nehalem` (-cpu Nehalem: SSE4.2 only) and `arm64` (qemu-aarch64 -cpu cortex-a76, Debian's arm64 python with PyPI's
aarch64 wheels: benchmarks/qemu_setup.sh builds that root and installs qemu-user). Emulation runs 100-350x slower:
keep --prompts small on `base`.

Here, fp32's greedy sequences of the prompts (native). Then each kind runs a worker process (`... cpu_kinds worker`,
torch-free) that steps every variant through those sequences one step at a time (mogo_export/agreement.py) and
saves the logits and the text embeddings. Per kind and variant: teacher-forced argmax agreement with native fp32,
the largest logit and embedding difference to the same variant run natively, and whether they are identical.
`--json FILE` writes the table; exit 1 if an int8 variant's agreement is below --bar (0.95) on some kind.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("fp32", "int8", "int8_fixed", "compact")
KINDS = ("native", "haswell", "nehalem", "arm64")
PROMPTS = ["a person walks forward", "a person jumps twice", "a person waves with the right hand",
           "a person kicks with the left leg", "a person sits down on the ground", "a person does a backflip",
           "a person runs forward quickly", "a person turns around", "a person dances", "a person salutes",
           "a person walks in a circle", "a person throws a ball overhand"]


def kind_command(kind: str, arm64_root: Path | None) -> tuple[list[str], dict]:
    """The command prefix (emulator and python) that runs a worker on `kind`, and its environment."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "runtime")])}
    if kind == "native":
        return [sys.executable], env
    if kind in ("haswell", "nehalem"):
        return ["qemu-x86_64", "-cpu", kind.capitalize(), sys.executable], env
    if kind == "arm64":
        env["PYTHONPATH"] = os.pathsep.join([str(arm64_root / "site"), env["PYTHONPATH"]])
        return ["qemu-aarch64", "-cpu", "cortex-a76", "-L", str(arm64_root),
                str(arm64_root / "usr" / "bin" / "python3.11")], env
    raise ValueError(f"unknown CPU kind {kind!r}; known: {', '.join(KINDS)}")


def worker(bundle: Path, refs: Path, out: Path) -> None:
    """Every variant stepped through the reference sequences; logits and embeddings saved (no torch here)."""
    import platform

    from mogo_export.agreement import forced_logits
    from mogo_runtime.bundle import Bundle
    from mogo_runtime.engine import open_backend

    r = np.load(refs)
    prompts = [str(p) for p in r["prompts"]]
    seqs = [r[f"seq{i}"] for i in range(len(prompts))]
    b = Bundle.load(bundle)
    saved = {"machine": np.array(platform.machine())}
    for v in (v for v in VARIANTS if v in b.variants):
        t0 = time.perf_counter()
        backend = open_backend(b, v, threads=1)
        saved[f"{v}/emb"] = backend.encode_text(prompts)
        for i, logits in enumerate(forced_logits(backend, prompts, seqs)):
            saved[f"{v}/logits{i}"] = logits
        print(f"  {v}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    np.savez(out, **saved)


def compare(results: dict, prompts: int) -> list[dict]:
    rows = []
    native = results["native"]
    ref = [native[f"fp32/logits{i}"].argmax(-1) for i in range(prompts)]
    for kind, res in results.items():
        for v in VARIANTS:
            if f"{v}/emb" not in res:
                continue
            logits = [res[f"{v}/logits{i}"] for i in range(prompts)]
            same = sum(int((a == b.argmax(-1)).sum()) for a, b in zip(ref, logits))
            total = sum(a.size for a in ref)
            diff = max(float(np.abs(a - native[f"{v}/logits{i}"]).max()) for i, a in enumerate(logits))
            emb = float(np.abs(res[f"{v}/emb"] - native[f"{v}/emb"]).max())
            rows.append({"kind": kind, "machine": str(res["machine"]), "variant": v, "agreement": same / total,
                         "logits_vs_native": diff, "embedding_vs_native": emb,
                         "identical_to_native": diff == 0.0 and emb == 0.0})
    return rows


def main(argv=None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["worker"]:
        ap = argparse.ArgumentParser(prog="cpu_kinds worker")
        ap.add_argument("--bundle", type=Path, required=True)
        ap.add_argument("--refs", type=Path, required=True)
        ap.add_argument("--out", type=Path, required=True)
        a = ap.parse_args(argv[1:])
        worker(a.bundle, a.refs, a.out)
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", type=Path, default=ROOT / "bundles" / "base")
    ap.add_argument("--prompts", type=int, default=8)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--bar", type=float, default=0.95, help="teacher-forced agreement every variant must keep")
    ap.add_argument("--json", type=Path)
    opts = ap.parse_args(argv)
    kinds = opts.kinds.split(",")
    for k in kinds:
        kind_command(k, Path("."))                                    # unknown kinds fail before any work
    arm64_root = None
    if any(k != "native" for k in kinds):
        setup = subprocess.run(["bash", str(ROOT / "benchmarks" / "qemu_setup.sh")], capture_output=True, text=True)
        if setup.returncode != 0:
            print(setup.stderr, file=sys.stderr)
            return 2
        arm64_root = Path(setup.stdout.strip().splitlines()[-1])

    from mogo_export.agreement import greedy_tokens
    from mogo_runtime.bundle import Bundle
    from mogo_runtime.engine import OrtBackend

    bundle = Bundle.load(opts.bundle)
    prompts = (PROMPTS * (opts.prompts // len(PROMPTS) + 1))[:opts.prompts]
    fp32 = OrtBackend(bundle, "fp32", threads=1)
    seqs = greedy_tokens(fp32, prompts, list(range(len(prompts))), bundle.dims.max_tokens)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        refs = Path(tmp) / "refs.npz"
        np.savez(refs, prompts=np.array(prompts), **{f"seq{i}": s for i, s in enumerate(seqs)})
        for kind in (["native"] + [k for k in kinds if k != "native"]):
            t0 = time.perf_counter()
            print(f"{kind}: {len(prompts)} prompts, {sum(len(s) + 1 for s in seqs)} steps per variant ...", file=sys.stderr,
                  flush=True)
            prefix, env = kind_command(kind, arm64_root)
            out = Path(tmp) / f"{kind}.npz"
            done = subprocess.run(prefix + ["-m", "benchmarks.cpu_kinds", "worker", "--bundle",
                                            str(opts.bundle.resolve()), "--refs", str(refs), "--out", str(out)],
                                  env=env, cwd=ROOT, stderr=subprocess.PIPE, text=True)
            noise = "TCG doesn't support requested feature"        # qemu's note on CPUID bits it leaves out
            print("\n".join(l for l in done.stderr.splitlines() if noise not in l), file=sys.stderr)
            if done.returncode != 0:
                print(f"{kind}: the worker failed ({done.returncode})", file=sys.stderr)
                return 2
            results[kind] = dict(np.load(out))
            print(f"{kind}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows = compare(results, len(prompts))
    print(f"| CPU kind | variant | teacher-forced agreement with native fp32 | max logit diff to native | "
          f"max embedding diff to native |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['kind']} ({r['machine']}) | {r['variant']} | {r['agreement']:.3f} | {r['logits_vs_native']:.2e} | "
              f"{r['embedding_vs_native']:.2e} |")
    if opts.json:
        opts.json.write_text(json.dumps({"bundle": str(opts.bundle), "prompts": prompts, "rows": rows}, indent=1))
    low = [r for r in rows if r["agreement"] < opts.bar]
    for r in low:
        print(f"below {opts.bar}: {r['variant']} on {r['kind']}: {r['agreement']:.3f}", file=sys.stderr)
    return 1 if low else 0


if __name__ == "__main__":
    sys.exit(main())
