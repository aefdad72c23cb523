"""Time per token of an endless stream's token loop in the Python runtime (compare: js/scripts/bench.mjs).

    .venv/bin/python js/scripts/bench.py BUNDLE [variant] [steps]   -> one JSON line
"""
import json
import sys
import time

from mogo_runtime import MotionGenerator
from mogo_runtime.decoding import GenerationTask

bundle, variant, steps = sys.argv[1], (sys.argv[2:3] or ["fp32"])[0], int((sys.argv[3:4] or ["300"])[0])
gen = MotionGenerator(bundle, variant=variant, threads=1)
emb = gen.backend.encode_text(["a person walks forward"])
task = GenerationTask(gen.backend, gen.skeleton, gen.sampling_defaults, gen.max_tokens, None, gen.bundle.manifest.streaming)
loop = task.loop(emb, [1])
for _ in range(20):   # warm up
    loop.step()
times = []
for _ in range(steps):
    t0 = time.perf_counter()
    loop.step()
    times.append((time.perf_counter() - t0) * 1e3)
times.sort()
print(json.dumps({"runtime": "python", "variant": variant, "steps": len(times), "median_ms": times[len(times) // 2],
                  "mean_ms": sum(times) / len(times)}))
