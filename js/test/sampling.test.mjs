import test from 'node:test';
import assert from 'node:assert/strict';
import { PCG64 } from '../src/pcg64.js';
import { SamplingConfig } from '../src/bundle/sampling.js';
import { applyGuidance, pairwiseSum, sample } from '../src/policy.js';
import { readReference, report } from './reference.mjs';

const { sums, sampler } = readReference('units.json');

test('pairwiseSum is numpy.sum bit for bit (pairwise blocks of 128, 8 accumulators)', () => {
  for (const { values, sum } of sums) assert.equal(pairwiseSum(Float64Array.from(values)), sum, `n = ${values.length}`);
});

test('sample picks what numpy picks: greedy, temperature, top-k, top-p, ties, END masked', () => {
  let picks = 0;
  for (const c of sampler) {
    const [B, L] = c.shape;
    const logits = Float32Array.from(c.logits, (x) => (x === null ? -Infinity : x));
    const config = SamplingConfig.fromManifest({ temperature: 1, top_k: null, top_p: null, guidance: 1, ...c.config });
    const rngs = c.seeds.map((s) => new PCG64(BigInt(s)));
    c.picks.forEach((want, step) => {
      assert.deepEqual(Array.from(sample(logits, L, config, rngs)), want.flat(), `${JSON.stringify(c.config)} ${c.shape} step ${step}`);
    });
    picks += c.picks.length * B * L;
  }
  report(`sampler: ${picks} picks over ${sampler.length} cases identical to numpy`);
});

test('SamplingConfig checks as Python does', () => {
  assert.equal(new SamplingConfig({ temperature: 0 }).greedy, true);
  assert.equal(new SamplingConfig({ topK: 0 }).topK, null);
  assert.throws(() => new SamplingConfig({ temperature: -1 }), /temperature must be in \[0, 100\]/);
  assert.throws(() => new SamplingConfig({ topP: 0 }), /top_p must be in \(0, 1\]/);
  assert.throws(() => new SamplingConfig({ topK: 1.5 }), /top_k must be an int/);
  assert.throws(() => new SamplingConfig({ guidance: 101 }), /guidance must be in \[0, 100\]/);
  assert.throws(() => new SamplingConfig({ temperature: '1' }), /temperature must be a number/);
  assert.throws(() => new SamplingConfig({ top_p: 0.9 }), /unknown sampling setting "top_p"/);
});

test('guidance is float32 arithmetic: uncond + g * (cond - uncond), each step rounded', () => {
  const cond = Float32Array.of(1.1, -3.7, 0), uncond = Float32Array.of(0.3, 2.25, 0);
  const got = applyGuidance(cond, uncond, 2.5);
  const f = Math.fround;
  for (let i = 0; i < 3; i++) assert.equal(got[i], f(uncond[i] + f(f(2.5) * f(cond[i] - uncond[i]))));
});
