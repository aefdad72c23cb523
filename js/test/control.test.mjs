// Control (js/src/control/) against the Python runtime's (mogo_runtime/control): the same control vectors, the same
// wanted poses of every request from the same root poses (units.json, written by make_reference.py), the same next
// root pose of a stream, the same refusals; and the requests on streams: only where the model has control and the
// stream is open.

import test from 'node:test';
import assert from 'node:assert/strict';
import { MotionGenerator } from '../src/generator.js';
import { FollowPath, GameRoot, Steer, WalkTo } from '../src/control/targets.js';
import { decode, encode } from '../src/control/vector.js';
import { RootIntegrator } from '../src/kinematics/frames.js';
import { SKELETONS } from '../src/kinematics/skeleton.js';
import { bundleReferences, maxAbsDiff, readReference, report } from './reference.mjs';

const units = readReference('units.json').control;
const refs = Object.fromEntries(bundleReferences().map((r) => [r.name, r]));
const TARGETS = { WalkTo, FollowPath, Steer };

test('control vectors, wanted poses and the next root pose: Python\'s numbers', () => {
  let exact = 0;
  const vectors = units.encode.map(({ now, future, vector }) => {
    const got = encode(now, future);
    exact += maxAbsDiff(Array.from(got), vector) === 0;
    const back = decode(now, got);   // decode undoes encode (to float32 precision)
    back.forEach((pose, k) => {
      assert.ok(Math.hypot(pose[0] - future[k][0], pose[1] - future[k][1]) < 1e-5);
      assert.ok(Math.abs(Math.sin(pose[2] - future[k][2])) < 1e-5);
    });
    return maxAbsDiff(Array.from(got), vector);
  });
  let worst = 0;
  for (const r of units.requests) {
    const target = new TARGETS[r.kind](...r.args);
    r.nows.forEach((now, i) => {
      worst = Math.max(worst, maxAbsDiff(target.future(now, units.times).flat(), r.futures[i].flat()));
      const reference = target.reference();
      assert.equal(reference === null, r.references[i] === null, `${r.kind} reference at pose ${i}`);
      if (reference !== null) worst = Math.max(worst, maxAbsDiff(reference, r.references[i]));
    });
    assert.equal(target.arrived, r.arrived, `${r.kind} arrived`);
    if (r.progress !== undefined) assert.ok(Math.abs(target.progress - r.progress) <= 1e-12, `${r.kind} progress`);
  }
  for (const placed of units.capsules) {
    const capsule = new GameRoot();
    for (const p of placed) {
      capsule.place(...p.place, p.frame);
      worst = Math.max(worst, maxAbsDiff(capsule.at(p.frame + 3), p.at),
        maxAbsDiff(capsule.future([0, 0, 0], units.times, 20, p.frame + 1).flat(), p.future.flat()));
    }
  }
  const root = new RootIntegrator(SKELETONS.humanml3d), features = Float32Array.from(units.features);
  units.next_poses.forEach((pose, i) => {
    root.push(features.subarray(i * 4 * 263, (i + 1) * 4 * 263));
    worst = Math.max(worst, maxAbsDiff(root.nextPose(), pose));
  });
  const vectorWorst = Math.max(...vectors);
  report(`control units: ${exact} of ${vectors.length} control vectors bit-identical (max |diff| ${vectorWorst.toExponential(1)}); `
    + `${units.requests.length} requests and ${units.capsules.length} capsules asked at every pose of a walk, and a `
    + `stream's next root pose: max |diff| ${worst.toExponential(1)} (float64)`);
  assert.ok(vectorWorst <= 1e-6 && worst <= 1e-9, `vectors ${vectorWorst}, poses ${worst}`);
});

test('bad requests are refused with what is wrong, as Python refuses them', () => {
  const cases = [
    [() => new WalkTo([Number.NaN, 0]), /goal must be \(x, z\): two finite numbers within 1e\+06 m/],
    [() => new WalkTo([1, 2, 3]), /goal must be/],
    [() => new WalkTo(['1', 2]), /goal must be \(x, z\) in metres \(numbers, not string\)/],
    [() => new WalkTo([true, 2]), /numbers, not boolean/],
    [() => new WalkTo([1, 2], 0), /speed must be in m\/s, from 0.05 to 10/],
    [() => new WalkTo([1, 2], 99), /speed must be/],
    [() => new FollowPath([[0, 0]]), /path must be 2 to 100000/],
    [() => new FollowPath([[0, 0], [0, 0]]), /two distinct/],
    [() => new FollowPath('abc'), /path must be a list/],
    [() => new Steer([30, 0]), /at most 10 m\/s, got 30/],
    [() => new Steer([1, 0], [0, 0]), /facing must be a direction/],
    [() => new GameRoot().place(0, 0, Infinity, 0), /heading must be/],
    [() => new GameRoot().place(0, 0, 'north', 0), /heading must be a number/],
  ];
  for (const [make, message] of cases) assert.throws(make, message);
});

test('requests need a model with control and an open stream; a bad one changes nothing', async () => {
  for (const name of ['toy', 'toy-control']) {
    if (!refs[name]) throw new Error(`the reference has no ${name} bundle: run js/test/run.sh`);
  }
  const free = await (await MotionGenerator.load(refs.toy.path)).stream('a person walks', { seed: 0 });
  assert.throws(() => free.walkTo([1, 1]), /trained without control/);
  const gen = await MotionGenerator.load(refs['toy-control'].path);
  const s = await gen.stream('a person walks', { seed: 0 });
  s.walkTo([3, 0]);
  const before = s.steering.target;
  assert.throws(() => s.walkTo('there'), /goal must be/);
  assert.throws(() => s.setRoot(1, 2, 'north'), /heading must be a number/);
  assert.equal(s.steering.target, before);
  assert.equal(s.arrived, false);
  await s.next();
  s.walkTo([s.steering.pose[0], s.steering.pose[1] + 0.1]);   // within ARRIVE of the next frame's root
  await s.next();
  assert.equal(s.arrived, true);
  await s.close();
  assert.throws(() => s.walkTo([1, 1]), /this stream is closed/);
});
