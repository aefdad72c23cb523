#!/usr/bin/env bash
# The rigs' files in real tools, from a clean clone (`make test-tools` runs this):
#   1. npm packages (three.js, Khronos's gltf-validator) into tests/tools/node_modules if missing;
#   2. real Blender as a Python module (bpy, a ~370 MB wheel; pins its own numpy) into .venv-blender if missing;
#   3. Godot 3's headless editor (Debian's godot3-server, 3.2.3 on bookworm) with apt-get if missing;
#   4. pytest tests/tools, which writes the files, reads them in each tool, and compares with the source motions.
# Environment: PYTHON (the repository's venv Python), BLENDER_PYTHON (a Python with bpy: skips step 2), GODOT (a
# Godot 3 editor binary that runs headless, e.g. a server build: skips step 3).
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
PY="${PYTHON:-$ROOT/.venv/bin/python}"
BPY_VERSION=5.0.1

if [ ! -f "$HERE/node_modules/.package-lock.json" ]; then
  (cd "$HERE" && npm ci --ignore-scripts --no-audit --no-fund)
fi

if [ -z "${BLENDER_PYTHON:-}" ]; then
  BLENDER_PYTHON="$ROOT/.venv-blender/bin/python"
  if [ ! -f "$ROOT/.venv-blender/.bpy-$BPY_VERSION" ]; then
    python3 -m venv "$ROOT/.venv-blender"
    start=$(date +%s)
    "$BLENDER_PYTHON" -m pip install -q "bpy==$BPY_VERSION"
    echo "tools: installed Blender (bpy $BPY_VERSION) in $(( $(date +%s) - start )) s," \
         "$(du -sm "$ROOT/.venv-blender" | cut -f1) MB"
    touch "$ROOT/.venv-blender/.bpy-$BPY_VERSION"
  fi
fi

GODOT="${GODOT:-$(command -v godot3-server || true)}"
if [ -z "$GODOT" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "tools: Godot is missing; installing Debian's headless editor (apt-get install -y godot3-server)"
    start=$(date +%s)
    if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
           godot3-server >/dev/null; }; then
      echo "tools: error: apt-get could not install godot3-server (Debian's Godot 3 headless editor)" >&2
    fi
    GODOT="$(command -v godot3-server || true)"
    if [ -n "$GODOT" ]; then
      echo "tools: installed Godot $("$GODOT" --version 2>/dev/null | tail -1) in $(( $(date +%s) - start )) s"
    fi
  fi
  if [ -z "$GODOT" ]; then
    echo "tools: error: the Godot import test needs Godot 3's headless editor; install it with" >&2
    echo "    sudo apt-get update && sudo apt-get install -y godot3-server" >&2
    echo "or point GODOT=/path/to/godot at another Godot 3 editor build that runs headless" >&2
    exit 2
  fi
fi
case "$("$GODOT" --version 2>/dev/null | tail -1)" in
  3.*) ;;
  *) echo "tools: error: $GODOT is not Godot 3 ('$("$GODOT" --version 2>&1 | tail -1)'): the import settings" \
          "the test writes are Godot 3's" >&2; exit 2 ;;
esac

cd "$ROOT"
MOGO_BLENDER_PYTHON="$BLENDER_PYTHON" MOGO_GODOT="$GODOT" "$PY" -m pytest -q tests/tools "$@"
