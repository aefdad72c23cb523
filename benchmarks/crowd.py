"""Crowd benchmark cases (`python -m benchmarks.cases crowd|crowd_soak ...`): many characters on one core.

  crowd       for each crowd size N (--sizes), N characters join over `refresh` ticks and play in real time at the
              bundle's fps: a character's frame i is due `i / fps` after its first frame was ready. Ticks run back to back
              (a game's worker thread). Reported per N: the tick time, the cost per character-token, and the
              99th-percentile lateness of every frame of every character; the largest N whose lateness stays
              <= LATE_LIMIT is the number of concurrent real-time characters one core carries.
  crowd_soak  N characters for --duration seconds of wall time, switching prompts every 4-10 s of their motion
              (each on its own schedule): per-tick time and RSS at every --interval, last / first.
"""
from __future__ import annotations

import time

import numpy as np

from .common import SOAK_LIMIT, current_rss_bytes, peak_rss_bytes

LATE_LIMIT = 0.050          # s: the 99th percentile of frame lateness a real-time character may have
SWITCH_S = (4.0, 10.0)      # stream seconds between a crowd_soak character's prompts
PROMPTS = ("a person walks forward", "a person turns left", "a person waves with the right hand",
           "a person jumps in place", "a person squats down slowly", "a person runs forward",
           "a person kicks with the left leg", "a person sits down")


def _crowd(args):
    from mogo_runtime import MotionGenerator
    from mogo_runtime.crowd import Crowd

    gen = MotionGenerator(args.bundle, variant=args.variant, threads=args.threads)
    return gen, (lambda: Crowd(gen, chunk=args.chunk))


def realtime_run(gen, crowd, n: int, seconds: float, spread: int) -> dict:
    """N characters, `seconds` of motion each, joining over the first `spread` ticks (character i at tick
    i % spread, as a game spawns them; a crowd that all joins in one tick also rebuilds its contexts in one tick,
    every `refresh` tokens); ticks back to back; the lateness of every frame."""
    fps = gen.dims.fps
    first: dict = {}
    late, ticks, sizes = [], [], []       # sizes: characters stepped in each tick
    tick = 0
    while crowd or tick < spread:
        for i in range(tick, n, spread) if tick < spread else ():
            crowd.add(PROMPTS[i % len(PROMPTS)], seed=i, seconds=seconds)
        tick += 1
        sizes.append(len(crowd))
        t = time.perf_counter()
        out = crowd.tick()
        now = time.perf_counter()
        ticks.append(now - t)
        for c, frames in out.items():
            first.setdefault(c, now)
            due = first[c] + np.arange(frames.index, frames.index + len(frames.joints)) / fps
            late.append(now - due)
    late = np.concatenate(late)
    ticks = np.array(ticks)
    per_tick_motion = gen.dims.downsample / fps
    return {"n": n, "tick_ms_median": 1e3 * float(np.median(ticks)), "tick_ms_p99": 1e3 * float(np.percentile(ticks, 99)),
            "character_token_ms": 1e3 * float(ticks.sum()) / sum(sizes),
            "realtime_capacity": per_tick_motion * sum(sizes) / float(ticks.sum()),
            "late_p99_ms": 1e3 * float(np.percentile(late, 99)), "late_max_ms": 1e3 * float(late.max()),
            "frames": int(late.size), "ok": bool(np.percentile(late, 99) <= LATE_LIMIT)}


def case_crowd(args) -> dict:
    gen, make = _crowd(args)
    spread = gen.bundle.manifest.streaming.refresh
    realtime_run(gen, make(), 4, 2.0, 1)                                         # warm-up
    rows, best = [], 0
    for n in args.sizes:
        row = realtime_run(gen, make(), n, args.crowd_seconds, spread)
        rows.append(row)
        best = n if row["ok"] else best
        if not row["ok"] and n > 2 * max(best, 1):                               # far past the limit: stop
            break
    return {"variant": args.variant, "threads": args.threads, "chunk": args.chunk, "seconds": args.crowd_seconds,
            "joined_over_ticks": spread,
            "late_limit_ms": 1e3 * LATE_LIMIT, "rows": rows, "max_realtime_characters": best,
            "guidance": gen.sampling_defaults.guidance}


def case_crowd_soak(args) -> dict:

    gen, make = _crowd(args)
    crowd = make()
    rng = np.random.default_rng(args.seed)
    per_token = gen.dims.downsample / gen.dims.fps
    lo, hi = (round(s / per_token) for s in SWITCH_S)
    spread = gen.bundle.manifest.streaming.refresh         # joining over `refresh` ticks, as realtime_run
    members = []
    for tick in range(spread):
        members += [crowd.add(PROMPTS[i % len(PROMPTS)], seed=i) for i in range(tick, args.characters, spread)]
        crowd.tick()
    switch_at = {c: int(rng.integers(lo, hi + 1)) for c in members}
    rows, t0 = [], time.perf_counter()
    mark, end = t0 + args.interval, t0 + args.duration
    tick_times: list[float] = []
    while True:
        t = time.perf_counter()
        crowd.tick()
        tick_times.append(time.perf_counter() - t)
        for c in members:
            if c.count >= switch_at[c]:
                c.set_prompt(PROMPTS[int(rng.integers(len(PROMPTS)))])
                switch_at[c] = c.count + int(rng.integers(lo, hi + 1))
        now = time.perf_counter()
        if now >= mark:
            rows.append({"interval": len(rows) + 1, "elapsed_s": now - t0, "ticks": len(tick_times),
                         "tick_ms": 1e3 * float(np.mean(tick_times)),
                         "rss_bytes": current_rss_bytes() or peak_rss_bytes(),
                         "peak_rss_bytes": current_rss_bytes("VmHWM") or peak_rss_bytes()})
            tick_times = []
            mark += args.interval
            if mark > end + 1e-6:
                break
    first, last = rows[0], rows[-1]
    out = {"variant": args.variant, "threads": args.threads, "characters": args.characters, "rows": rows,
           "duration_s": args.duration, "interval_s": args.interval, "limit": SOAK_LIMIT,
           "switches": sum(len(c.switches) for c in members), "tokens": sum(c.count for c in members),
           "tick_time_ratio": last["tick_ms"] / first["tick_ms"], "rss_ratio": last["rss_bytes"] / first["rss_bytes"]}
    out["met"] = out["tick_time_ratio"] <= SOAK_LIMIT and out["rss_ratio"] <= SOAK_LIMIT
    return out


def crowd_section(crowds: list[dict], soak: dict | None) -> list[str]:
    """The report's Markdown for the crowd cases."""
    out = []
    for c in crowds:
        out += ["", f"## Crowds: {c['variant']}, {c['threads']} thread, guidance {c['guidance']:g}, decode every "
                    f"{c['chunk']} token(s)", "",
                f"Each character plays {c['seconds']:g} s in real time from its first frame; N characters join over "
                f"{c['joined_over_ticks']} ticks; ticks run back to back. Largest N with p99 lateness ≤ "
                f"{c['late_limit_ms']:.0f} ms: **{c['max_realtime_characters']}**.", "",
                "| N | tick ms (median / p99) | ms per character-token | characters one core keeps in real time "
                "(throughput) | p99 / max lateness ms | |", "|---|---|---|---|---|---|"]
        out += [f"| {r['n']} | {r['tick_ms_median']:.1f} / {r['tick_ms_p99']:.1f} | {r['character_token_ms']:.3f} | "
                f"{r['realtime_capacity']:.0f} | {r['late_p99_ms']:.0f} / {r['late_max_ms']:.0f} | "
                f"{'ok' if r['ok'] else 'late'} |" for r in c["rows"]]
    if soak:
        out += ["", f"## Crowd soak: {soak['characters']} characters, {soak['variant']}, prompt switches every 4-10 s",
                "", f"{soak['duration_s']:.0f} s of wall time: {soak['tokens']:,} tokens, {soak['switches']:,} "
                    "switches.", "", "| interval | ticks | ms per tick | RSS MB |", "|---|---|---|---|"]
        out += [f"| {r['interval']} | {r['ticks']} | {r['tick_ms']:.1f} | {r['rss_bytes'] / 1e6:.0f} |"
                for r in soak["rows"]]
        out += ["", f"Last ÷ first: tick time {soak['tick_time_ratio']:.3f}×, RSS {soak['rss_ratio']:.3f}× (both ≤ "
                    f"{soak['limit']:g}×: {'met' if soak['met'] else '**missed**'})."]
    return out
