import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import * as ort from 'onnxruntime-node';
import { Bundle } from '../src/bundle/folder.js';
import { fileLoader, urlLoader } from '../src/bundle/io.js';
import { parseManifest } from '../src/bundle/manifest.js';
import { BundleError } from '../src/bundle/sections.js';
import { MotionGenerator } from '../src/generator.js';
import { bundleReferences } from './reference.mjs';

const references = Object.fromEntries(bundleReferences().map((r) => [r.name, r]));
for (const name of ['toy', 'toy-portable']) {
  if (!references[name]) throw new Error(`the reference has no ${name} bundle (bundle-${name}.json): run js/test/run.sh`);
}
const toy = references.toy;
const original = JSON.parse(readFileSync(join(references['toy-portable'].path, 'manifest.json'), 'utf8'));
const BAD = JSON.parse(readFileSync(new URL('../../tests/golden/bad_manifests.json', import.meta.url), 'utf8'));

/** `manifest` with the edits of tests/golden/bad_manifests.json applied: set, delete or append at a JSON path. */
function edited(manifest, edits) {
  const m = structuredClone(manifest);
  for (const edit of edits) {
    const [verb] = ['set', 'delete', 'append'].filter((v) => Object.hasOwn(edit, v));
    const path = edit[verb], key = path[path.length - 1];
    const parent = path.slice(0, -1).reduce((at, k) => at[k], m);
    if (!(verb === 'set' || Object.hasOwn(parent, key))) throw new Error(`no ${JSON.stringify(path)} to ${verb}`);
    if (verb === 'set') parent[key] = structuredClone(edit.value);
    else if (verb === 'append') parent[key].push(structuredClone(edit.value));
    else if (Array.isArray(parent)) parent.splice(key, 1);
    else delete parent[key];
  }
  return m;
}

test('the toy manifest parses: dims, special tokens, cache names, variants, streaming, portable, ORT', () => {
  const m = parseManifest(original, 'm.json');
  assert.equal(m.model.endId, m.model.codebookSize);
  assert.equal(m.model.bosId, m.model.codebookSize + 1);
  assert.deepEqual(m.pastNames.slice(0, 2), ['past_key_values.0.key', 'past_key_values.0.value']);
  assert.deepEqual(m.presentNames.slice(-1), [`present.${m.model.nLayers - 1}.value`]);
  assert.equal(m.variants.fp32.step.quantized, false);
  assert.deepEqual(m.variants.int8.step.quantization, original.variants.int8.step.quantization);
  assert.deepEqual(m.streaming, { window: original.streaming.window, refresh: original.streaming.refresh });
  assert.equal(m.samplingDefaults.topP, original.sampling_defaults.top_p);
  assert.equal(m.portable.capacity, original.portable.capacity);
  assert.deepEqual(m.ort.variants, { int8_ort: 'int8', portable_ort: 'portable' });
});

test('every bad manifest of tests/golden/bad_manifests.json is refused with the file and the field named', () => {
  for (const [name, setup] of Object.entries(BAD.setups)) {   // a setup alone parses: the cases fail for their own edit
    assert.ok(parseManifest(edited(original, setup), 'bundle/manifest.json'), name);
  }
  for (const c of BAD.cases) {
    assert.throws(() => parseManifest(edited(original, [...(BAD.setups[c.with] ?? []), ...c.edit]), 'bundle/manifest.json'),
      (e) => e instanceof BundleError && e.message.startsWith('bundle/manifest.json: ') && e.message.includes(c.names),
      `${c.why}: expected a BundleError naming ${c.names}`);
  }
  console.log(`bad manifests: ${BAD.cases.length} cases of tests/golden/bad_manifests.json refused, each naming its field`);
});

test('a file that is not what the manifest records is refused when it is read', async () => {
  const loader = fileLoader(toy.path);
  const tampered = { where: toy.path, readBytes: async (name, most) => {
    const bytes = await loader.readBytes(name, most);
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
  const fetchFn = async (url) => {   // a stand-in for fetch, as web/worker.js passes one: no body stream, no headers
    const name = decodeURIComponent(url.slice('https://example.test/toy/'.length));
    try {
      const bytes = readFileSync(join(toy.path, name));
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
