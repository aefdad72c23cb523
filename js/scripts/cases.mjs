// Golden-format cases (tests/golden/make_golden.py's format: variant, sampling, seed, text, seconds, stream, and the
// tokens the Python runtime gave) run by the JavaScript runtime on onnxruntime-node: which give the same tokens.
//   node js/scripts/cases.mjs BUNDLE CASES.json      -> one JSON line {runtime, cases, identical, wrong, ms}
// benchmarks/compact.py writes the cases and runs this (and web/scripts/cases.mjs, the same in Chromium).
import { readFileSync } from 'node:fs';
import { MotionGenerator } from '../src/index.js';
import { SamplingConfig } from '../src/bundle/sampling.js';
import { samplingOf } from '../test/control_case.mjs';
import { runGoldenCase, sameAsGolden } from '../test/golden_case.mjs';

const [dir, file] = process.argv.slice(2);
if (!dir || !file) {
  console.error('usage: node js/scripts/cases.mjs BUNDLE CASES.json');
  process.exit(2);
}
const cases = JSON.parse(readFileSync(file, 'utf8')).cases;
const generators = {}, wrong = [];
const t0 = performance.now();
for (const [i, c] of cases.entries()) {
  generators[c.variant] ??= await MotionGenerator.load(dir, { variant: c.variant, threads: 1 });
  const got = await runGoldenCase(generators[c.variant], c, new SamplingConfig(samplingOf(c.sampling)));
  if (!sameAsGolden(got, c)) wrong.push(i);
}
console.log(JSON.stringify({ runtime: 'node', cases: cases.length, identical: cases.length - wrong.length, wrong,
  ms: performance.now() - t0 }));
