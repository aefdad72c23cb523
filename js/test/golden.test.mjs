// The golden tokens (tests/golden/toy.json, written by the Python runtime) from the JavaScript runtime: the same
// toy bundle, prompts, seeds and settings must give exactly the stored tokens (and, for prompts of several actions,
// the stored aligned texts, and for streams, the tokens their prompt switches landed at). And the controlled streams of
// tests/golden/toy_control.json: the same requests at the same frames give the same tokens, landing at the same
// tokens, the same arrivals, and control vectors within float32 rounding of Python's. run.sh builds the toy
// bundles and passes their folders as MOGO_JS_TOY and MOGO_JS_TOY_CONTROL.

import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';
import { MotionGenerator } from '../src/generator.js';
import { SamplingConfig } from '../src/bundle/sampling.js';
import { compareControlCase, runControlCase, samplingOf } from './control_case.mjs';
import { runGoldenCase, sameAsGolden } from './golden_case.mjs';
import { report } from './reference.mjs';

const ROOT = fileURLToPath(new URL('../..', import.meta.url));
const GOLDEN = JSON.parse(readFileSync(join(ROOT, 'tests', 'golden', 'toy.json'), 'utf8'));
const GOLDEN_CONTROL = JSON.parse(readFileSync(join(ROOT, 'tests', 'golden', 'toy_control.json'), 'utf8'));

function toyFolder(name = 'MOGO_JS_TOY') {
  const dir = process.env[name];
  if (!dir) throw new Error(`${name} is not set: run js/test/run.sh (it builds the toy bundles)`);
  return dir;
}

/** The sha256 of the files the golden cases of `variants` run (as make_golden.bundle_hashes). */
function bundleHashes(dir, variants) {
  const manifest = JSON.parse(readFileSync(join(dir, 'manifest.json'), 'utf8'));
  const used = new Set([manifest.text_encoder.tokenizer,
    ...variants.flatMap((v) => Object.values(manifest.variants[v]).map((g) => g.file))]);
  return Object.fromEntries(Object.entries(manifest.files)
    .filter(([name]) => used.has(name)).map(([name, f]) => [name, f.sha256]));
}

const sampling = (cfg) => new SamplingConfig(samplingOf(cfg));

test('the JavaScript runtime gives the golden tokens', async () => {
  const dir = toyFolder();
  // the files the golden cases run: fp32 and int8 graphs and the tokenizer
  assert.deepEqual(bundleHashes(dir, ['fp32', 'int8']), GOLDEN.files,
    'the toy bundle changed since tests/golden/toy.json was written: regenerate it (tests/golden/make_golden.py)');
  const generators = {};
  let same = 0, steps = 0;
  const wrong = [];
  for (const [i, c] of GOLDEN.cases.entries()) {
    generators[c.variant] ??= await MotionGenerator.load(dir, { variant: c.variant, threads: 1 });
    const got = await runGoldenCase(generators[c.variant], c, sampling(c.sampling));
    steps += c.tokens.reduce((n, t) => n + t.length, 0);
    if (sameAsGolden(got, c)) same += 1;
    else wrong.push(i);
  }
  const planned = GOLDEN.cases.filter((c) => c.aligned).length, streams = GOLDEN.cases.filter((c) => c.stream).length;
  report(`golden: ${same} of ${GOLDEN.cases.length} cases (${steps} time steps; ${planned} with prompts of several `
    + `actions, ${streams} of them streams with prompt switches) identical to tests/golden/toy.json`);
  assert.deepEqual(wrong, [], `cases ${wrong.slice(0, 5).join(', ')} differ`);
});

test('the JavaScript runtime gives the golden controlled streams', async () => {
  const dir = toyFolder('MOGO_JS_TOY_CONTROL');
  const variants = [...new Set(GOLDEN_CONTROL.cases.map((c) => c.variant))];
  assert.deepEqual(bundleHashes(dir, variants), GOLDEN_CONTROL.files,
    'the control toy bundle changed since tests/golden/toy_control.json was written: regenerate it (tests/golden/make_golden.py)');
  const generators = {};
  const wrong = [];
  let same = 0, tokens = 0, vectors = 0, exact = 0, worst = 0;
  for (const [i, c] of GOLDEN_CONTROL.cases.entries()) {
    generators[c.variant] ??= await MotionGenerator.load(dir, { variant: c.variant, threads: 1 });
    const r = compareControlCase(await runControlCase(generators[c.variant], c, sampling(c.sampling)), c);
    tokens += c.tokens.length;
    vectors += r.vectors;
    exact += r.exact;
    worst = Math.max(worst, r.worst);
    if (r.same) same += 1;
    else wrong.push(i);
  }
  report(`golden control: ${same} of ${GOLDEN_CONTROL.cases.length} controlled streams (${tokens} tokens; requests landed `
    + `at the same tokens) identical to tests/golden/toy_control.json; control vectors: ${exact} of ${vectors} `
    + `bit-identical, max |difference| ${worst.toExponential(1)}`);
  assert.deepEqual(wrong, [], `controlled streams ${wrong.slice(0, 5).join(', ')} differ`);
});
