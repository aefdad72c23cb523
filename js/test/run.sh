#!/usr/bin/env bash
# The JavaScript runtime's tests, from a clean clone (`make test-js` runs this):
#   1. install onnxruntime-node into js/node_modules if it is missing (--ignore-scripts: its postinstall
#      downloads binaries the registry package already ships, and fails offline);
#   2. build the toy bundles of tests/runtime/toy_bundle.py (with and without a streaming section, with the
#      portable, int8_fixed and ORT-format variants, and with control) in a temporary folder, with the repository's
#      venv, and broken copies of them (test/make_broken.py);
#   3. write what the Python runtime gives on them (js/test/make_reference.py), the token streams it writes and
#      decodes (js/test/make_wire_reference.py), and what a motion server's clients must get
#      (js/test/make_serve_reference.py);
#   4. run `node --test`, which compares and prints the parity numbers (lines starting "parity:"); test/serve.test.mjs
#      starts `mogo serve` on the portable toy itself (and stops it, however the test ends).
#
# Environment:
#   PYTHON=...               the Python with mogo_runtime, onnxruntime, tokenizers (default .venv/bin/python)
#   MOGO_JS_TINY=1           also train and export a `tiny` bundle (the real exporter's graphs; ~2 min on 2 cores)
#   MOGO_JS_BUNDLES="a=DIR"  also compare on existing bundles, e.g. "base=bundles/base" (space-separated)
#   MOGO_JS_KEEP=DIR         write bundles and references to DIR and keep them (default: a temporary folder)
set -euo pipefail

JS="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ROOT="$(dirname "$JS")"
PY="${PYTHON:-$ROOT/.venv/bin/python}"

if [ ! -d "$JS/node_modules/onnxruntime-node" ]; then
  (cd "$JS" && npm install --ignore-scripts --no-audit --no-fund)
fi

if [ -n "${MOGO_JS_KEEP:-}" ]; then
  WORK="$MOGO_JS_KEEP"
  mkdir -p "$WORK"
else
  WORK="$(mktemp -d)"
  trap 'rm -rf "$WORK"' EXIT
fi

"$PY" "$ROOT/tests/runtime/toy_bundle.py" "$WORK/toy"
"$PY" "$ROOT/tests/runtime/toy_bundle.py" "$WORK/toy-clips" --seed 1 --clips
"$PY" "$ROOT/tests/runtime/toy_bundle.py" "$WORK/toy-control" --control   # tests/golden/toy_control.json's
# as the pytest fixture portable_toy_bundle, its decoder centred on the mean pose the toy's manifest records
(cd "$ROOT/tests/runtime" && "$PY" -c "import json, sys; import numpy as np; from pathlib import Path; from toy_bundle import build_toy_bundle
mean = np.array(json.loads(Path(sys.argv[1], 'manifest.json').read_text())['normalization']['mean'], np.float32)
build_toy_bundle(Path(sys.argv[2]), mean, portable=True, ort=True)" "$WORK/toy" "$WORK/toy-portable")
# broken bundles, one graph damaged in each, hashes forged (js/test/make_broken.py)
"$PY" "$JS/test/make_broken.py" "$WORK/toy" "$WORK/toy-portable" "$WORK/broken"

BUNDLES=(--bundle "toy=$WORK/toy" --bundle "toy-clips=$WORK/toy-clips" --bundle "toy-portable=$WORK/toy-portable"
  --bundle "toy-control=$WORK/toy-control")
if [ "${MOGO_JS_TINY:-0}" = "1" ]; then
  if [ ! -f "$WORK/tiny/bundle/manifest.json" ]; then
    # as tests/tiny_bundle.py builds it, into our own folder (its .cache is shared with pytest)
    (cd "$ROOT" && export TQDM_DISABLE=1 &&
      "$PY" -m mogo_export.cli dataset "$WORK/tiny/data" --clips 60 --seed 0 &&
      "$PY" -m mogo_export.cli train --data "$WORK/tiny/data" --out "$WORK/tiny/checkpoints" --preset tiny &&
      "$PY" -m mogo_export.cli export "$WORK/tiny/checkpoints" --out "$WORK/tiny/bundle")
  fi
  BUNDLES+=(--bundle "tiny=$WORK/tiny/bundle")
fi
for extra in ${MOGO_JS_BUNDLES:-}; do
  BUNDLES+=(--bundle "$extra")
done

"$PY" "$JS/test/make_reference.py" --out "$WORK/reference" "${BUNDLES[@]}"
"$PY" "$JS/test/make_wire_reference.py" --out "$WORK/reference" --compact "$WORK/toy-portable" --steered "$WORK/toy-control"
"$PY" "$JS/test/make_serve_reference.py" --out "$WORK/reference" --bundle "$WORK/toy-portable"
cd "$JS"
# the server's client (test/serve.test.mjs) uses the global WebSocket: Node 22 has it, Node 20 behind a flag
if ! node -e 'process.exit(typeof WebSocket === "function" ? 0 : 1)'; then
  export NODE_OPTIONS="${NODE_OPTIONS:-} --experimental-websocket"
fi
PYTHON="$PY" MOGO_JS_REFERENCE="$WORK/reference" MOGO_JS_TOY="$WORK/toy" MOGO_JS_TOY_CONTROL="$WORK/toy-control" \
  MOGO_JS_BROKEN="$WORK/broken" node --test test/*.test.mjs
