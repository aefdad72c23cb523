#!/usr/bin/env bash
# The rigs' files in real tools, from a clean clone (`make test-tools` runs this):
#   1. npm packages (three.js, Khronos's gltf-validator) into tests/tools/node_modules if missing;
#   2. real Blender as a Python module (bpy, a ~370 MB wheel; pins its own numpy) into .venv-blender if missing;
#   3. pytest tests/tools, which writes the files, reads them in both, and compares with the source motions.
# Environment: PYTHON (the repository's venv Python), BLENDER_PYTHON (a Python with bpy: skips step 2).
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

cd "$ROOT"
MOGO_BLENDER_PYTHON="$BLENDER_PYTHON" "$PY" -m pytest -q tests/tools "$@"
