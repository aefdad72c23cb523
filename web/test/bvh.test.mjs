// js/src/outputs/bvh.js (the browser's BVH writer) against runtime/mogo_runtime/outputs/bvh.py on the same joints: a real HumanML3D clip and a noisy copy.

import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { test } from 'node:test';
import { fileURLToPath } from 'node:url';

import { SKELETONS } from '../../js/src/kinematics/skeleton.js';
import { fixed, jointsToBvhText } from '../../js/src/outputs/bvh.js';
import { compareBvh } from './compare.mjs';

const PY = process.env.PYTHON ?? fileURLToPath(new URL('../../.venv/bin/python', import.meta.url));
const reference = JSON.parse(execFileSync(PY, [fileURLToPath(new URL('./reference.py', import.meta.url)), 'fixture'],
  { maxBuffer: 1 << 28, encoding: 'utf8' }));

for (const c of reference.cases) {
  test(`BVH of ${c.name} (${c.frames} frames, ${c.units}, ${c.fps} fps) equals bvh.py's`, () => {
    const js = jointsToBvhText(c.joints, c.frames, SKELETONS.humanml3d, { fps: c.fps, units: c.units });
    const r = compareBvh(js, c.bvh, c.name);
    console.log(`web: bvh ${c.name}: ${r.identical} of ${r.lines} lines identical to Python's, ${r.sameValues} of `
      + `${r.values} numbers, the rest within ${r.maxDiff.toExponential(1)}`);
    assert.ok(r.identical >= r.lines - 2, `${c.name}: only ${r.identical} of ${r.lines} lines identical`);
  });
}

test("numbers are printed as Python's f'{x:.6f}' prints them (ties to even, negative zero)", () => {
  // exact binary ties: 2**-7 = 0.0078125 and 3 * 2**-7 = 0.0234375 round to the even digit
  assert.equal(fixed(0.0078125, 6), '0.007812');
  assert.equal(fixed(0.0234375, 6), '0.023438');
  assert.equal(fixed(-0.0078125, 6), '-0.007812');
  assert.equal(fixed(-0, 6), '-0.000000');
  assert.equal(fixed(-1e-9, 6), '-0.000000');
  assert.equal(fixed(0.05, 8), '0.05000000');
  assert.equal(fixed(123.4567895, 6), '123.456789');   // not a tie in binary: below the half
});

test('bad joints are refused with the reason', () => {
  const sk = SKELETONS.humanml3d;
  assert.throws(() => jointsToBvhText(new Float32Array(10), 1, sk), /shape \(T, 22, 3\)/);
  const nan = new Float32Array(66).fill(0.1);
  nan[5] = NaN;
  assert.throws(() => jointsToBvhText(nan, 1, sk), /NaN or inf, first at frame 0 joint 1 \(left_hip\)/);
  assert.throws(() => jointsToBvhText(new Float32Array(66), 1, sk), /zero length/);
});
