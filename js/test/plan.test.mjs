// A prompt of several actions splits as the Python runtime splits it (runtime/mogo_runtime/plan.py): plan.js is held
// to tests/golden/plans.json case by case, errors included (their words).

import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';
import { MAX_ACTIONS, planActions } from '../src/plan.js';

const ROOT = fileURLToPath(new URL('../..', import.meta.url));
const TABLE = JSON.parse(readFileSync(join(ROOT, 'tests', 'golden', 'plans.json'), 'utf8')).cases;

for (const [prompt, want] of TABLE) {
  test(`plans.json: ${JSON.stringify(prompt).slice(0, 60)}`, () => {
    if (typeof want === 'string') {
      assert.throws(() => planActions(prompt), (e) => e instanceof RangeError && e.message.includes(want));
    } else {
      assert.deepEqual(planActions(prompt).map((a) => [a.text, a.seconds]), want);
    }
  });
}

test('the table covers what it must: several actions, durations, subjects, errors', () => {
  assert.ok(TABLE.length >= 19);
  assert.ok(TABLE.some(([, want]) => typeof want === 'string' && want.includes(`at most ${MAX_ACTIONS} actions`)));
  assert.ok(TABLE.some(([, want]) => Array.isArray(want) && want.some(([, s]) => s !== null)));
});
