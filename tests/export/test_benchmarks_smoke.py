"""`make bench` in miniature: the orchestrator runs every kind of case on the tiny bundle and writes its JSON and
Markdown with the expected fields. No timing assertions (a shared machine); only that the numbers exist."""
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_benchmark_runs_and_reports(tiny_bundle, tiny_checkpoints, tmp_path):
    out = tmp_path / "results"
    # fp32 and int8: the variants whose step the benchmark's step case drives (the dynamic cache); the portable
    # variants' fixed-capacity step is not one of its cases yet
    cmd = [sys.executable, "-m", "benchmarks.run", "--bundle", str(tiny_bundle), "--checkpoints",
           str(tiny_checkpoints), "--quick", "--threads", "1", "--batches", "1", "--variants", "fp32,int8",
           "--out", str(out)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    (json_path,) = out.glob("*.json")
    report = json.loads(json_path.read_text())
    summary = report["summary"]
    assert summary["errors"] == []
    assert summary["motion_tokens"] == 196 // report["meta"]["model"]["downsample"]

    goals = {g["key"]: g for g in summary["goals"]}
    assert set(goals) == {"rtf_int8_t1", "ttff_int8_t1", "int8_over_fp32_step", "ort_over_torch",
                          "kv_over_recompute", "step_over_floor", "step_over_cache_floor", "peak_rss", "cold_start",
                          "stream_over_generate", "crowd_int8", "crowd_soak"}
    for g in goals.values():
        assert isinstance(g["value"], (int, float)) and g["value"] > 0, g
        assert isinstance(g["met"], bool), g

    steps = summary["steps"]
    assert {(s["variant"], s["past"]) for s in steps} >= {("fp32", 1), ("int8", 1)}
    for s in steps:
        assert s["seconds"]["median"] > 0 and s["over_floor"] > 0 and s["floor"]["flops"] > 0

    e2e = {(r["engine"], r["variant"], r["kv_cache"]): r for r in summary["e2e"]}
    assert set(e2e) == {("onnxruntime", "fp32", True), ("onnxruntime", "int8", True), ("torch", "fp32", True),
                        ("torch", "fp32", False)}
    for r in e2e.values():
        assert r["frames"] == 196 and r["rtf"] > 0 and r["peak_rss_bytes"] > 0
        assert {"text", "step", "sample", "decode", "joints", "loop_other"} <= set(r["profile"]["parts"])
    assert e2e[("onnxruntime", "int8", True)]["stream_first_frame"]["median"] > 0

    assert set(summary["cold_start"]) == {"fp32", "int8"}
    crowds = {c["variant"]: c for c in summary["crowds"]}
    assert set(crowds) == {"int8_fixed", "portable"}
    for c in crowds.values():
        assert [r["n"] for r in c["rows"]] == [1, 8] and all(r["character_token_ms"] > 0 for r in c["rows"])
    assert summary["crowd_soak"]["tokens"] > 0 and summary["crowd_soak"]["rows"]
    assert summary["cold_start"]["int8"]["import_and_load"]["median"] > 0
    assert set(summary["bundle_bytes"]) == set(json.loads((tiny_bundle / "manifest.json").read_text())["variants"])
    assert summary["floor"]["1"]["copy_dram_gbs"]["median"] > 0       # JSON keys are strings

    md = (out / "latest.md").read_text()
    for heading in ("## Goals (issues 6 and 18)", "## Step graph latency", "## End to end", "## Cold start",
                    "## Bundle size per variant", "## Machine", "## Crowds: int8_fixed", "## Crowds: portable",
                    "## Crowd soak: 64 characters"):
        assert heading in md
    for g in goals.values():
        assert g["measure"] in md
    assert md in done.stdout                                            # the table is printed too


def test_the_compact_benchmark_measures_every_variant(tiny_bundle, tmp_path):
    """benchmarks.compact on the tiny bundle, Python only (Node and Chromium run in `make test-js` / `test-web`)."""
    cmd = [sys.executable, "-m", "benchmarks.compact", "--bundle", str(tiny_bundle), "--seeds", "1", "--rounds", "1",
           "--no-js", "--out", str(tmp_path)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    (path,) = tmp_path.glob("compact-*.json")
    result = json.loads(path.read_text())
    sizes = result["sizes_mb"]
    assert sizes["compact"] < 0.5 * sizes["portable"] and set(result["speed"]) == {"fp32", "portable", "compact", "int8"}
    assert 0.9 <= result["agreement"]["compact"]["teacher_forced"] <= 1.0
    assert result["cases"]["count"] == 2 * 20 + 1 and result["cases"]["steps"] > 0
