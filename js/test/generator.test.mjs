// MotionGenerator's arguments are checked, and defaulted, as Python's are (generator.py).

import test from 'node:test';
import assert from 'node:assert/strict';
import { MotionGenerator } from '../src/generator.js';
import { bundleReferences } from './reference.mjs';

const refs = Object.fromEntries(bundleReferences().map((r) => [r.name, r]));
for (const name of ['toy', 'toy-clips']) {
  if (!refs[name]) throw new Error(`the reference has no ${name} bundle: run js/test/run.sh`);
}
const endless = await MotionGenerator.load(refs.toy.path);
const clips = await MotionGenerator.load(refs['toy-clips'].path);
const WALK = 'a person walks forward';

test('prompts: a string or a non-empty list of non-blank strings', async () => {
  await assert.rejects(endless.generate('   '), /prompt 0 is empty or whitespace only/);
  await assert.rejects(endless.generate([]), /empty list of prompts/);
  await assert.rejects(endless.generate([WALK, 3]), /prompt 1 is a number, expected a string/);
  await assert.rejects(endless.stream([WALK]), /stream\(\) takes one prompt/);
});

test('seconds: rounded half up to whole tokens, within the bundle\'s range', async () => {
  const perToken = endless.dims.downsample / endless.dims.fps;
  assert.equal(endless.tokensFor(1.5 * perToken), 2);
  assert.equal(endless.tokensFor(0.5 * perToken), 1);
  assert.equal(endless.tokensFor(null), null);
  assert.throws(() => endless.tokensFor(0.4 * perToken), /seconds must be between/);
  assert.throws(() => endless.tokensFor('3'), /seconds must be a number/);
  assert.throws(() => clips.tokensFor(clips.maxSeconds + 2 * perToken), /for this bundle/);
  assert.equal(endless.tokensFor(clips.maxSeconds + 2 * perToken), clips.maxTokens + 2);   // endless: up to an hour
  const m = await endless.generate(WALK, { seconds: 10 * perToken, seed: 1 });
  assert.deepEqual(m.tokens.dims, [10, endless.dims.numLevels]);
  assert.deepEqual(m.joints.dims, [10 * endless.dims.downsample, 22, 3]);
});

test('seeds: prompt i of a batch draws what a lone run with seed + i draws', async () => {
  const [a, b] = await endless.generate([WALK, 'a person jumps twice'], { seed: 3 });
  const lone = await endless.generate('a person jumps twice', { seed: 4 });
  assert.deepEqual(b.tokens, lone.tokens);
  assert.equal(a.seed, 3n);
  await assert.rejects(endless.generate(WALK, { seed: -1 }), /seeds must be ints in \[0, 2\*\*63\)/);
  await assert.rejects(endless.generate(WALK, { seed: 2n ** 63n }), /seeds must be ints in \[0, 2\*\*63\)/);
  await assert.rejects(endless.generate(WALK, { seed: 1.5 }), /seed must be an int/);
  await assert.rejects(endless.generate([WALK, WALK], { seed: [1] }), /got 1 seeds for 2 prompts/);
});

test('sampling: null means the bundle\'s defaults; a plain object is checked', async () => {
  const defaults = await endless.generate(WALK, { seed: 5 });
  const explicit = await endless.generate(WALK, { seed: 5, sampling: { temperature: 1, topP: endless.samplingDefaults.topP } });
  assert.deepEqual(defaults.tokens, explicit.tokens);
  await assert.rejects(endless.generate(WALK, { sampling: { temp: 1 } }), /unknown sampling setting "temp"/);
});

test('timelines: starts from 0, increasing, before the end; endless bundles only', async () => {
  const story = [[WALK, 0], ['a person jumps twice', 1.0]];
  await assert.rejects(endless.generate(story), /a timeline needs seconds/);
  await assert.rejects(endless.generate([[WALK, 0.5], ['a person jumps', 1.0]], { seconds: 2 }), /must begin at 0 and increase/);
  await assert.rejects(endless.generate([[WALK, 0], ['a person jumps', 0]], { seconds: 2 }), /must begin at 0 and increase/);
  await assert.rejects(endless.generate(story, { seconds: 1.0 }), /each before the end/);
  await assert.rejects(clips.generate(story, { seconds: 2 }), /not trained for endless streams/);
  const m = await endless.generate(story, { seconds: 2, seed: 1 });
  assert.equal(m.text, `${WALK} | a person jumps twice`);
});

test('progress is reported after every step with the step limit', async () => {
  const seen = [];
  await endless.generate(WALK, { seconds: 1.0, onProgress: (step, limit) => seen.push([step, limit]) });
  assert.deepEqual(seen, [1, 2, 3, 4, 5].map((s) => [s, 5]));
});

test('an endless stream has no end; its start is the fixed-length motion of the same seed', async () => {
  const s = await endless.stream(WALK, { seed: 3 });
  const n = 3 * endless.maxTokens * endless.dims.downsample;   // far past max_tokens
  const frames = [];
  for await (const frame of s) {
    frames.push(frame);
    if (frames.length === n) await s.close();
  }
  assert.deepEqual(frames.map((f) => f.index), Array.from({ length: n }, (_, i) => i));
  assert.equal(frames[5].time, 5 / endless.fps);
  const within = endless.bundle.manifest.streaming.window + endless.bundle.manifest.streaming.refresh + 1;
  const m = await endless.generate(WALK, { seconds: within * endless.dims.downsample / endless.fps, seed: 3 });
  const streamed = frames.slice(0, m.numFrames).flatMap((f) => Array.from(f.joints));
  assert.ok(streamed.every((x, i) => Math.abs(x - m.joints.data[i]) <= 1e-5));
  await assert.rejects(endless.stream(WALK, { chunk: 0 }), /chunk must be an int in \[1, 1024\]/);
  assert.throws(() => s.setPrompt(''), /this stream is closed/);
});

test('a stream closed, or whose motion ended, follows no more prompts', async () => {
  const closed = /this stream is closed \(close\(\), or its motion ended\): it follows no more prompts$/;
  const s = await endless.stream(WALK, { seed: 1 });
  assert.throws(() => s.setPrompt(''), /prompt 0 is empty/);
  await s.next();
  await s.setPrompt('a person jumps twice');
  await s.close();
  assert.throws(() => s.setPrompt('a person turns left'), closed);
  const never = await endless.stream(WALK, { seed: 1 });   // closed before its first frame
  await never.close();
  assert.throws(() => never.setPrompt('a person turns left'), closed);
  const ended = await endless.stream(WALK, { seed: 1, seconds: 1 });
  for await (const frame of ended) assert.ok(frame.time < 1);
  assert.throws(() => ended.setPrompt('a person turns left'), closed);
  assert.deepEqual(s.switches, [{ token: 1, text: 'a person jumps twice', alignedText: null }]);
});

// A prompt of several actions (plan.js), as tests/runtime/test_plan.py holds the Python runtime to it.
const JUMP = 'a person jumps twice', WAVE = 'a person waves with the right hand';

test('each action of a prompt plays until the model ends it, then the next', async () => {
  const L = endless.dims.numLevels;
  for (let seed = 0; seed < 6; seed++) {
    const walk = await endless.generate(WALK, { seed });   // a lone action: the model ends it
    const both = await endless.generate(`${WALK} and then jumps twice`, { seed });
    const n = walk.tokens.dims[0];
    // up to its END the first action is exactly the lone motion; then the second one plays, and ends the motion
    assert.deepEqual(both.tokens.data.slice(0, n * L), walk.tokens.data);
    assert.ok(n < both.tokens.dims[0] && both.tokens.dims[0] <= n + endless.maxTokens);
    assert.equal(both.alignedText, `${WALK} | ${JUMP}`);
    assert.equal(walk.alignedText, null);
    assert.equal(walk.actions, null);
    assert.deepEqual(both.actions, [[WALK, 0], [JUMP, n * endless.dims.downsample]]);   // where each action starts
  }
});

test('a stated duration holds the action that long', async () => {
  const L = endless.dims.numLevels, text = `${WALK} for 2 seconds, then jumps twice for 1.2 s`;
  for (let seed = 0; seed < 4; seed++) {
    const held = await endless.generate(WALK, { seconds: 2, seed });   // END restarts the walk: 2 s exactly
    const k = held.tokens.dims[0];
    const motion = await endless.generate(text, { seed });
    assert.deepEqual(motion.tokens.data.slice(0, k * L), held.tokens.data);
    assert.equal(motion.tokens.dims[0], k + endless.tokensFor(1.2));
    const fixed = await endless.generate(text, { seconds: 6, seed });   // then the jump is held
    assert.deepEqual(fixed.tokens.data.slice(0, motion.tokens.data.length), motion.tokens.data);
    assert.equal(fixed.tokens.dims[0], endless.tokensFor(6));
  }
  await assert.rejects(endless.generate(`${WALK} for 601 seconds`), /more than 0 and at most 600 seconds/);
});

test('a list of prompts gets what each gets alone', async () => {
  const prompts = [WALK, `${JUMP}, then walks forward`, WAVE];
  const together = await endless.generate(prompts, { seed: 5 });
  for (const [i, p] of prompts.entries()) {
    assert.deepEqual((await endless.generate(p, { seed: 5 + i })).tokens, together[i].tokens);
  }
  assert.deepEqual(together.map((m) => m.alignedText), [null, `${JUMP} | ${WALK}`, null]);
});

test('a stream follows a prompt of several actions; one of too many is refused and the stream goes on', async () => {
  const ds = endless.dims.downsample, s = await endless.stream(WALK, { seed: 2, chunk: 1 });
  for (let i = 0; i < 3 * ds; i++) await s.next();
  await s.setPrompt(`${JUMP} and then waves with the right hand`);
  assert.equal(s.alignedText, `${JUMP} | ${WAVE}`);
  assert.equal(s.loop.streams[0].parts.length, 2);
  assert.equal(s.switches.at(-1).alignedText, s.alignedText);
  for (let i = 0; i < 40 * ds; i++) assert.equal((await s.next()).done, false);   // the last action is held: no end
  assert.equal(s.loop.streams[0].part, 1);
  assert.throws(() => s.setPrompt(Array(9).fill(WALK).join(', then ')), /at most 8 actions/);
  assert.equal((await s.next()).done, false);
  await s.close();
  const planned = await endless.stream(`${JUMP} for 1 second, then waves with the right hand`, { seed: 2 });
  assert.equal(planned.alignedText, `${JUMP} | ${WAVE}`);
  assert.deepEqual(planned.loop.streams[0].limits, [endless.tokensFor(1), null]);
  await planned.close();
});

test('on a bundle of single clips a prompt is one conditioning', async () => {
  const whole = `${WALK} and then jumps twice`;
  const m = await clips.generate(whole, { seed: 1 });
  assert.equal(m.alignedText, null);
  assert.deepEqual(clips.plan([whole]), [{ actions: [{ text: whole, seconds: null }], limits: [null] }]);
});
