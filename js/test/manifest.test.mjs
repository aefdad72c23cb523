import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import * as ort from 'onnxruntime-node';
import { Bundle } from '../src/bundle.js';
import { BundleError, parseManifest } from '../src/manifest.js';
import { MotionGenerator } from '../src/generator.js';
import { fileLoader, urlLoader } from '../src/io.js';
import { bundleReferences } from './reference.mjs';

const toy = bundleReferences().find((r) => r.name === 'toy');
if (!toy) throw new Error('the reference has no toy bundle (bundle-toy.json): run js/test/run.sh');
const original = JSON.parse(readFileSync(join(toy.path, 'manifest.json'), 'utf8'));
const edited = (edit) => {
  const m = structuredClone(original);
  edit(m);
  return m;
};
const refused = (edit, pattern) => assert.throws(() => parseManifest(edited(edit), 'm.json'),
  (e) => e instanceof BundleError && pattern.test(e.message), `expected ${pattern}`);

test('the toy manifest parses: dims, special tokens, cache names, variants, streaming', () => {
  const m = parseManifest(original, 'm.json');
  assert.equal(m.model.endId, m.model.codebookSize);
  assert.equal(m.model.bosId, m.model.codebookSize + 1);
  assert.deepEqual(m.pastNames.slice(0, 2), ['past_key_values.0.key', 'past_key_values.0.value']);
  assert.deepEqual(m.presentNames.slice(-1), [`present.${m.model.nLayers - 1}.value`]);
  assert.equal(m.variants.fp32.step.quantized, false);
  assert.equal(m.variants.int8.step.quantized, true);
  assert.deepEqual(m.streaming, { window: original.streaming.window, refresh: original.streaming.refresh });
  assert.equal(m.samplingDefaults.topP, original.sampling_defaults.top_p);
});

test('a bad manifest is refused with the file and the field named', () => {
  refused((m) => { m.schema = 'other'; }, /m\.json: field schema: .*\(not a mogo bundle\)/);
  refused((m) => { m.schema_version = 1; }, /field schema_version: is 1; this runtime reads version 2/);
  refused((m) => { delete m.model.n_layers; }, /field model\.n_layers: missing/);
  refused((m) => { m.model.codebook_size = 0; }, /field model\.codebook_size: expected an integer in \[1/);
  refused((m) => { m.model.end_id += 1; }, /field model\.end_id: .* the other sizes imply/);
  refused((m) => { m.model.fps = 0; }, /field model\.fps: expected a number in \(0, 1000\]/);
  refused((m) => { m.skeleton.parents[3] = 1; }, /field skeleton\.parents: differs/);
  refused((m) => { m.cache.past = 'past.{layer}'; }, /field cache\.past: a name template with \{layer\} and \{kind\}/);
  refused((m) => { m.cache.past = 'past.{layer}.{kind}.{oops}'; }, /field cache\.past/);
  refused((m) => { m.sampling_defaults.top_p = 2; }, /field sampling_defaults: top_p must be in \(0, 1\]/);
  refused((m) => { m.sampling_defaults.beam = 2; }, /field sampling_defaults\.beam: unknown sampling setting/);
  refused((m) => { m.streaming.window = m.model.max_rel_dist; }, /field streaming\.refresh: window \+ refresh is/);
  refused((m) => { delete m.variants.fp32; }, /field variants\.fp32: missing/);
  refused((m) => { m.variants.int8.step.file = 'nope.onnx'; }, /field variants\.int8\.step\.file: "nope\.onnx" is not in 'files'/);
  refused((m) => { m.files['../x'] = m.files['step.onnx']; }, /a bundle file must be a plain file name/);
  refused((m) => { m.graphs.step.inputs.reverse(); }, /field graphs\.step\.inputs: names and ranks/);
  refused((m) => { m.graphs.step.outputs[0].shape[3] += 1; }, /graphs\.step\.outputs\[0\]\.shape: .* should end in/);
  refused((m) => { m.normalization.mode = 'x'; }, /field normalization\.mode/);
  refused((m) => { m.text_encoder.pooling = 'cls'; }, /field text_encoder\.pooling: only mean pooling/);
});

test('a file that is not what the manifest records is refused when it is read', async () => {
  const loader = fileLoader(toy.path);
  const tampered = { where: toy.path, readBytes: async (name) => {
    const bytes = await loader.readBytes(name);
    if (name === 'step.onnx') bytes[bytes.length - 1] ^= 1;
    return bytes;
  } };
  await assert.rejects(MotionGenerator.load(tampered), /step\.onnx: sha256 does not match the manifest/);
  await assert.rejects(MotionGenerator.load(toy.path, { variant: 'fp16' }), /unknown variant "fp16"; bundle .* has fp32, int8/);
  await assert.rejects(MotionGenerator.load(toy.path, { threads: 0 }), /threads must be an int in \[1, 64\]/);
  await assert.rejects(MotionGenerator.load('/nonexistent/bundle'), /manifest missing or unreadable/);
});

test('a graph whose inputs differ from the manifest is refused', async () => {
  const bundle = await Bundle.load(fileLoader(toy.path));
  const session = await ort.InferenceSession.create(join(toy.path, 'lookup.onnx'));
  assert.throws(() => bundle.checkSession('decoder', 'lookup.onnx', session), /lookup\.onnx: inputs are \["tokens"\], manifest graphs\.decoder\.inputs lists \["latent"\]/);
});

test('urlLoader reads a bundle through fetch (the browser path), with the same checks', async () => {
  const files = fileLoader(toy.path);
  const fetchFn = async (url) => {
    const name = decodeURIComponent(url.slice('https://example.test/toy/'.length));
    try {
      const bytes = await files.readBytes(name);
      return { ok: true, status: 200, arrayBuffer: async () => bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.length) };
    } catch {
      return { ok: false, status: 404 };
    }
  };
  const gen = await MotionGenerator.load(urlLoader('https://example.test/toy', fetchFn), { ort });
  const fromDisk = await MotionGenerator.load(toy.path);
  const a = await gen.generate('a person walks forward', { seed: 3 });
  const b = await fromDisk.generate('a person walks forward', { seed: 3 });
  assert.deepEqual(a.tokens, b.tokens);
});
