"""The benchmark report's Markdown (`benchmarks.run` writes it to results/latest.md and prints it)."""
from __future__ import annotations

from .common import MOTION_FRAMES
from .crowd import crowd_section


def _med(s: dict | None) -> float | None:
    return None if not s or not s.get("n") else s["median"]


def _fmt_goal_value(key, v):
    if v is None:
        return "n/a"
    if key == "rtf_int8_t1":
        return f"{v:.1f}×"
    if key == "ttff_int8_t1":
        return f"{v * 1e3:.1f} ms"
    if key == "peak_rss":
        return f"{v / 1e6:.0f} MB"
    if key == "cold_start":
        return f"{v:.2f} s"
    return f"{v:.2f}"


def _ms(s: dict | None, digits=2) -> str:
    if not s or not s.get("n"):
        return "n/a"
    return f"{s['median'] * 1e3:.{digits}f} [{s['min'] * 1e3:.{digits}f}–{s['max'] * 1e3:.{digits}f}]"


def markdown(report: dict) -> str:
    meta, summ = report["meta"], report["summary"]
    out = [f"# mogo benchmark: {meta['bundle']}", "",
           f"{meta['time']} · {meta['machine']} · onnxruntime {meta['versions'].get('onnxruntime')} · "
           f"numpy {meta['versions'].get('numpy')} · {meta['repeats']} rounds · total {meta['total_seconds']:.0f} s",
           "", f"Command: `{meta['command']}`", "",
           f"Motion: {MOTION_FRAMES} frames = {summ['motion_tokens']} tokens (downsample "
           f"{meta['model']['downsample']}, {meta['model']['fps']:g} fps). Each configuration ran once per round "
           "in its own process, rounds one after another; times are median [min–max] over those processes (a "
           "step sample is the median of its process's calls). Ratios are computed within this run; absolute "
           "times on a shared machine are context only.", "",
           "## Goals (issues 6 and 18)", "", "| measure | goal | measured | | detail |", "|---|---|---|---|---|"]
    for g in summ["goals"]:
        met = "n/a" if g["met"] is None else ("met" if g["met"] else "**missed**")
        out.append(f"| {g['measure']} | {g['goal']} | {_fmt_goal_value(g['key'], g['value'])} | {met} | "
                   f"{g['detail']} |")
    if summ.get("context"):
        out += ["", "## Other ratios in this run (context)", "", "| ratio | value | note |", "|---|---|---|"]
        out += [f"| {c['ratio']} | {c['value']:.2f} | {c['note']} |" for c in summ["context"]]
    out += ["", "## Step graph latency (ms per call)", "",
            "Rows = prompts × (2 with guidance); int8 with several rows runs row by row in the runtime (the "
            "batched graph is timed here). Floor = max(bytes read / bandwidth, FLOPs / sgemm throughput), bytes = "
            "step file + KV cache at that past; DRAM = 128 MiB copy, cache = 4 MiB copy.", "",
            "| variant | threads | prompts (rows) | past | step ms | DRAM floor ms | step ÷ floor | cache floor ms | "
            "step ÷ cache floor |", "|---|---|---|---|---|---|---|---|---|"]
    for s in summ["steps"]:
        fl, cf = s.get("floor"), s.get("cache_floor")
        out.append(f"| {s['variant']} | {s['threads']} | {s['batch']} ({s['rows']}) | {s['past']} | "
                   f"{_ms(s['seconds'], 3)} | {fl['floor'] * 1e3:.3f} ({fl['bound'][:3]}) | {s['over_floor']:.2f} | "
                   f"{cf['floor'] * 1e3:.3f} ({cf['bound'][:3]}) | {s['over_cache_floor']:.2f} |"
                   if fl else f"| {s['variant']} | {s['threads']} | {s['batch']} ({s['rows']}) | {s['past']} | "
                              f"{_ms(s['seconds'], 3)} | n/a | n/a | n/a | n/a |")
    out += ["", f"## End to end: {MOTION_FRAMES} frames from text to joints", "",
            "| engine | variant | threads | cache | wall ms | ms per token | real-time factor | first frame ms (stream) "
            "| stream wall ms | peak RSS MB |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in summ["e2e"]:
        out.append(f"| {r['engine']} | {r['variant']} | {r['threads']} | {'KV' if r['kv_cache'] else 'recompute'} | "
                   f"{_ms(r['wall'], 1)} | {r['wall']['median'] * 1e3 / r['tokens']:.3f} | {r['rtf']:.1f}× | "
                   f"{_ms(r.get('stream_first_frame'), 1)} | {_ms(r.get('stream_wall'), 1)} | "
                   f"{r['peak_rss_bytes'] / 1e6:.0f} |")
    out += ["", "## Where one generation's time goes (one instrumented run, ms)", "",
            "| engine | variant | threads | cache | wall | text | step | sample | decode | joints | loop/other |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in summ["e2e"]:
        p = r["profile"]["parts"]
        out.append(f"| {r['engine']} | {r['variant']} | {r['threads']} | {'KV' if r['kv_cache'] else 'recompute'} | "
                   f"{r['profile']['wall'] * 1e3:.1f} | " +
                   " | ".join(f"{p.get(k, 0) * 1e3:.1f}" for k in ("text", "step", "sample", "decode", "joints",
                                                                  "loop_other")) + " |")
    out += ["", "## Cold start (fresh process, s)", "",
            "| variant | import mogo_runtime | import onnxruntime | Bundle.load | sessions | import + load | "
            "first frame after load | process wall | peak RSS MB |", "|---|---|---|---|---|---|---|---|---|"]
    for v, c in summ["cold_start"].items():
        out.append(f"| {v} | " + " | ".join(f"{_med(c[k]):.3f}" for k in (
            "import_mogo_runtime", "import_onnxruntime", "bundle_load", "sessions", "import_and_load",
            "first_frame_after_load", "process_wall")) + f" | {c['peak_rss_bytes'] / 1e6:.0f} |")
    out += ["", "## Bundle size per variant (MB, manifest)", "",
            "| variant | total | " + " | ".join(next(iter(summ["bundle_bytes"].values())).keys() - {"total"}) + " |"]
    keys = [k for k in next(iter(summ["bundle_bytes"].values())) if k != "total"]
    out[-1] = "| variant | total | " + " | ".join(keys) + " |"
    out.append("|---" * (len(keys) + 2) + "|")
    for v, b in summ["bundle_bytes"].items():
        out.append(f"| {v} | {b['total'] / 1e6:.1f} | " + " | ".join(f"{b[k] / 1e6:.2f}" for k in keys) + " |")
    out += ["", "## Machine (this run)", "", "| threads | DRAM copy GB/s | cache copy GB/s | sgemm 1024³ GFLOP/s | "
            "sgemm 4×256×1024 GFLOP/s |", "|---|---|---|---|---|"]
    for th, fl in sorted(summ["floor"].items()):
        out.append(f"| {th} | {_med(fl['copy_dram_gbs']):.1f} | {_med(fl['copy_cache_gbs']):.1f} | "
                   f"{_med(fl['sgemm_1024_gflops']):.1f} | {_med(fl['sgemm_rows4_256x1024_gflops']):.1f} |")
    w = summ["step_work"]
    out += ["", f"Step matmul weights: {w['per_stream']:,} per stream row, {w['per_prompt']:,} per prompt, "
                f"{w['per_head_row']:,} per stream × head (relative positions), from {w['source']}."]
    out += soak_table(summ.get("soak"))
    out += crowd_section(summ.get("crowds", []), summ.get("crowd_soak"))
    if summ["errors"]:
        out += ["", "## Failed cases", ""] + [f"- {e.get('case')}: {e['error'][:300]}" for e in summ["errors"]]
    return "\n".join(out) + "\n"


def soak_table(soak: dict | None) -> list[str]:
    """The soak's Markdown section: one row per interval, then the check (last interval vs first)."""
    if soak is None:
        return []
    out = ["", f"## Soak: one endless stream, prompt switches ({soak['variant']}, {soak['threads']} thread)", ""]
    if "skipped" in soak:
        return out + [f"Skipped: {soak['skipped']}."]
    minutes = soak["interval_s"] == 60
    every = "minute" if minutes else f"{soak['interval_s']:g} s"
    out += [f"{soak['duration_s']:.0f} s of wall time, frames consumed as fast as they come, a new prompt every "
            f"4-10 s of stream time: {soak['switches']:,} switches, {soak['tokens']:,} tokens, "
            f"{soak['stream_seconds'] / 3600:.1f} h of motion. Measured at the end of each "
            f"{every}; ms per token = the interval's wall "
            "time / its tokens (the first interval includes warm-up).", "",
            f"| {'minute' if minutes else 'interval'} | tokens | ms per token | RSS MB | peak RSS MB | switches |",
            "|---|---|---|---|---|---|"]
    for r in soak["rows"]:
        out.append(f"| {r['interval']} | {r['tokens']:,} | {r['token_ms']:.3f} | {r['rss_bytes'] / 1e6:.1f} | "
                   f"{r['peak_rss_bytes'] / 1e6:.1f} | {r['switches']} |")
    verdict = "met" if soak["met"] else "**missed**"
    out += ["", f"Last ÷ first: ms per token {soak['token_time_ratio']:.3f}×, RSS {soak['rss_ratio']:.3f}× "
                f"(both ≤ {soak['limit']:g}×: {verdict})."]
    return out


# ----------------------------------------------------------------------------------------------------------------
