"""`make bench`: every configuration of issue 6 in its own process, repeated; JSON + a Markdown table.

    python -m benchmarks.run [--bundle bundles/base] [--checkpoints checkpoints/base] [--repeats 5]

Writes benchmarks/results/<timestamp>.json and benchmarks/results/latest.md (and prints the table). Each round runs
every configuration once, each in a fresh process (`benchmarks.cases`); rounds repeat, so load drift on a shared
machine spreads over all configurations alike. Absolute times are context only; the goals are judged on ratios
measured within one run. After the rounds, a soak: one endless stream with prompt switches for --soak seconds
(default 600), RSS and time per token each minute (benchmarks/README.md).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from mogo_runtime.bundle import read_manifest
from mogo_runtime.bundle.manifest import INT8_FIXED, PORTABLE, Manifest

from .common import motion_tokens
from .report import _med, markdown

ROOT = Path(__file__).resolve().parent.parent

GOALS = [  # key, measure, goal text, threshold, direction (issue 6's goals, raised by issue 18 where it set them)
    ("rtf_int8_t1", "real-time factor, int8, 1 thread", "≥ 200×", 200.0, ">="),
    ("crowd_int8", "concurrent real-time characters on one core (int8_fixed; p99 frame lateness ≤ 50 ms at "
     "20 fps)", "≥ 500", 500, ">="),
    ("ttff_int8_t1", "time to first frame (streaming, includes text encoding), int8, 1 thread", "≤ 5 ms", 0.005,
     "<="),
    ("stream_over_generate", "streaming (all frames) ÷ generate, int8, 1 thread", "≤ 1.1", 1.1, "<="),
    ("cold_start", "cold start, import + load (int8, fresh process)", "≤ 0.3 s", 0.3, "<="),
    ("int8_over_fp32_step", "int8 step ÷ fp32 step (batch 1, 1 thread, past T'/2)", "≤ 0.5", 0.5, "<="),
    ("step_over_floor", "step time ÷ physical floor (int8, batch 1, 1 thread, past T'/2; DRAM floor)", "≤ 2", 2.0,
     "<="),
    ("crowd_soak", "64 characters for the crowd soak: tick time and RSS, last interval ÷ first", "≤ 1.1", 1.1,
     "<="),
    ("ort_over_torch", "ORT fp32 end-to-end ÷ torch eager (KV-cached) end-to-end, 1 thread", "≤ 0.33", 0.33, "<="),
    ("kv_over_recompute", "KV-cached ÷ recompute-every-step end-to-end (torch, 1 thread)", "≤ 0.1", 0.1, "<="),
    ("step_over_cache_floor", "step time ÷ cache-resident floor (same step; weights in L3, stricter)", "≤ 2", 2.0,
     "<="),
    ("peak_rss", "runtime peak RSS (int8, 1 thread, generate + stream)", "≤ 200 MB", 200e6, "<="),
]


# ----------------------------------------------------------------------------------------------------------------
# running cases

def run_case(case: str, args: list[str], threads: int, timeout: float) -> dict:
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(threads)
    env.pop("MOGO_BLOCK_TORCH", None)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(ROOT / "runtime")] +
                                        ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    cmd = [sys.executable, "-m", "benchmarks.cases", case, "--threads", str(threads), *args, "--json"]
    t = time.perf_counter()
    try:
        done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"case": case, "error": f"timed out after {timeout:.0f} s", "cmd": cmd}
    wall = time.perf_counter() - t
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
    if done.returncode != 0 or not lines:
        return {"case": case, "error": f"exit {done.returncode}: {done.stderr.strip()[-2000:]}", "cmd": cmd,
                "process_wall": wall}
    result = json.loads(lines[-1])
    result["process_wall"] = wall
    return result


def plan(opts, rnd: int) -> list[tuple[str, str, list[str], int]]:
    """The processes of round `rnd` (0-based): every configuration once -> [(label, case, args, threads)].

    Rounds run one after another, so a configuration's repeats are spread over the whole run and a slow spell on a
    shared machine hits every configuration alike (ratios stay fair). Round 0 also profiles one generation."""
    b = ["--bundle", str(opts.bundle)]
    one = ["--repeats", str(opts.per_process)]
    quick = ["--quick"] if opts.quick else []
    step_warm = ["--warmup", "1"] if opts.quick else []
    gen_opts = (["--warmup", "0"] if opts.quick else []) + (["--profile"] if rnd == 0 else [])
    gen_opts += ["--seed", str(rnd * opts.per_process)]
    jobs = []
    for th in opts.threads:
        jobs.append((f"floor threads={th}", "floor", b + quick, th))
    for v in opts.variants:
        for th in opts.threads:
            for batch in opts.batches:
                jobs.append((f"step {v} threads={th} batch={batch}", "step",
                             b + one + step_warm + ["--variant", v, "--batch", str(batch), "--iters", str(opts.iters)],
                             th))
    for v in opts.e2e_variants:
        for th in opts.threads:
            jobs.append((f"e2e onnxruntime {v} threads={th}", "e2e", b + one + gen_opts + ["--variant", v], th))
    if opts.torch:
        ck = ["--checkpoints", str(opts.checkpoints)]
        for kv in (True, False):
            for th in opts.threads:
                jobs.append((f"torch {'kv-cache' if kv else 'recompute'} threads={th}", "torch",
                             b + ck + one + gen_opts + ([] if kv else ["--no-kv-cache"]), th))
    if rnd < opts.cold_repeats:
        for v in opts.variants:
            jobs.append((f"cold start {v}", "cold", b + ["--variant", v], 1))
    return jobs


def _merge_stats(items: list[dict | None]) -> dict | None:
    values = [x for s in items if s and s.get("n") for x in s["values"]]
    return _stats(values) if values else None


def merge(results: list[dict]) -> list[dict]:
    """Processes of the same configuration (one per round) -> one result, their samples pooled."""
    groups: dict[tuple, list[dict]] = {}
    for r in results:
        if "error" in r or r["case"] in ("cold", "soak", "crowd", "crowd_soak"):
            continue
        key = (r["case"], r.get("variant"), r["threads"], r.get("batch"), r.get("engine"), r.get("kv_cache"))
        groups.setdefault(key, []).append(r)
    merged = []
    for key, rs in groups.items():
        m = dict(rs[0])
        m["processes"] = len(rs)
        case = key[0]
        if case == "floor":
            for k, v in rs[0].items():
                if isinstance(v, dict) and "values" in v:
                    m[k] = _merge_stats([r[k] for r in rs])
        elif case == "step":
            m["points"] = [{**p, "seconds": _merge_stats([r["points"][i]["seconds"] for r in rs])}
                           for i, p in enumerate(rs[0]["points"])]
        else:
            for k in ("wall", "stream_first_frame", "stream_wall"):
                if k in m:
                    m[k] = _merge_stats([r.get(k) for r in rs])
            m["rtf"] = m["motion_seconds"] / m["wall"]["median"]
            m["peak_rss_bytes"] = max(r["peak_rss_bytes"] for r in rs)
            m["profile"] = next((r["profile"] for r in rs if r.get("profile")), None)
        merged.append(m)
    return merged


# ----------------------------------------------------------------------------------------------------------------
# the physical floor of one step

def step_work(bundle: Path, manifest: Manifest) -> dict:
    """Matmul weights per graph row kind, from step.onnx (exact), or an estimate from the manifest."""
    m = manifest.model
    C, R1, K = m.n_heads * m.head_dim, m.max_rel_dist + 1, m.codebook_size
    work = {"per_stream": 0, "per_prompt": 0, "per_head_row": 0, "source": "step.onnx"}
    try:
        import onnx

        g = onnx.load(str(bundle / manifest.graph_file("step", "fp32").file)).graph
        shapes = {i.name: tuple(i.dims) for i in g.initializer}
        for n in g.node:
            if n.op_type == "Constant":
                for a in n.attribute:
                    if a.name == "value":
                        shapes[n.output[0]] = tuple(a.t.dims)
        for n in g.node:
            if n.op_type not in ("MatMul", "Gemm") or len(n.input) < 2:
                continue
            w = shapes.get(n.input[1])
            if w is None or len(w) != 2:
                continue                                   # activation x activation: attention, counted below
            k, nn = w
            if n.input[0] == "text_embedding":
                work["per_prompt"] += k * nn               # cond_proj: one row per prompt
            elif C in (k, nn) and R1 in (k, nn):
                work["per_head_row"] += k * nn             # q+v against every phi row, one row per stream and head
            else:
                work["per_stream"] += k * nn
    except Exception as e:                                                      # noqa: BLE001
        L = m.n_layers
        work = {"per_stream": L * 12 * C * C + C * (K + 1), "per_prompt": m.text_dim * C,
                "per_head_row": L * C * R1, "source": f"estimate ({type(e).__name__}: {e})"}
    return work


def step_floor(manifest: Manifest, work: dict, weight_bytes: int, rows: int, past: int, bandwidth: float,
               flops_per_s: float) -> dict:
    m = manifest.model
    L, H, hd, NL = m.num_levels, m.n_heads, m.head_dim, m.n_layers
    streams = rows * L
    flops = 2 * (work["per_stream"] * streams + work["per_prompt"] * rows + work["per_head_row"] * streams * H)
    flops += NL * 2 * 2 * streams * H * hd * (past + 1)                       # q.k and att.v
    kv_bytes = 2 * NL * streams * H * past * hd * 4                             # float32 cache, read once
    bytes_read = weight_bytes + kv_bytes
    t_mem, t_flop = bytes_read / bandwidth, flops / flops_per_s
    return {"flops": flops, "bytes": bytes_read, "kv_bytes": kv_bytes, "t_mem": t_mem, "t_flops": t_flop,
            "floor": max(t_mem, t_flop), "bound": "memory" if t_mem >= t_flop else "compute"}


# ----------------------------------------------------------------------------------------------------------------
# summary

def summarize(results: list[dict], manifest: Manifest, bundle: Path, opts) -> dict:
    ok = merge(results) + [r for r in results if "error" not in r and r["case"] == "cold"]
    floors = {r["threads"]: r for r in ok if r["case"] == "floor"}
    files = manifest.files                                                      # name -> (bytes, sha256)
    variant_bytes = {}
    for v, graphs in manifest.variants.items():
        names = {g.file for g in graphs.values()} | {n for n in files if not n.endswith(".onnx")}
        variant_bytes[v] = {"total": sum(files[n][0] for n in names),
                            **{g: files[spec.file][0] for g, spec in graphs.items()}}
    work = step_work(bundle, manifest)

    steps = []
    for r in (r for r in ok if r["case"] == "step"):
        fl = floors.get(r["threads"]) or floors.get(1)
        for p in r["points"]:
            row = {"variant": r["variant"], "threads": r["threads"], "batch": r["batch"], "rows": r["rows"],
                   "past": p["past"], "seconds": p["seconds"]}
            if fl:
                wb = variant_bytes[r["variant"]]["step"]
                gf = _med(fl["sgemm_1024_gflops"]) * 1e9
                dram = step_floor(manifest, work, wb, r["rows"], p["past"], _med(fl["copy_dram_gbs"]) * 1e9, gf)
                cache = step_floor(manifest, work, wb, r["rows"], p["past"], _med(fl["copy_cache_gbs"]) * 1e9, gf)
                row.update(floor=dram, cache_floor=cache, over_floor=_med(p["seconds"]) / dram["floor"],
                           over_cache_floor=_med(p["seconds"]) / cache["floor"])
            steps.append(row)
    e2e = [r for r in ok if r["case"] in ("e2e", "torch")]
    colds = [r for r in ok if r["case"] == "cold"]
    cold = {}
    for v in sorted({r["variant"] for r in colds}):
        rs = [r for r in colds if r["variant"] == v]
        cold[v] = {k: _stats([r[k] for r in rs]) for k in ("import_mogo_runtime", "import_onnxruntime", "bundle_load",
                                                             "sessions", "import_and_load", "first_frame_after_load",
                                                             "process_wall")}
        cold[v]["peak_rss_bytes"] = max(r["peak_rss_bytes"] for r in rs)

    def find_e2e(engine, variant, threads, kv=True):
        for r in e2e:
            if r["engine"] == engine and r["variant"] == variant and r["threads"] == threads and r["kv_cache"] == kv:
                return r
        return None

    def find_step(variant, threads, batch, past):
        for s in steps:
            if (s["variant"], s["threads"], s["batch"], s["past"]) == (variant, threads, batch, past):
                return s
        return None

    T = motion_tokens(manifest.model)
    mid = T // 2
    values: dict[str, tuple[float | None, str]] = {}
    q, f = find_e2e("onnxruntime", "int8", 1), find_e2e("onnxruntime", "fp32", 1)
    tk, tr = find_e2e("torch", "fp32", 1, True), find_e2e("torch", "fp32", 1, False)
    values["rtf_int8_t1"] = (q and q["rtf"], q and f"{_med(q['wall']) * 1e3:.1f} ms for {q['motion_seconds']:g} s")
    values["ttff_int8_t1"] = (q and _med(q["stream_first_frame"]), "")
    s8, s32 = find_step("int8", 1, 1, mid), find_step("fp32", 1, 1, mid)
    values["int8_over_fp32_step"] = (
        s8 and s32 and _med(s8["seconds"]) / _med(s32["seconds"]),
        s8 and s32 and f"{_med(s8['seconds']) * 1e3:.3f} / {_med(s32['seconds']) * 1e3:.3f} ms")
    values["ort_over_torch"] = (f and tk and _med(f["wall"]) / _med(tk["wall"]),
                                f and tk and f"{_med(f['wall']) * 1e3:.1f} / {_med(tk['wall']) * 1e3:.1f} ms")
    values["kv_over_recompute"] = (tk and tr and _med(tk["wall"]) / _med(tr["wall"]),
                                   tk and tr and f"{_med(tk['wall']) * 1e3:.1f} / {_med(tr['wall']) * 1e3:.1f} ms")
    values["step_over_floor"] = (s8 and s8.get("over_floor"), s8 and "floor" in s8 and
                                 f"{_med(s8['seconds']) * 1e3:.3f} / {s8['floor']['floor'] * 1e3:.3f} ms "
                                 f"({s8['floor']['bound']}-bound)")
    values["step_over_cache_floor"] = (s8 and s8.get("over_cache_floor"), s8 and "cache_floor" in s8 and
                                       f"{_med(s8['seconds']) * 1e3:.3f} / {s8['cache_floor']['floor'] * 1e3:.3f} ms "
                                       f"({s8['cache_floor']['bound']}-bound)")
    values["stream_over_generate"] = (q and _med(q["stream_wall"]) / _med(q["wall"]),
                                      q and f"{_med(q['stream_wall']) * 1e3:.1f} / {_med(q['wall']) * 1e3:.1f} ms")
    crowds = [r for r in results if r["case"] == "crowd" and "error" not in r]
    crowd_soak = next((r for r in results if r["case"] == "crowd_soak" and "error" not in r), None)
    c8 = next((r for r in crowds if r["variant"] == INT8_FIXED), None)
    values["crowd_int8"] = (c8 and c8["max_realtime_characters"],
                            c8 and "largest N tried with p99 lateness ≤ 50 ms; rows in 'Crowds' below")
    values["crowd_soak"] = (crowd_soak and max(crowd_soak["tick_time_ratio"], crowd_soak["rss_ratio"]),
                            crowd_soak and f"tick time {crowd_soak['tick_time_ratio']:.3f}×, RSS "
                                           f"{crowd_soak['rss_ratio']:.3f}×")
    values["peak_rss"] = (q and q["peak_rss_bytes"], "")
    values["cold_start"] = (cold.get("int8") and _med(cold["int8"]["import_and_load"]),
                            cold.get("int8") and f"fresh process incl. interpreter: "
                                                 f"{_med(cold['int8']['process_wall']):.2f} s")
    goals = []
    for key, measure, goal, thr, direction in GOALS:
        value, detail = values.get(key, (None, ""))
        met = None if value is None else (value >= thr if direction == ">=" else value <= thr)
        goals.append({"key": key, "measure": measure, "goal": goal, "value": value, "met": met,
                      "detail": detail or ""})
    context = []

    def ratio(label, a, b, note=""):
        if a is not None and b is not None and b > 0:
            context.append({"ratio": label, "value": a / b, "note": note})

    w = lambda r, k="wall": r and _med(r.get(k))                               # noqa: E731
    ratio("ORT int8 (KV) ÷ torch recompute, end to end, 1 thread", w(q), w(tr), "across engines")
    ratio("ORT fp32 ÷ torch recompute, end to end, 1 thread", w(f), w(tr), "across engines")
    ratio("ORT int8 ÷ ORT fp32, end to end, 1 thread", w(q), w(f))
    for v in opts.variants:
        ratio(f"ORT {v}: 2 threads ÷ 1 thread, end to end", w(find_e2e("onnxruntime", v, 2)),
              w(find_e2e("onnxruntime", v, 1)))
        ratio(f"ORT {v}: streaming (all frames) ÷ generate, 1 thread", w(find_e2e("onnxruntime", v, 1), "stream_wall"),
              w(find_e2e("onnxruntime", v, 1)), "the decoder runs on a receptive-field window every step")
    for r in (q, f):
        if r and r.get("profile"):
            ratio(f"ORT {r['variant']}: sampling share of generate, 1 thread", r["profile"]["parts"]["sample"],
                  r["profile"]["wall"], "one instrumented run")
    for v in opts.variants:
        for th in opts.threads:
            a, b1 = find_step(v, th, max(opts.batches), T), find_step(v, th, 1, T)
            if a and b1 and max(opts.batches) > 1:
                ratio(f"step {v} {th} thread(s), past {T}: batch {max(opts.batches)} ÷ (batch 1 × "
                      f"{max(opts.batches)})", _med(a["seconds"]), _med(b1["seconds"]) * max(opts.batches),
                      "< 1: batching prompts pays")
    soak = next((r for r in results if r["case"] == "soak" and "error" not in r), None)
    return {"goals": goals, "context": context, "steps": steps, "e2e": e2e, "cold_start": cold, "floor": floors,
            "bundle_bytes": variant_bytes, "step_work": work, "motion_tokens": T, "soak": soak, "crowds": crowds,
            "crowd_soak": crowd_soak,
            "errors": [r for r in results if "error" in r]}


def _stats(xs):
    xs = sorted(xs)
    return {"n": len(xs), "median": statistics.median(xs), "min": xs[0], "max": xs[-1], "values": xs}


def _csv(kind):
    return lambda s: [kind(x) for x in s.split(",") if x]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, default=Path("bundles/base"))
    ap.add_argument("--checkpoints", type=Path, default=Path("checkpoints/base"),
                    help="for the torch cases (skipped, with a note, if absent)")
    ap.add_argument("--repeats", type=int, default=5,
                    help="rounds: every configuration runs once per round, in its own process")
    ap.add_argument("--per-process", type=int, default=1, help="timed repeats inside each process (default 1)")
    ap.add_argument("--cold-repeats", type=int, default=None, help="fresh processes per variant (default: repeats)")
    ap.add_argument("--iters", type=int, default=30, help="step calls per process and past (their median counts)")
    ap.add_argument("--budget", type=float, default=720,
                    help="seconds: start no new round (after 2) that would end past this; `make bench` must end "
                         "within 15 minutes")
    ap.add_argument("--threads", type=_csv(int), default=[1, 2])
    ap.add_argument("--batches", type=_csv(int), default=[1, 8])
    ap.add_argument("--variants", type=_csv(str), default=None, help="default: fp32 and int8")
    ap.add_argument("--no-torch", dest="torch", action="store_false")
    ap.add_argument("--quick", action="store_true", help="smoke test: 1 repeat, few calls")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--timeout", type=float, default=600, help="seconds per case")
    ap.add_argument("--soak", type=float, default=None,
                    help="seconds of the soak (one endless stream with prompt switches, after the rounds; default "
                         "600, --quick 4; 0 skips it)")
    ap.add_argument("--soak-interval", type=float, default=None,
                    help="seconds between the soak's measurements (default 60, --quick 1)")
    ap.add_argument("--crowd-soak", type=float, default=None,
                    help="seconds of the crowd soak (64 characters switching prompts; default 600, --quick 4; 0 "
                         "skips it)")
    opts = ap.parse_args(argv)
    opts.crowd_soak = (4.0 if opts.quick else 600.0) if opts.crowd_soak is None else opts.crowd_soak
    if opts.quick:
        opts.repeats, opts.iters = 1, 3
        opts.cold_repeats = opts.cold_repeats or 1
    opts.soak = (4.0 if opts.quick else 600.0) if opts.soak is None else opts.soak
    opts.soak_interval = opts.soak_interval or (1.0 if opts.quick else 60.0)
    opts.cold_repeats = opts.cold_repeats or opts.repeats
    opts.bundle = opts.bundle if opts.bundle.is_absolute() else (Path.cwd() / opts.bundle)
    opts.checkpoints = opts.checkpoints if opts.checkpoints.is_absolute() else (Path.cwd() / opts.checkpoints)
    if not (opts.bundle / "manifest.json").is_file():
        print(f"benchmarks: no bundle at {opts.bundle} (build one with `make demo`, or pass --bundle)",
              file=sys.stderr)
        return 2
    manifest = read_manifest(opts.bundle)
    # the step case drives the dynamic-cache step graph: fp32 and int8 (portable and ORT copies: mogo-export verify);
    # end to end also runs the fixed-capacity variants (their step writes the cache in place)
    e2e = opts.variants or [v for v in manifest.variants if v in ("fp32", "int8", PORTABLE, INT8_FIXED)]
    opts.variants = opts.variants or [v for v in manifest.variants if v in ("fp32", "int8")]
    opts.e2e_variants = e2e
    notes = []
    if opts.torch and not ((opts.checkpoints / "vq.pt").is_file() and (opts.checkpoints / "transformer.pt").is_file()):
        notes.append(f"torch cases skipped: no checkpoints at {opts.checkpoints}")
        opts.torch = False
    notes.append(f"downsample {manifest.model.downsample} only: pass another --bundle for another preset")

    n_jobs = sum(len(plan(opts, r)) for r in range(opts.repeats))
    print(f"benchmarks: {opts.repeats} rounds, {n_jobs} processes on {opts.bundle} ({'; '.join(notes)})", flush=True)
    t0 = time.perf_counter()
    results, done, rounds = [], 0, 0
    for rnd in range(opts.repeats):
        elapsed = time.perf_counter() - t0
        if rnd >= 2 and elapsed + elapsed / rnd > opts.budget:
            notes.append(f"stopped after {rnd} of {opts.repeats} rounds to stay within --budget {opts.budget:.0f} s")
            print(f"benchmarks: {notes[-1]}", flush=True)
            break
        for label, case, args, threads in plan(opts, rnd):
            r = run_case(case, args, threads, opts.timeout)
            r["round"] = rnd
            results.append(r)
            done += 1
            status = f"ERROR {r['error'][:200]}" if "error" in r else f"{r['process_wall']:.1f} s"
            print(f"[{done:3d}/{n_jobs}] round {rnd + 1}: {label:40s} {status}  "
                  f"(elapsed {time.perf_counter() - t0:.0f} s)", flush=True)
        rounds = rnd + 1
    fixed = [v for v in (INT8_FIXED, PORTABLE) if v in manifest.variants] if manifest.streaming else []
    for v in fixed:
        print(f"benchmarks: crowd, {v}", flush=True)
        results.append(run_case("crowd", ["--bundle", str(opts.bundle), "--variant", v] +
                                (["--sizes", "1,8", "--crowd-seconds", "1"] if opts.quick else []), 1, opts.timeout))
    if fixed and opts.crowd_soak > 0:
        print(f"benchmarks: crowd soak, 64 characters for {opts.crowd_soak:.0f} s", flush=True)
        results.append(run_case("crowd_soak", ["--bundle", str(opts.bundle), "--variant", fixed[0], "--duration",
                                               str(opts.crowd_soak), "--interval", str(opts.soak_interval)],
                                1, opts.crowd_soak + opts.timeout))
    if opts.soak > 0:
        print(f"benchmarks: soak, one endless stream for {opts.soak:.0f} s", flush=True)
        r = run_case("soak", ["--bundle", str(opts.bundle), "--variant", "int8" if "int8" in opts.variants else
                              opts.variants[0], "--duration", str(opts.soak), "--interval", str(opts.soak_interval)],
                     1, opts.soak + opts.timeout)
        results.append(r)
        print(f"benchmarks: soak {'ERROR ' + r['error'][:200] if 'error' in r else 'done'}  "
              f"(elapsed {time.perf_counter() - t0:.0f} s)", flush=True)
    total = time.perf_counter() - t0

    versions = {}
    for mod in ("onnxruntime", "numpy"):
        try:
            versions[mod] = __import__(mod).__version__
        except Exception:                                                       # noqa: BLE001
            versions[mod] = None
    cpu = platform.processor()
    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name"))
    except Exception:                                                           # noqa: BLE001
        pass
    stamp = datetime.now(timezone.utc)
    meta = {"time": stamp.strftime("%Y-%m-%d %H:%M:%S UTC"), "bundle": str(opts.bundle),
            "checkpoints": str(opts.checkpoints) if opts.torch else None,
            "machine": f"{cpu}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}",
            "versions": versions, "python": platform.python_version(), "repeats": rounds,
            "per_process": opts.per_process,
            "cold_repeats": opts.cold_repeats, "iters": opts.iters, "threads": opts.threads, "batches": opts.batches,
            "variants": opts.variants, "quick": opts.quick, "notes": notes, "total_seconds": total,
            "soak_seconds": opts.soak, "soak_interval": opts.soak_interval, "crowd_soak_seconds": opts.crowd_soak,
            "command": "python -m benchmarks.run " + " ".join(sys.argv[1:] if argv is None else argv),
            "model": manifest.model.to_dict(), "sampling_defaults": manifest.sampling_defaults.to_dict()}
    report = {"meta": meta, "summary": summarize(results, manifest, opts.bundle, opts), "results": results}
    md = markdown(report)
    opts.out.mkdir(parents=True, exist_ok=True)
    json_path = opts.out / f"{stamp.strftime('%Y%m%d-%H%M%S')}.json"
    json_path.write_text(json.dumps(report, indent=1, default=str))
    (opts.out / "latest.md").write_text(md)
    print()
    print(md)
    print(f"wrote {json_path} and {opts.out / 'latest.md'} ({total:.0f} s)")
    return 1 if report["summary"]["errors"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
