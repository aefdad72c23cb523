// Time per token of an endless stream's token loop (step graph + sampling), as scripts/bench.py does for Python.
//   node js/scripts/bench.mjs BUNDLE [variant] [steps]   -> one JSON line
import { EndlessLoop, MotionGenerator } from '../src/index.js';

const [dir, variant = 'fp32', steps = '300'] = process.argv.slice(2);
const gen = await MotionGenerator.load(dir, { variant, threads: 1 });
const emb = await gen.backend.encodeText(['a person walks forward']);
const loop = new EndlessLoop(gen.backend, emb, gen.samplingDefaults, [1n], gen.bundle.manifest.streaming);
for (let i = 0; i < 20; i++) await loop.step();   // warm up
const times = [];
for (let i = 0; i < Number(steps); i++) {
  const t0 = process.hrtime.bigint();
  await loop.step();
  times.push(Number(process.hrtime.bigint() - t0) / 1e6);
}
times.sort((a, b) => a - b);
const mean = times.reduce((a, b) => a + b, 0) / times.length;
console.log(JSON.stringify({ runtime: 'node', variant, steps: times.length, median_ms: times[times.length >> 1], mean_ms: mean }));
