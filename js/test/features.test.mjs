import test from 'node:test';
import assert from 'node:assert/strict';
import { FootLock } from '../src/kinematics/frames.js';
import { SKELETONS } from '../src/kinematics/skeleton.js';
import { readReference, report } from './reference.mjs';

const { foot_lock: cases } = readReference('units.json');

test('FootLock is kinematics/frames.py FootLock bit for bit, in any chunking', () => {
  let moved = 0;
  for (const { joints, features, locked } of cases) {
    const J = Float32Array.from(joints), F = Float32Array.from(features), n = F.length / 263;
    const want = Float32Array.from(locked);
    for (const chunk of [n, 1, 4]) {
      const lock = new FootLock(SKELETONS.humanml3d), got = [];
      for (let t = 0; t < n; t += chunk) {
        const end = Math.min(n, t + chunk);
        got.push(...lock.push(J.subarray(t * 66, end * 66), F.subarray(t * 263, end * 263)));
      }
      assert.deepEqual(Float32Array.from(got), want, `${n} frames in chunks of ${chunk}`);
    }
    for (let i = 0; i < J.length; i++) moved = Math.max(moved, Math.abs(want[i] - J[i]));
  }
  assert.ok(moved > 0.01, 'the cases never lock a toe');
  report(`foot lock: ${cases.length} cases identical to Python in chunks of 1, 4 and whole; largest shift ${moved.toFixed(3)} m`);
});

test('FootLock refuses joints and features of different lengths', () => {
  assert.throws(() => new FootLock(SKELETONS.humanml3d).push(new Float32Array(66), new Float32Array(2 * 263)), /FootLock.push wants/);
});
