#!/usr/bin/env bash
# What benchmarks/cpu_kinds.py needs to run the runtime on other CPUs, installed where missing:
#   1. qemu-user (Debian's qemu-x86_64 and qemu-aarch64), with apt-get where we are root, else it says what to install;
#   2. an ARM64 root in ROOT (default ~/.cache/mogo/arm64): Debian bookworm's python3.11 for arm64 (debootstrap's
#      first stage, its packages unpacked; no chroot, so no binfmt), PyPI's aarch64 wheels of numpy and onnxruntime
#      in ROOT/site, and an ARM /proc/cpuinfo under the prefix (onnxruntime reads it at import and crashes on an
#      x86 one). qemu-aarch64 -L ROOT makes ROOT the program's /.
# Prints ROOT on its last line. About a minute the first time (downloads ~60 MB); nothing once built.
set -euo pipefail
ROOT="${1:-${MOGO_ARM64_ROOT:-$HOME/.cache/mogo/arm64}}"
PY="${PYTHON:-$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/.venv/bin/python}"

need=()
command -v qemu-x86_64 >/dev/null && command -v qemu-aarch64 >/dev/null || need+=(qemu-user)
[ -f "$ROOT/.complete" ] || command -v debootstrap >/dev/null || need+=(debootstrap)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "qemu_setup: installing ${need[*]} (apt-get)" >&2
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  else
    echo "qemu_setup: error: needs ${need[*]}: sudo apt-get install -y ${need[*]}" >&2
    exit 2
  fi
fi

if [ ! -f "$ROOT/.complete" ]; then
  rm -rf "$ROOT.partial"
  mkdir -p "$(dirname "$ROOT")"
  echo "qemu_setup: building the ARM64 root in $ROOT (debootstrap, aarch64 wheels)" >&2
  debootstrap --arch=arm64 --foreign --variant=minbase --include=python3.11 bookworm "$ROOT.partial" \
    http://deb.debian.org/debian >/dev/null
  for deb in "$ROOT.partial"/var/cache/apt/archives/*.deb; do dpkg-deb -x "$deb" "$ROOT.partial"; done
  wheels="$(mktemp -d)"
  "$PY" -m pip download -q --platform manylinux_2_28_aarch64 --platform manylinux2014_aarch64 --python-version 3.11 \
    --only-binary=:all: -d "$wheels" "numpy==$("$PY" -c 'import numpy; print(numpy.__version__)')" \
    "onnxruntime==$("$PY" -c 'import onnxruntime; print(onnxruntime.__version__)')"
  mkdir -p "$ROOT.partial/site" "$ROOT.partial/proc"
  for w in "$wheels"/*.whl; do "$PY" -m zipfile -e "$w" "$ROOT.partial/site"; done
  rm -rf "$wheels"
  # a Cortex-A76 (what qemu-aarch64 -cpu cortex-a76 emulates), as its kernel lists it
  printf 'processor\t: 0\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid asimdrdm lrcpc dcpop asimddp\nCPU implementer\t: 0x41\nCPU architecture: 8\nCPU variant\t: 0x4\nCPU part\t: 0xd0b\nCPU revision\t: 1\n\n' \
    > "$ROOT.partial/proc/cpuinfo"
  touch "$ROOT.partial/.complete"
  rm -rf "$ROOT"
  mv "$ROOT.partial" "$ROOT"
fi
echo "$ROOT"
