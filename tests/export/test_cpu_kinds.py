"""The bundle's variants on other CPUs (benchmarks/cpu_kinds.py, on the tiny trained bundle): QEMU emulates an
x86 without VNNI (Haswell: AVX2), an SSE4.2-only x86 (Nehalem) and an ARM64 Cortex-A76, running the same runtime.

int8 weights are 7-bit (export/bundle.py, INT8_REDUCE_RANGE), so onnxruntime's u8 x s8 kernel cannot saturate its
int16 pair sums on Haswell: there the int8 text embedding is the native one bit for bit (with 8-bit weights it was
0.033 off on this tiny bundle, and the step's logits 0.16).
Elsewhere an activation that differs in its last bit may round to another quantum (base: logits up to 0.14 off);
every variant keeps teacher-forced agreement with fp32 on every kind.
benchmarks/qemu_setup.sh installs qemu-user and builds the ARM64 root where missing (apt-get, debootstrap, PyPI's
aarch64 wheels: about a minute the first time).
"""
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BAR = 0.95


def test_every_variant_keeps_its_numbers_on_every_cpu_kind(tiny_bundle, tmp_path):
    out = tmp_path / "kinds.json"
    done = subprocess.run([sys.executable, "-m", "benchmarks.cpu_kinds", "--bundle", str(tiny_bundle), "--prompts", "3",
                           "--json", str(out), "--bar", str(BAR)], cwd=ROOT, capture_output=True, text=True, timeout=900)
    print(done.stdout)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    rows = {(r["kind"], r["variant"]): r for r in json.loads(out.read_text())["rows"]}
    assert {k for k, _ in rows} == {"native", "haswell", "nehalem", "arm64"}
    assert rows["arm64", "fp32"]["machine"] == "aarch64" and rows["haswell", "fp32"]["machine"] == "x86_64"
    for (kind, variant), r in rows.items():
        assert r["agreement"] >= BAR, (kind, variant, r)
        if variant in ("fp32", "compact"):            # float32 arithmetic: the last bits move, no more
            assert r["logits_vs_native"] < 1e-4 and r["embedding_vs_native"] < 1e-5, (kind, variant, r)
    for variant in ("int8", "int8_fixed"):             # no saturation on Haswell: the int8 text encoder's numbers
        assert rows["haswell", variant]["embedding_vs_native"] == 0.0, rows["haswell", variant]
