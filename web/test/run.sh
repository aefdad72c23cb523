#!/usr/bin/env bash
# The web page's tests, from a clean clone (`make test-web` runs this):
#   1. find Debian's chromium (install it with apt-get where we are root, else stop and say what to install);
#   2. install web/'s npm packages (onnxruntime-web, three, playwright-core) if missing: `npm ci --ignore-scripts`
#      from package-lock.json (no browser download: playwright-core drives the system chromium);
#   3. build the toy bundle of tests/runtime/toy_bundle.py (endless, fp32 + int8) with the repository's venv, the
#      copies of it the page test needs (toy-variants, toy-failing, and toy-clips: no endless streams), the toy
#      bundle with control (toy-control: click-to-walk, tests/golden/toy_control.json), and write
#      what the Python runtime gives on the toy bundle and MOGO_WEB_BUNDLES (web/test/reference.py);
#   4. run `node --test`: the BVH writer against bvh.py, then the page in headless chromium (page.test.mjs), which
#      prints `web:` lines (tokens compared, time to first frame, frames per second, the screenshots' path).
#
# Environment:
#   PYTHON=...                the Python with mogo_runtime (default .venv/bin/python)
#   CHROMIUM=...              the browser (default: chromium on PATH)
#   MOGO_WEB_BUNDLES="a=DIR"  also test existing bundles in the page, e.g. "base=bundles/base" (space-separated)
#   MOGO_WEB_OUT=DIR          where screenshots go (default outputs/web-test)
set -euo pipefail

WEB="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ROOT="$(dirname "$WEB")"
PY="${PYTHON:-$ROOT/.venv/bin/python}"

CHROMIUM="${CHROMIUM:-$(command -v chromium || true)}"
if [ -z "$CHROMIUM" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "test-web: chromium is missing; installing Debian's package (apt-get install -y chromium)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    CHROMIUM="$(command -v chromium)"
  else
    echo "test-web: error: the browser tests need Debian's chromium; install it with" >&2
    echo "    sudo apt-get update && sudo apt-get install -y chromium" >&2
    echo "or point CHROMIUM=/path/to/chromium at another Chromium build" >&2
    exit 2
  fi
fi

if [ ! -d "$WEB/node_modules/playwright-core" ] || [ ! -d "$WEB/node_modules/onnxruntime-web" ] || [ ! -d "$WEB/node_modules/three" ]; then
  (cd "$WEB" && npm ci --ignore-scripts --no-audit --no-fund)
fi

WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT

"$PY" "$ROOT/tests/runtime/toy_bundle.py" "$WORK/bundles/toy"
"$PY" "$ROOT/tests/runtime/toy_bundle.py" "$WORK/bundles/toy-clips" --clips
"$PY" "$ROOT/tests/runtime/toy_bundle.py" "$WORK/bundles/toy-control" --control   # tests/golden/toy_control.json's
"$PY" - "$WORK" <<'EOF'
import sys
from pathlib import Path

work = Path(sys.argv[1])
# the same bundle with two variants the page does not know: `copy` (the fp32 graphs, so the page's runtime runs it
# and must offer it; not named `portable`, which needs the manifest's portable section) and `broken` (a step graph
# onnxruntime cannot read: not offered, named)
import hashlib, json, shutil  # noqa: E401,E402
shutil.copytree(work / "bundles" / "toy", work / "bundles" / "toy-variants")
folder = work / "bundles" / "toy-variants"
(folder / "broken.onnx").write_bytes(b"not an onnx graph")
manifest = json.loads((folder / "manifest.json").read_text())
files = manifest["variants"]["fp32"]
manifest["variants"]["copy"] = {g: {"file": e["file"], "quantization": None} for g, e in files.items()}
manifest["variants"]["broken"] = {**files, "step": {"file": "broken.onnx", "quantization": {"method": "made-later"}}}
data = (folder / "broken.onnx").read_bytes()
manifest["files"]["broken.onnx"] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
(folder / "manifest.json").write_text(json.dumps(manifest, indent=1))

# toy-failing: the decoder gives NaN whenever it decodes more than one token, so a stream shows its first token's
# frames and then fails in the worker (the runtime refuses NaN), and every clip fails
import numpy as np, onnx  # noqa: E401,E402
from onnx import helper, numpy_helper  # noqa: E402
shutil.copytree(work / "bundles" / "toy", work / "bundles" / "toy-failing")
folder = work / "bundles" / "toy-failing"
model = onnx.load(folder / "decoder.onnx")
for node in model.graph.node:
    node.output[:] = ["features_raw" if o == "features" else o for o in node.output]
model.graph.initializer.extend([numpy_helper.from_array(np.array([1], np.int64), "fail_axis"),
                                numpy_helper.from_array(np.array([1], np.int64), "fail_one_token"),
                                numpy_helper.from_array(np.array(np.nan, np.float32), "fail_nan"),
                                numpy_helper.from_array(np.array(1.0, np.float32), "fail_keep")])
model.graph.node.extend([helper.make_node("Shape", ["latent"], ["fail_shape"]),
                         helper.make_node("Gather", ["fail_shape", "fail_axis"], ["fail_tokens"]),
                         helper.make_node("Greater", ["fail_tokens", "fail_one_token"], ["fail_more"]),
                         helper.make_node("Where", ["fail_more", "fail_nan", "fail_keep"], ["fail_factor"]),
                         helper.make_node("Mul", ["features_raw", "fail_factor"], ["features"])])
onnx.checker.check_model(model, full_check=True)
onnx.save(model, folder / "decoder.onnx")
manifest = json.loads((folder / "manifest.json").read_text())
data = (folder / "decoder.onnx").read_bytes()
manifest["files"]["decoder.onnx"] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
(folder / "manifest.json").write_text(json.dumps(manifest, indent=1))
print(f"toy bundles built in {work}/bundles")
EOF

BUNDLES=("toy=$WORK/bundles/toy")
for extra in ${MOGO_WEB_BUNDLES:-}; do
  BUNDLES+=("$extra")
done
"$PY" "$WEB/test/reference.py" clips --out "$WORK/reference.json" "${BUNDLES[@]}"

cd "$WEB"
CHROMIUM="$CHROMIUM" PYTHON="$PY" MOGO_WEB_REFERENCE="$WORK/reference.json" MOGO_WEB_WORK="$WORK" \
  MOGO_WEB_OUT="${MOGO_WEB_OUT:-$ROOT/outputs/web-test}" node --test --test-concurrency=1 test/*.test.mjs
