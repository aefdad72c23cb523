// The golden tokens (tests/golden/toy.json, written by the Python runtime) from the JavaScript runtime: the same
// toy bundle, prompts, seeds and settings must give exactly the stored tokens. run.sh builds the toy bundle and
// passes its folder as MOGO_JS_TOY.

import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';
import { MotionGenerator } from '../src/generator.js';
import { SamplingConfig } from '../src/bundle/sampling.js';
import { report } from './reference.mjs';

const ROOT = fileURLToPath(new URL('../..', import.meta.url));
const GOLDEN = JSON.parse(readFileSync(join(ROOT, 'tests', 'golden', 'toy.json'), 'utf8'));

function toyFolder() {
  const dir = process.env.MOGO_JS_TOY;
  if (!dir) throw new Error('MOGO_JS_TOY is not set: run js/test/run.sh (it builds the toy bundle)');
  return dir;
}

const sampling = (cfg) => new SamplingConfig({
  temperature: cfg.temperature, topK: cfg.top_k ?? null, topP: cfg.top_p ?? null, guidance: cfg.guidance ?? 1,
});

test('the JavaScript runtime gives the golden tokens', async () => {
  const dir = toyFolder();
  // the files the golden cases run (as make_golden.bundle_hashes): fp32 and int8 graphs and the tokenizer
  const manifest = JSON.parse(readFileSync(join(dir, 'manifest.json'), 'utf8'));
  const used = new Set([manifest.text_encoder.tokenizer,
    ...['fp32', 'int8'].flatMap((v) => Object.values(manifest.variants[v]).map((g) => g.file))]);
  const hashes = Object.fromEntries(Object.entries(manifest.files)
    .filter(([name]) => used.has(name)).map(([name, f]) => [name, f.sha256]));
  assert.deepEqual(hashes, GOLDEN.files,
    'the toy bundle changed since tests/golden/toy.json was written: regenerate it (tests/golden/make_golden.py)');
  const generators = {};
  let same = 0, steps = 0;
  const wrong = [];
  for (const [i, c] of GOLDEN.cases.entries()) {
    generators[c.variant] ??= await MotionGenerator.load(dir, { variant: c.variant, threads: 1 });
    const gen = generators[c.variant];
    const motions = await gen.generate(c.text, { seconds: c.seconds ?? null, seed: BigInt(c.seed), sampling: sampling(c.sampling) });
    const L = gen.dims.numLevels;
    const got = (Array.isArray(motions) ? motions : [motions]).map((m) => Array.from(
      { length: m.tokens.data.length / L }, (_, t) => Array.from(m.tokens.data.slice(t * L, (t + 1) * L))));
    steps += c.tokens.reduce((n, t) => n + t.length, 0);
    if (JSON.stringify(got) === JSON.stringify(c.tokens)) same += 1;
    else wrong.push(i);
  }
  report(`golden: ${same} of ${GOLDEN.cases.length} cases (${steps} time steps) identical to tests/golden/toy.json`);
  assert.deepEqual(wrong, [], `cases ${wrong.slice(0, 5).join(', ')} differ`);
});
