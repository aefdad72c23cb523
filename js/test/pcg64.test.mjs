import test from 'node:test';
import assert from 'node:assert/strict';
import { PCG64 } from '../src/pcg64.js';
import { readReference, report } from './reference.mjs';

const { pcg64 } = readReference('units.json');

test('PCG64 draws what numpy draws, bit for bit, for every seed', () => {
  let draws = 0;
  for (const { seed, draws: want } of pcg64) {
    const rng = new PCG64(BigInt(seed));
    want.forEach((w, i) => assert.equal(rng.random(), w, `seed ${seed}, draw ${i}`));
    draws += want.length;
  }
  report(`PCG64: ${draws} draws over ${pcg64.length} seeds identical to numpy`);
});

test('PCG64 takes number and BigInt seeds alike and refuses negative ones', () => {
  assert.equal(new PCG64(5).random(), new PCG64(5n).random());
  assert.throws(() => new PCG64(-1), /seed must be >= 0/);
});
