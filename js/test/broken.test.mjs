// Bundles whose graphs are broken or lie, their hashes forged, as test/make_broken.py builds them (run.sh does). Like
// the Python runtime, the JavaScript one refuses each with a BundleError naming the graph, at load where the graph
// declares what is wrong, else at its first call: it never returns a motion read from misshapen outputs.

import test from 'node:test';
import assert from 'node:assert/strict';
import { join } from 'node:path';
import { MotionGenerator } from '../src/generator.js';
import { BundleError, NonFiniteOutput } from '../src/index.js';

const dir = process.env.MOGO_JS_BROKEN;
if (!dir) throw new Error('MOGO_JS_BROKEN is not set: run js/test/run.sh (it builds the broken bundles)');
const WALK = 'a person walks forward';
const load = (name, variant = 'fp32') => MotionGenerator.load(join(dir, name), { variant });
const refused = (pattern) => (e) => e instanceof BundleError && pattern.test(e.message) && !e.message.includes('\n');

for (const graph of ['step', 'decoder']) {
  test(`NaN weights in ${graph}.onnx: NonFiniteOutput naming it, no motion`, async () => {
    const gen = await load(`nan-${graph}`);
    await assert.rejects(gen.generate(WALK, { seconds: 1, seed: 0 }),
      (e) => e instanceof NonFiniteOutput && e.message.startsWith(`${graph}.onnx: the ${graph} graph produced NaN`));
  });
}

test('a step graph whose logits are wider, or (portable) narrower, than the manifest says is refused at load', async () => {
  await assert.rejects(load('wide-logits'),
    refused(/wide-logits\/step\.onnx: output "logits" has shape \["batch",1,2,18\], manifest graphs\.step says/));
  await assert.rejects(load('narrow-portable-logits', 'portable'),
    refused(/step\.portable\.onnx: output "logits" has shape \["batch",1,2,16\], manifest portable\.step says/));
});

test('a step graph that returns logits of another width than it declares is refused at its first call', async () => {
  for (const [name, variant, width] of [['lying-wide-logits', 'fp32', 18], ['lying-narrow-portable-logits', 'portable', 16]]) {
    const gen = await load(name, variant);
    const file = variant === 'fp32' ? 'step\\.onnx' : 'step\\.portable\\.onnx';
    await assert.rejects(gen.generate(WALK, { seconds: 1, seed: 0 }),
      refused(new RegExp(`^${file}: returned logits \\[1,1,2,${width}\\] and a cache .* the manifest's model says \\[1, 1, 2, 17\\]`)));
    await assert.rejects((async () => { for await (const frame of await gen.stream(WALK)) assert.ok(frame); })(),
      refused(new RegExp(`^${file}: returned logits`)));
  }
});

test('a step graph whose cache grows faster than the steps fed is refused at its first call', async () => {
  const gen = await load('growing-cache'), start = performance.now();
  await assert.rejects(gen.generate(WALK, { seconds: 4, seed: 0 }),
    refused(/^step\.onnx: returned logits \[1,1,2,17\] and a cache \[1,2,2,4\] for 1 step\(s\) after 0; the manifest's model says \[1, 1, 2, 17\] and \[1,2,1,4\]/));
  assert.ok(performance.now() - start < 2000, 'refused, but not at once');
});

test('a graph onnxruntime fails to run is a BundleError naming it', async () => {
  const gen = await load('decoder-fails-at-run');
  await assert.rejects(gen.generate(WALK, { seconds: 1, seed: 0 }),
    refused(/^decoder\.onnx: onnxruntime could not run the decoder graph \(.*\); the bundle is broken$/));
});

test('a tokenizer that could explode (a Replace in a Sequence) is refused at load, naming the file and the part', async () => {
  await assert.rejects(load('exploding-tokenizer'),
    refused(/exploding-tokenizer\/tokenizer\.json: normalizer "Replace" is not one this runtime reads \(it reads BertNormalizer, /));
});
