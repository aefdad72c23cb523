// Bundles that load but are broken: NaN weights in a graph (its hash forged), as tests/runtime/corrupt.py makes
// them. Like the Python engine, the JavaScript one refuses to return NaN or inf, naming the graph.

import test from 'node:test';
import assert from 'node:assert/strict';
import { MotionGenerator } from '../src/generator.js';
import { NonFiniteOutput } from '../src/index.js';

const broken = (process.env.MOGO_JS_BROKEN || '').split(' ').filter(Boolean);

test('run.sh built the broken bundles', () => assert.ok(broken.length >= 2, 'MOGO_JS_BROKEN lists no bundles'));

for (const entry of broken) {
  const [graph, path] = entry.split('=');
  test(`NaN weights in ${graph}: NonFiniteOutput naming it, no motion`, async () => {
    const gen = await MotionGenerator.load(path, { variant: 'fp32', threads: 1 });
    await assert.rejects(gen.generate('a person walks forward', { seconds: 1, seed: 0 }),
      (e) => e instanceof NonFiniteOutput && e.message.startsWith(`${graph}: the ${graph.split('.')[0]} graph produced NaN`));
  });
}
