// manifest.json, typed and checked as runtime/mogo_runtime/manifest.py does (docs/bundle.md, "manifest.json").
//
// Every field the runtime reads is checked (type, range, agreement between sections) and every failure names
// the file and the dotted field, so a broken or foreign bundle is refused before any graph is opened.
// `parseManifest` returns a frozen object with camelCase names for the JavaScript side.

import { SamplingConfig } from './sampling.js';
import { SKELETONS, featureLayout } from './skeleton.js';

export const SCHEMA = 'mogo-bundle';
export const SCHEMA_VERSION = 2;   // 2: cache-name templates; `normalization` an object; numbers stored as numbers
export const GRAPHS = ['text_encoder', 'step', 'lookup', 'decoder'];
export const DTYPES = ['float32', 'int64', 'float16'];
export const PER_ROW_INT8 = 'mogo.per_row_dynamic';   // one activation scale per row: batch-invariant int8
const NORMALIZATION = 'decoder-output-denormalised';   // decoder.onnx multiplies by Std and adds Mean itself
// name -> rank of each graph's fixed inputs and outputs (the step graph's cache names come from `cache`)
const GRAPH_IO = {
  text_encoder: [{ input_ids: 2, attention_mask: 2 }, { text_embedding: 2 }],
  step: [{ text_embedding: 2, tokens: 3 }, { logits: 4 }],
  lookup: [{ tokens: 3 }, { latent: 3 }],
  decoder: [{ latent: 3 }, { features: 3 }],
};
// the manifest's `model` section: snake_case name -> the name the JavaScript side uses
const MODEL_FIELDS = {
  num_levels: 'numLevels', codebook_size: 'codebookSize', n_layers: 'nLayers', n_heads: 'nHeads',
  head_dim: 'headDim', text_dim: 'textDim', max_rel_dist: 'maxRelDist', downsample: 'downsample', fps: 'fps',
  receptive_field: 'receptiveField', feature_dim: 'featureDim', latent_dim: 'latentDim', max_tokens: 'maxTokens',
};
const SHA256 = /^[0-9a-f]{64}$/;

/** A bundle that cannot be used: the message names the file and the field. */
export class BundleError extends Error {
  constructor(message) {
    super(message);
    this.name = 'BundleError';
  }
}

/** Typed reads from one JSON object; every failure names the file and the dotted field path. */
class Fields {
  constructor(obj, where, path = '') {
    this.where = where;
    this.path = path;
    if (obj === null || typeof obj !== 'object' || Array.isArray(obj)) {
      throw new BundleError(`${where}: ${path ? `field ${path}` : 'the manifest'}: must be a JSON object, got ${kind(obj)}`);
    }
    this.obj = obj;
  }

  name(key) {
    return [this.path, key].filter(Boolean).join('.');
  }

  fail(key, message) {
    throw new BundleError(`${this.where}: field ${this.name(key)}: ${message}`);
  }

  has(key) {
    return Object.hasOwn(this.obj, key);
  }

  get(key, fallback) {
    if (!this.has(key)) {
      if (fallback === undefined) this.fail(key, 'missing');
      return fallback;
    }
    return this.obj[key];
  }

  int(key, lo = 0, hi = 2 ** 31, fallback) {
    const v = this.get(key, fallback);
    if (typeof v !== 'number' || !Number.isInteger(v) || v < lo || v > hi) {
      this.fail(key, `expected an integer in [${lo}, ${hi}], got ${show(v)}`);
    }
    return v;
  }

  num(key, lo, hi) {
    const v = this.get(key);
    if (typeof v !== 'number' || !Number.isFinite(v) || !(v > lo && v <= hi)) {
      this.fail(key, `expected a number in (${lo}, ${hi}], got ${show(v)}`);
    }
    return v;
  }

  str(key, fallback) {
    const v = this.get(key, fallback);
    if (typeof v !== 'string' || !v) this.fail(key, `expected a non-empty string, got ${show(v)}`);
    return v;
  }

  sub(key) {
    return new Fields(this.get(key), this.where, this.name(key));
  }

  list(key) {
    const v = this.get(key);
    if (!Array.isArray(v)) this.fail(key, `expected a list, got ${kind(v)}`);
    return v;
  }
}

function kind(v) {
  if (v === null) return 'null';
  return Array.isArray(v) ? 'list' : typeof v;
}

function show(v) {
  return v === undefined ? 'nothing' : JSON.stringify(v);
}

/** Compare JSON values as JSON (object key order aside). */
function sameJson(a, b) {
  if (Array.isArray(a) || Array.isArray(b)) {
    return Array.isArray(a) && Array.isArray(b) && a.length === b.length && a.every((x, i) => sameJson(x, b[i]));
  }
  if (a !== null && b !== null && typeof a === 'object' && typeof b === 'object') {
    const keys = Object.keys(a);
    return keys.length === Object.keys(b).length && keys.every((k) => Object.hasOwn(b, k) && sameJson(a[k], b[k]));
  }
  return a === b;
}

/**
 * Check and type a manifest read from JSON.
 * @param {object} data the parsed manifest.json
 * @param {string} where the file, which starts every error message
 */
export function parseManifest(data, where) {
  const f = new Fields(data, where);
  if (f.get('schema', null) !== SCHEMA) {
    f.fail('schema', `is ${show(f.get('schema', null))}, expected "${SCHEMA}" (not a mogo bundle)`);
  }
  if (f.get('schema_version', null) !== SCHEMA_VERSION) {
    f.fail('schema_version', `is ${show(f.get('schema_version', null))}; this runtime reads version ${SCHEMA_VERSION} `
      + '(re-export the bundle with `mogo-export export`)');
  }
  const producer = f.get('producer', {});
  if (producer === null || typeof producer !== 'object' || Array.isArray(producer)) {
    f.fail('producer', `expected an object, got ${kind(producer)}`);
  }
  const model = parseModel(f.sub('model'));
  const skeleton = parseSkeleton(f.sub('skeleton'), f.sub('features'), model);
  const cache = parseCache(f.sub('cache'));
  const manifest = {
    producer,
    model,
    skeleton,
    layout: featureLayout(skeleton.parents.length),
    normalization: parseNormalization(f.sub('normalization'), model),
    textEncoder: parseTextEncoder(f.sub('text_encoder')),
    samplingDefaults: parseSampling(f.sub('sampling_defaults')),
    cache,
    pastNames: cacheNames(cache.past, model.nLayers),
    presentNames: cacheNames(cache.present, model.nLayers),
    files: parseFiles(f.sub('files')),
    graphs: Object.fromEntries(GRAPHS.map((g) => [g, parseGraph(f.sub('graphs').sub(g))])),
    variants: parseVariants(f.sub('variants')),
    tca: f.get('tca', null) === null ? null : f.sub('tca').obj,
    streaming: f.get('streaming', null) === null ? null : parseStreaming(f.sub('streaming'), model),
    portable: f.get('portable', null) === null ? null : parsePortable(f.sub('portable')),
    ort: f.get('ort', null) === null ? null : parseOrt(f.sub('ort')),
  };
  checkAgreement(manifest, where);
  return deepFreeze(manifest);
}

/** The portable variant's step graph (docs/bundle.md, "The portable variant"): a cache of `capacity` slots. */
function parsePortable(f) {
  const capacity = f.get('capacity', null);
  if (!Number.isInteger(capacity) || capacity < 1) f.fail('capacity', `expected an integer >= 1, got ${show(capacity)}`);
  return { capacity, opset: f.get('opset', null), step: parseGraph(f.sub('step')) };
}

/** ORT-format variants and the variant each was converted from. */
function parseOrt(f) {
  const variants = f.get('variants', null);
  if (variants === null || typeof variants !== 'object' || Array.isArray(variants)) {
    f.fail('variants', `expected an object, got ${kind(variants)}`);
  }
  return { variants: { ...variants }, requiredOperators: f.get('required_operators', null) };
}

/** The variant an ORT-format variant was converted from; any other variant is its own source. */
export function sourceVariant(manifest, variant) {
  return manifest.ort?.variants[variant] ?? variant;
}

/** Whether the variant's step graph is the portable one or its per-row int8 form (fixed-capacity cache, `position` input). */
export function fixedCache(manifest, variant) {
  return manifest.portable !== null && ['portable', 'int8_fixed'].includes(sourceVariant(manifest, variant));
}

/** The inputs and outputs a variant's graph has: the portable step's differ from `graphs.step`. */
export function graphSpec(manifest, graph, variant) {
  return graph === 'step' && fixedCache(manifest, variant) ? manifest.portable.step : manifest.graphs[graph];
}

/** The file and quantization of one graph of one variant; throws for an unknown variant. */
export function graphFile(manifest, graph, variant) {
  if (!Object.hasOwn(manifest.variants, variant)) {
    throw new BundleError(`unknown variant ${JSON.stringify(variant)}; this bundle has ${Object.keys(manifest.variants).join(', ')}`);
  }
  return manifest.variants[variant][graph];
}

/** The cache I/O names for n layers, key then value per layer: `past_key_values.{layer}.{kind}`. */
export function cacheNames(template, nLayers) {
  const names = [];
  for (let layer = 0; layer < nLayers; layer++) {
    for (const kindName of ['key', 'value']) names.push(formatTemplate(template, { layer, kind: kindName }));
  }
  return names;
}

/** Python's str.format for {layer} and {kind}; null for any other field (an unusable template). */
function formatTemplate(template, values) {
  let unknown = false;
  const out = template.replace(/\{([^{}]*)\}/g, (_, key) => {
    if (!Object.hasOwn(values, key)) unknown = true;
    return String(values[key]);
  });
  return unknown ? null : out;
}

function parseModel(f) {
  const model = {};
  for (const [key, name] of Object.entries(MODEL_FIELDS)) {
    model[name] = key === 'fps' ? f.num(key, 0, 1000) : f.int(key, key === 'receptive_field' ? 0 : 1);
  }
  const derived = { end_id: model.codebookSize, bos_id: model.codebookSize + 1, pad_id: model.codebookSize + 2,
    d_model: model.nHeads * model.headDim };
  for (const [key, want] of Object.entries(derived)) {
    if (f.get(key, want) !== want) f.fail(key, `is ${show(f.get(key))}, the other sizes imply ${want}`);
  }
  // special tokens past the codebook: codes 0..K-1, END = K ends the motion, BOS = K+1 the prompt prefix
  return { ...model, endId: derived.end_id, bosId: derived.bos_id, padId: derived.pad_id,
    maxSeconds: (model.maxTokens * model.downsample) / model.fps };
}

function parseSkeleton(f, features, model) {
  const name = f.str('name');
  if (!Object.hasOwn(SKELETONS, name)) {
    f.fail('name', `unknown skeleton ${JSON.stringify(name)}; this runtime knows ${Object.keys(SKELETONS).sort().join(', ')}`);
  }
  const skeleton = SKELETONS[name];
  for (const [key, want] of Object.entries(skeleton)) {
    if (!sameJson(f.get(key), want)) {
      f.fail(key, `differs from the ${JSON.stringify(name)} skeleton this runtime knows (${JSON.stringify(want).slice(0, 60)}...)`);
    }
  }
  const layout = featureLayout(skeleton.parents.length);
  if (!sameJson(features.obj, layout)) {
    features.fail('', `differs from the feature layout of the ${JSON.stringify(name)} skeleton this runtime knows`);
  }
  if (layout.dim !== model.featureDim) {
    f.fail('name', `${JSON.stringify(name)} has ${layout.dim} features per frame, model.feature_dim is ${model.featureDim}`);
  }
  return skeleton;
}

function parseNormalization(f, model) {
  if (f.str('mode') !== NORMALIZATION) f.fail('mode', `expected "${NORMALIZATION}", got ${show(f.get('mode'))}`);
  const stats = {};
  for (const key of ['mean', 'std']) {
    const v = f.list(key);
    if (v.length !== model.featureDim || !v.every((x) => typeof x === 'number' && Number.isFinite(x))) {
      f.fail(key, `expected ${model.featureDim} finite numbers`);
    }
    const least = Math.min(...v);
    // features are scaled by std: 0 flattens a feature, < 0 mirrors it
    if (key === 'std' && least <= 0) f.fail(key, `every value must be > 0, got ${least} at index ${v.indexOf(least)}`);
    stats[key] = Float64Array.from(v);
  }
  return stats;
}

function parseTextEncoder(f) {
  if (f.str('pooling', 'mean') !== 'mean') f.fail('pooling', `only mean pooling is supported, got ${show(f.get('pooling'))}`);
  return { name: f.str('name'), tokenizer: f.str('tokenizer'), maxLength: f.int('max_length', 2, 65536), pooling: 'mean' };
}

function parseSampling(f) {
  const unknown = Object.keys(f.obj).filter((k) => !['temperature', 'top_k', 'top_p', 'guidance'].includes(k));
  if (unknown.length) f.fail(unknown.sort()[0], 'unknown sampling setting');
  try {
    return SamplingConfig.fromManifest(f.obj);
  } catch (e) {
    throw new BundleError(`${f.where}: field ${f.path}: ${e.message}`);
  }
}

function parseCache(f) {
  const cache = { past: f.str('past'), present: f.str('present') };
  for (const key of ['past', 'present']) {
    const names = cacheNames(cache[key], 2);
    if (names.includes(null) || new Set(names).size !== 4 || formatTemplate(cache[key], { layer: 0, kind: 'key' }) === cache[key]) {
      f.fail(key, `a name template with {layer} and {kind} fields, got ${show(cache[key])}`);
    }
  }
  return cache;
}

function parseFiles(f) {
  const files = {};
  for (const name of Object.keys(f.obj)) {
    const entry = f.sub(name);
    // bundle files are plain names inside the bundle folder: no directories, no way out of it
    if (!name || name.includes('/') || name === '.' || name === '..' || name.includes('\\') || name.includes('\0')) {
      f.fail(name, 'a bundle file must be a plain file name inside the bundle folder');
    }
    const digest = entry.str('sha256');
    if (!SHA256.test(digest)) entry.fail('sha256', `expected 64 lowercase hex digits, got ${show(digest)}`);
    files[name] = { bytes: entry.int('bytes', 0, 2 ** 40), sha256: digest };
  }
  if (!Object.keys(files).length) f.fail('', 'lists no files');
  return files;
}

function parseGraph(f) {
  const graph = {};
  for (const kindName of ['inputs', 'outputs']) {
    const specs = f.list(kindName).map((d, i) => parseTensor(new Fields(d, f.where, `${f.path}.${kindName}[${i}]`)));
    const names = specs.map((s) => s.name);
    if (!specs.length || new Set(names).size !== names.length) {
      f.fail(kindName, `expected a non-empty list of distinct names, got ${JSON.stringify(names)}`);
    }
    graph[kindName] = specs;
  }
  return graph;
}

function parseTensor(f) {
  const dtype = f.str('dtype');
  const shape = f.list('shape');
  if (!DTYPES.includes(dtype)) f.fail('dtype', `expected one of ${DTYPES.join(', ')}, got ${show(dtype)}`);
  if (shape.length > 8 || !shape.every((d) => typeof d === 'string' || (Number.isInteger(d) && d >= 1))) {
    f.fail('shape', `expected at most 8 dims, each a name or an integer >= 1, got ${JSON.stringify(shape)}`);
  }
  return { name: f.str('name'), dtype, shape };
}

function parseVariants(f) {
  if (!f.has('fp32')) f.fail('fp32', 'missing: every bundle has the fp32 variant');
  const variants = {};
  for (const v of Object.keys(f.obj)) {
    const graphs = f.sub(v);
    variants[v] = {};
    for (const g of GRAPHS) {
      const e = graphs.sub(g);
      const q = e.get('quantization', null);
      if (q !== null && (typeof q !== 'object' || Array.isArray(q))) e.fail('quantization', `expected an object or null, got ${kind(q)}`);
      const quantization = q && Object.keys(q).length ? q : null;
      // a quantized graph runs one row per call (docs/bundle.md, the generation loop, step 3)
      variants[v][g] = { file: e.str('file'), quantization, quantized: quantization !== null };
    }
  }
  return variants;
}

function parseStreaming(f, model) {
  const spec = { window: f.int('window', 1), refresh: f.int('refresh', 1) };
  if (spec.window + spec.refresh > model.maxRelDist) {   // as trained: every distance to the prefix is distinct
    f.fail('refresh', `window + refresh is ${spec.window + spec.refresh}, more than model.max_rel_dist ${model.maxRelDist}`);
  }
  return spec;
}

/** Agreement between sections: files named by variants are listed, the step graph's I/O is the cache. */
function checkAgreement(m, where) {
  for (const [v, graphs] of Object.entries(m.variants)) {
    for (const [g, entry] of Object.entries(graphs)) {
      if (!Object.hasOwn(m.files, entry.file)) {
        throw new BundleError(`${where}: field variants.${v}.${g}.file: ${JSON.stringify(entry.file)} is not in 'files'`);
      }
    }
  }
  for (const name of [m.textEncoder.tokenizer, ...(m.tca ? [m.tca.file] : [])]) {
    if (!Object.hasOwn(m.files, name)) {
      throw new BundleError(`${where}: ${JSON.stringify(name)} is named by the manifest but not listed in 'files'`);
    }
  }
  for (const [graph, [inputs, outputs]] of Object.entries(GRAPH_IO)) {
    const cache = graph === 'step';
    const wants = [['inputs', { ...inputs, ...(cache ? ranks(m.pastNames) : {}) }],
      ['outputs', { ...outputs, ...(cache ? ranks(m.presentNames) : {}) }]];
    for (const [kindName, want] of wants) {
      const got = Object.fromEntries(m.graphs[graph][kindName].map((s) => [s.name, s.shape.length]));
      if (!sameJson(Object.keys(got), Object.keys(want)) || !sameJson(got, want)) {
        throw new BundleError(`${where}: field graphs.${graph}.${kindName}: names and ranks are ${JSON.stringify(got)}, `
          + `expected ${JSON.stringify(want)}${cache ? ' (n_layers and the cache templates)' : ''}`);
      }
    }
  }
  const logits = m.graphs.step.outputs[0].shape;
  if (logits.length !== 4 || logits[2] !== m.model.numLevels || logits[3] !== m.model.codebookSize + 1) {
    throw new BundleError(`${where}: field graphs.step.outputs[0].shape: ${JSON.stringify(logits)} should end in `
      + `[${m.model.numLevels}, ${m.model.codebookSize + 1}] (levels, codes + END)`);
  }
}

function ranks(names) {
  return Object.fromEntries(names.map((n) => [n, 4]));
}

function deepFreeze(obj) {
  if (obj && typeof obj === 'object' && !ArrayBuffer.isView(obj) && !Object.isFrozen(obj)) {
    Object.freeze(obj);
    for (const v of Object.values(obj)) deepFreeze(v);
  }
  return obj;
}
