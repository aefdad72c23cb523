"""One measured configuration per process: `python -m benchmarks.cases CASE --bundle DIR [options] --json`.

Cases (each prints one JSON object as its last stdout line with --json):
  floor   memory bandwidth (numpy copy) and sgemm throughput at the thread count of the process env
  step    step.onnx latency at a few past lengths (one variant, thread count and batch), via the runtime's session
  e2e     MotionGenerator: a fixed-length motion from text to joints, streaming time to first frame, a time
          breakdown (text, step, sampling, decode, joints, loop), peak RSS
  torch   TorchGenerator from the checkpoints, KV-cached or recomputing the sequence every step (--no-kv-cache)
  cold    a fresh process: import mogo_runtime + load the bundle + build MotionGenerator, then the first frame
  soak    one endless stream for --duration seconds of wall time, flat out, switching prompts every few seconds of
          stream time: RSS and time per token at the end of every --interval (memory or time that creeps up)
  crowd, crowd_soak   many characters in one loop (benchmarks/crowd.py)

The orchestrator (`benchmarks.run`) sets OMP/OPENBLAS/MKL_NUM_THREADS for each process. Only `torch` imports
torch, so the other processes' RSS is the runtime's alone.
"""
from __future__ import annotations

import argparse
import json
import os
import time

_T_START = time.perf_counter()   # before any heavy import: the cold case's clock starts here

from .common import (PROMPT, SOAK_LIMIT, current_rss_bytes, guided, motion_tokens, peak_rss_bytes,  # noqa: E402
                     profiled, read_manifest, stats)
from .crowd import case_crowd, case_crowd_soak  # noqa: E402


# ----------------------------------------------------------------------------------------------------------------
# floor: what the machine can do

def case_floor(args) -> dict:
    import numpy as np

    def best_of(fn, reps):
        times = []
        for _ in range(reps):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        return times

    out = {"threads": args.threads, "threads_env": os.environ.get("OMP_NUM_THREADS")}
    # Memory bandwidth, STREAM-copy style: bytes read + bytes written per second. 128 MiB per array is far past
    # the last-level cache; 4 MiB per array stays in it (the step graph's weights may live there between steps).
    for name, mib, reps in (("dram", 128, 4 if args.quick else 10), ("cache", 4, 50 if args.quick else 400)):
        n = mib * (1 << 20) // 4
        src = np.random.default_rng(0).random(n, dtype=np.float32)
        dst = np.empty_like(src)
        np.copyto(dst, src)                                                     # touch the pages first
        times = best_of(lambda: np.copyto(dst, src), reps)
        gbs = [2 * src.nbytes / t / 1e9 for t in times]
        out[f"copy_{name}_gbs"] = stats(gbs)
        out[f"copy_{name}_bytes"] = src.nbytes
        del src, dst
    # sgemm: a large square product (the throughput ceiling) and the step's shape at batch 1 (matrix x few rows).
    for name, (m, k, n), reps, inner in (("sgemm_1024", (1024, 1024, 1024), 3 if args.quick else 10, 1),
                                         ("sgemm_rows4_256x1024", (4, 256, 1024), 5 if args.quick else 20, 50)):
        a = np.random.default_rng(1).random((m, k), dtype=np.float32)
        b = np.random.default_rng(2).random((k, n), dtype=np.float32)
        a @ b
        times = best_of(lambda: [a @ b for _ in range(inner)], reps)
        out[name + "_gflops"] = stats([2 * m * k * n * inner / t / 1e9 for t in times])
    try:
        cfg = np.show_config(mode="dicts")
        out["blas"] = cfg.get("Build Dependencies", {}).get("blas", {}).get("name")
    except Exception:                                                           # noqa: BLE001 (informational)
        out["blas"] = None
    return out


# ----------------------------------------------------------------------------------------------------------------
# step: the transformer step graph alone

def case_step(args) -> dict:
    import numpy as np
    from mogo_runtime import Bundle
    from mogo_runtime.text import session_options

    # The step graph alone, batched (however the runtime would split it), on the growing cache.
    bundle = Bundle.load(args.bundle, args.variant)
    session = bundle.session("step", args.variant, session_options(args.threads))
    outputs = ["logits", *bundle.manifest.present_names]
    row_by_row = "step" in bundle.manifest.row_by_row(args.variant)             # how the runtime would run it
    m = bundle.dims
    L, K = m.num_levels, m.codebook_size
    rows = args.batch * (2 if guided(bundle.manifest) else 1)
    rng = np.random.default_rng(0)
    emb = rng.standard_normal((rows, m.text_dim)).astype(np.float32)
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    tokens = rng.integers(0, K, size=(rows, 1, L)).astype(np.int64)
    T = motion_tokens(m)
    pasts = args.pasts or sorted({1, T // 2, T})
    results = []
    for P in pasts:
        past = [rng.standard_normal((rows, L * m.n_heads, P, m.head_dim)).astype(np.float32)
                for _ in bundle.manifest.past_names]
        control = bundle.manifest.control        # a model with control reads a control vector too (zeros: none)
        feed = {"text_embedding": emb, "tokens": tokens, **dict(zip(bundle.manifest.past_names, past)),
                **({"control": np.zeros((rows, 1, control.dim), np.float32)} if control else {})}
        for _ in range(args.warmup):
            session.run(outputs, feed)
        per_repeat = []
        for _ in range(args.repeats):
            times = []
            for _ in range(args.iters):
                t = time.perf_counter()
                session.run(outputs, feed)
                times.append(time.perf_counter() - t)
            per_repeat.append(float(np.median(times)))                          # robust to a stray slow call
        results.append({"past": P, "seconds": stats(per_repeat),
                        "kv_cache_bytes": int(sum(p.nbytes for p in past))})
    return {"variant": args.variant, "threads": args.threads, "batch": args.batch, "rows": rows,
            "motion_tokens": T, "iters": args.iters, "repeats": args.repeats,
            "row_by_row_in_runtime": row_by_row and rows > 1, "points": results}


# ----------------------------------------------------------------------------------------------------------------
# e2e: text -> joints with the runtime

def case_e2e(args) -> dict:
    import numpy as np
    from mogo_runtime import MotionGenerator

    gen = MotionGenerator(args.bundle, variant=args.variant, threads=args.threads)      # as a user would
    rss_loaded = current_rss_bytes()
    fps = gen.dims.fps
    T = motion_tokens(gen.dims)
    seconds = T * gen.dims.downsample / fps
    frames = gen.tokens_for(seconds) * gen.dims.downsample
    if args.warmup:
        gen.generate(PROMPT, seconds=seconds, seed=100)                          # warm-up (first-run allocations)
    walls, ttff, stream_walls = [], [], []
    for i in range(args.repeats):
        t = time.perf_counter()
        motion = gen.generate(PROMPT, seconds=seconds, seed=args.seed + i)
        walls.append(time.perf_counter() - t)
        assert motion.joints.shape[0] == frames, (motion.joints.shape, frames)
    for i in range(args.repeats):
        t = time.perf_counter()
        n = 0
        for n, frame in enumerate(gen.stream(PROMPT, seconds=seconds, seed=args.seed + i), 1):
            if n == 1:
                ttff.append(time.perf_counter() - t)
        stream_walls.append(time.perf_counter() - t)
        assert n == frames, (n, frames)
    profile = (profiled(lambda clock: gen.generate(PROMPT, seconds=seconds, seed=args.seed, clock=clock))
               if args.profile else None)
    return {"engine": "onnxruntime", "variant": args.variant, "threads": args.threads, "kv_cache": True,
            "frames": frames, "motion_seconds": frames / fps, "tokens": T,
            "guidance": gen.sampling_defaults.guidance,
            "wall": stats(walls), "rtf": frames / fps / float(np.median(walls)),
            "stream_first_frame": stats(ttff), "stream_wall": stats(stream_walls),
            "profile": profile, "rss_after_load_bytes": rss_loaded, "peak_rss_bytes": peak_rss_bytes()}


# ----------------------------------------------------------------------------------------------------------------
# torch: the same work in eager PyTorch, from the checkpoints the bundle was exported from

def case_torch(args) -> dict:
    import numpy as np
    import torch

    import mogo_export.reference as tgen

    torch.set_num_threads(args.threads)
    manifest = read_manifest(args.bundle)
    sampling = manifest.sampling_defaults
    gen = tgen.TorchGenerator.from_checkpoints(args.checkpoints, kv_cache=args.kv_cache)
    rss_loaded = current_rss_bytes()
    be = gen.backend
    T = motion_tokens(manifest.model)
    frames = T * be.dims.downsample
    if args.warmup:
        gen.generate([PROMPT], seed=100, sampling=sampling, num_tokens=T)       # warm-up
    walls = []
    for i in range(args.repeats):
        t = time.perf_counter()
        (motion,) = gen.generate([PROMPT], seed=args.seed + i, sampling=sampling, num_tokens=T)
        walls.append(time.perf_counter() - t)
        assert motion.joints.shape[0] == frames, (motion.joints.shape, frames)
    profile = (profiled(lambda clock: gen.generate([PROMPT], seed=args.seed, sampling=sampling, num_tokens=T,
                                               clock=clock)) if args.profile else None)
    return {"engine": "torch", "variant": "fp32", "threads": args.threads, "kv_cache": args.kv_cache,
            "frames": frames, "motion_seconds": frames / be.dims.fps, "tokens": T,
            "wall": stats(walls), "rtf": frames / be.dims.fps / float(np.median(walls)),
            "profile": profile, "torch": torch.__version__, "rss_after_load_bytes": rss_loaded,
            "peak_rss_bytes": peak_rss_bytes()}


# ----------------------------------------------------------------------------------------------------------------
# cold: a fresh process from import to the first frame

def case_cold(args) -> dict:
    t0 = _T_START
    import mogo_runtime                                                        # noqa: F401
    t1 = time.perf_counter()
    import onnxruntime                                                          # noqa: F401
    t2 = time.perf_counter()
    from mogo_runtime import Bundle, MotionGenerator

    bundle = Bundle.load(args.bundle, args.variant)                              # as MotionGenerator(path)
    t3 = time.perf_counter()
    gen = MotionGenerator(bundle, variant=args.variant, threads=args.threads)        # sessions, checked
    t4 = time.perf_counter()
    T = motion_tokens(bundle.dims)
    next(iter(gen.stream(PROMPT, seconds=T * gen.dims.downsample / gen.dims.fps, seed=0)))
    t5 = time.perf_counter()
    return {"variant": args.variant, "threads": args.threads, "import_mogo_runtime": t1 - t0,
            "import_onnxruntime": t2 - t1, "bundle_load": t3 - t2, "sessions": t4 - t3,
            "import_and_load": t4 - t0, "first_frame_after_load": t5 - t4, "peak_rss_bytes": peak_rss_bytes()}


# ----------------------------------------------------------------------------------------------------------------
# soak: one endless stream for minutes

SOAK_PROMPTS = ("a person walks forward", "a person turns left", "a person waves with the right hand",
                "a person jumps in place", "a person squats down slowly", "a person runs forward",
                "a person kicks with the left leg", "a person sits down")
SOAK_SWITCH_S = (4.0, 10.0)     # stream seconds between prompts, as a game changes a character's action


def case_soak(args) -> dict:
    """A game's character for `duration` seconds: one stream, never restarted, a new prompt (never the one before)
    every SOAK_SWITCH_S seconds of motion, frames consumed as fast as they come. At the end of each `interval`
    of wall time: RSS (current and peak) and the interval's wall time per token (sampling, decoding, the frame
    loop and the switches' text encoding: what a consumer waits for). The first interval includes warm-up."""
    import numpy as np
    from mogo_runtime import MotionGenerator

    gen = MotionGenerator(args.bundle, variant=args.variant, threads=args.threads)
    base = {"variant": args.variant, "threads": args.threads, "duration_s": args.duration,
            "interval_s": args.interval}
    if not gen.endless:
        return {**base, "skipped": f"{args.bundle} has no endless streams (no 'streaming' in its manifest)"}
    fps = gen.dims.fps
    rng = np.random.default_rng(args.seed)
    lo, hi = (round(s * fps) for s in SOAK_SWITCH_S)
    prompt = int(rng.integers(len(SOAK_PROMPTS)))
    next_switch = int(rng.integers(lo, hi + 1))
    rows, switches, frames = [], 0, 0
    stream = gen.stream(SOAK_PROMPTS[prompt], seed=args.seed)
    t0 = time.perf_counter()
    mark, last_t, last_tokens, last_switches = t0 + args.interval, t0, 0, 0
    end = t0 + args.duration
    try:
        for frame in stream:
            frames += 1
            if frame.index + 1 >= next_switch:
                prompt = (prompt + 1 + int(rng.integers(len(SOAK_PROMPTS) - 1))) % len(SOAK_PROMPTS)
                stream.set_prompt(SOAK_PROMPTS[prompt])
                switches += 1
                next_switch += int(rng.integers(lo, hi + 1))
            now = time.perf_counter()
            if now >= mark:
                tokens = stream.tokens
                rows.append({"interval": len(rows) + 1, "elapsed_s": now - t0, "tokens": tokens - last_tokens,
                             "token_ms": 1e3 * (now - last_t) / max(1, tokens - last_tokens),
                             "rss_bytes": current_rss_bytes() or peak_rss_bytes(),
                             "peak_rss_bytes": current_rss_bytes("VmHWM") or peak_rss_bytes(),
                             "switches": switches - last_switches, "stream_seconds": frames / fps})
                last_t, last_tokens, last_switches = now, tokens, switches
                mark += args.interval
                if mark > end + 1e-6:
                    break
    finally:
        stream.close()
    first, last = rows[0], rows[-1]
    out = {**base, "rows": rows, "tokens": stream.tokens, "switches": switches, "stream_seconds": frames / fps,
           "rss_ratio": last["rss_bytes"] / first["rss_bytes"], "token_time_ratio": last["token_ms"] / first["token_ms"],
           "limit": SOAK_LIMIT}
    out["met"] = out["rss_ratio"] <= SOAK_LIMIT and out["token_time_ratio"] <= SOAK_LIMIT
    return out


CASES = {"floor": case_floor, "step": case_step, "e2e": case_e2e, "torch": case_torch, "cold": case_cold,
         "soak": case_soak, "crowd": case_crowd, "crowd_soak": case_crowd_soak}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.cases", description=__doc__.splitlines()[0])
    ap.add_argument("case", choices=sorted(CASES))
    ap.add_argument("--bundle", default="bundles/base")
    ap.add_argument("--checkpoints", default="checkpoints/base")
    ap.add_argument("--variant", default="int8")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--batch", type=int, default=1, help="step: prompts (rows double with guidance)")
    ap.add_argument("--pasts", type=lambda s: [int(x) for x in s.split(",") if x], default=None,
                    help="step: past lengths (default 1, T'/2, T' for a 196-frame motion)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--iters", type=int, default=30, help="step: calls per repeat (their median is one sample)")
    ap.add_argument("--warmup", type=int, default=5, help="step: calls before timing; e2e/torch: 0 = no warm-up run")
    ap.add_argument("--no-kv-cache", dest="kv_cache", action="store_false", help="torch: recompute every step")
    ap.add_argument("--quick", action="store_true", help="floor: fewer repetitions (smoke tests)")
    ap.add_argument("--profile", action="store_true", help="e2e/torch: add one instrumented generation")
    ap.add_argument("--seed", type=int, default=0, help="e2e/torch: first seed (repeat i uses seed + i); soak: its seed")
    ap.add_argument("--duration", type=float, default=600.0, help="soak: seconds of wall time")
    ap.add_argument("--interval", type=float, default=60.0, help="soak: seconds between measurements")
    ap.add_argument("--sizes", type=lambda s: [int(x) for x in s.split(",") if x],
                    default=[1, 16, 64, 128, 192, 256, 384, 512], help="crowd: the crowd sizes tried, in order")
    ap.add_argument("--chunk", type=int, default=1, help="crowd, crowd_soak: tokens per decode after the first")
    ap.add_argument("--crowd-seconds", type=float, default=10.0, help="crowd: seconds of motion per character")
    ap.add_argument("--characters", type=int, default=64, help="crowd_soak: characters")
    ap.add_argument("--json", action="store_true", help="print the result as one JSON line")
    args = ap.parse_args(argv)
    result = {"case": args.case, **CASES[args.case](args)}
    print(json.dumps(result) if args.json else json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
