// The manifest's sections, typed: one parser per section, checking every field it reads and naming the file and
// the dotted field when one is wrong (runtime/mogo_runtime/bundle/sections.py; docs/bundle.md, "manifest.json").
// manifest.js puts them together and checks that they agree. Sections come back as plain objects, camelCase.

import { oneLine, shown } from '../checks.js';
import { SamplingConfig } from './sampling.js';

export const GRAPHS = ['text_encoder', 'step', 'lookup', 'decoder'];   // every bundle's
// graphs a bundle may have, in every variant or none: the decoder with its causal state explicit (docs/bundle.md)
export const OPTIONAL_GRAPHS = ['decoder_step'];
export const DECODING_GRAPHS = ['lookup', 'decoder', 'decoder_step'];   // tokens -> frames: all a decode-only client opens
/** The graphs a `graphs` (or variant) object names: GRAPHS, and the optional ones it has. */
export const presentGraphs = (obj) => [...GRAPHS, ...OPTIONAL_GRAPHS.filter((g) => kind(obj) === 'object' && Object.hasOwn(obj, g))];
export const DTYPES = ['float32', 'int64', 'float16'];
export const PER_ROW_INT8 = 'mogo.per_row_dynamic';   // int8 with one activation scale per row: batchable
export const WEIGHT_INT8 = 'mogo.weight_only_int8';   // int8 weights turned back to float32 in the graph, float32 arithmetic
export const BATCH_INVARIANT = [PER_ROW_INT8, WEIGHT_INT8];   // methods whose rows never depend on the rest of their batch
export const PORTABLE_OPSET = 17;   // the portable variant's graphs' opset: this or lower (LayerNormalization's first)
const NORMALIZATION = 'decoder-output-denormalised';   // decoder.onnx multiplies by Std and adds Mean itself
const SHA256 = /^[0-9a-f]{64}$/;
const NAME_MAX = 255;   // bytes of one file name on the file systems a bundle lands on (ext4, APFS, NTFS)
// the `model` section: snake_case name -> the name the JavaScript side uses
const MODEL_FIELDS = {
  num_levels: 'numLevels', codebook_size: 'codebookSize', n_layers: 'nLayers', n_heads: 'nHeads',
  head_dim: 'headDim', text_dim: 'textDim', max_rel_dist: 'maxRelDist', downsample: 'downsample', fps: 'fps',
  receptive_field: 'receptiveField', feature_dim: 'featureDim', latent_dim: 'latentDim', max_tokens: 'maxTokens',
};

/** A bundle that cannot be used: the message names the file and the field. */
export class BundleError extends Error {
  name = 'BundleError';
}

/** Typed reads from one JSON object (checks.py Fields); every failure names the file and the dotted field. */
export class Fields {
  constructor(obj, where, path = '') {
    if (obj === null || typeof obj !== 'object' || Array.isArray(obj)) {
      throw new BundleError(`${where}${path ? `: field ${path}` : ''}: must be a JSON object, got ${kind(obj)}`);
    }
    Object.assign(this, { obj, where, path });
  }

  /** The dotted name of `key` (a key from the file: on one line, cut short). */
  name(key) { return [this.path, oneLine(key, 60)].filter(Boolean).join('.'); }

  fail(key, message) { throw new BundleError(`${this.where}: field ${this.name(key)}: ${message}`); }

  /** The value at `key`; missing: `fallback`, or a failure when there is none. */
  get(key, fallback) {
    if (Object.hasOwn(this.obj, key)) return this.obj[key];
    if (fallback === undefined) this.fail(key, 'missing');
    return fallback;
  }

  int(key, lo = 0, hi = 2 ** 31, fallback) {
    const v = this.get(key, fallback);
    if (!Number.isInteger(v) || v < lo || v > hi) this.fail(key, `expected an integer in [${lo}, ${hi}], got ${shown(v)}`);
    return v;
  }

  num(key, lo, hi) {
    const v = this.get(key);
    if (!Number.isFinite(v) || !(v > lo && v <= hi)) this.fail(key, `expected a number in (${lo}, ${hi}], got ${shown(v)}`);
    return v;
  }

  str(key, fallback) {
    const v = this.get(key, fallback);
    if (typeof v !== 'string' || !v) this.fail(key, `expected a non-empty string, got ${shown(v)}`);
    return v;
  }

  sub(key) { return new Fields(this.get(key), this.where, this.name(key)); }

  list(key) {
    const v = this.get(key);
    if (!Array.isArray(v)) this.fail(key, `expected a list, got ${kind(v)}`);
    return v;
  }

  /** The section at `key` through `parse`, or null where it is missing or null. */
  optional(key, parse) { return this.get(key, null) === null ? null : parse(this.sub(key)); }
}

export const kind = (v) => (v === null ? 'null' : Array.isArray(v) ? 'list' : typeof v);

/** JSON values compared as JSON (object key order aside). */
export function sameJson(a, b) {
  if (Array.isArray(a) || Array.isArray(b)) {
    return Array.isArray(a) && Array.isArray(b) && a.length === b.length && a.every((x, i) => sameJson(x, b[i]));
  }
  if (a !== null && b !== null && typeof a === 'object' && typeof b === 'object') {
    const keys = Object.keys(a);
    return keys.length === Object.keys(b).length && keys.every((k) => Object.hasOwn(b, k) && sameJson(a[k], b[k]));
  }
  return a === b;
}

/** The network's sizes; special tokens past the codebook: END = K ends the motion, BOS = K+1 the prompt prefix. */
export function parseModel(f) {
  const model = {};
  for (const [key, name] of Object.entries(MODEL_FIELDS)) {
    model[name] = key === 'fps' ? f.num(key, 0, 1000) : f.int(key, key === 'receptive_field' ? 0 : 1);
  }
  const K = model.codebookSize, derived = { end_id: K, bos_id: K + 1, pad_id: K + 2, d_model: model.nHeads * model.headDim };
  for (const [key, want] of Object.entries(derived)) {
    if (f.get(key, want) !== want) f.fail(key, `is ${shown(f.get(key))}, the other sizes imply ${want}`);
  }
  return { ...model, endId: K, bosId: K + 1, padId: K + 2, maxSeconds: (model.maxTokens * model.downsample) / model.fps };
}

/** A graph's inputs and outputs: {name, dtype, shape} each (every tensor read first, as Python), names distinct. */
export function parseGraph(f) {
  const graph = Object.fromEntries(['inputs', 'outputs'].map((io) => [io, f.list(io).map((d, i) => {
    const t = new Fields(d, f.where, `${f.path}.${io}[${i}]`), dtype = t.str('dtype'), shape = t.list('shape');
    if (!DTYPES.includes(dtype)) t.fail('dtype', `expected one of ${DTYPES.join(', ')}, got ${shown(dtype)}`);
    if (shape.length > 8 || !shape.every((n) => typeof n === 'string' || (Number.isInteger(n) && n >= 1))) {
      t.fail('shape', `expected at most 8 dims, each a name or an integer >= 1, got ${shown(shape)}`);
    }
    return { name: t.str('name'), dtype, shape };
  })]));
  for (const [io, specs] of Object.entries(graph)) {
    const names = specs.map((s) => s.name);
    if (!specs.length || new Set(names).size !== names.length) {
      f.fail(io, `expected a non-empty list of distinct names, got ${shown(names, 200)}`);
    }
  }
  return graph;
}

/** The cache I/O names for n layers, key then value per layer, e.g. `past_key_values.{layer}.{kind}`. */
export function cacheNames(template, nLayers) {
  return Array.from({ length: nLayers }, (_, layer) => ['key', 'value'].map(
    (kind) => formatTemplate(template, { layer, kind }))).flat();
}

/** Python's str.format for {layer} and {kind}; null for any other field (an unusable template). */
function formatTemplate(template, values) {
  let unknown = false;
  const out = template.replace(/\{([^{}]*)\}/g, (_, key) => {
    unknown ||= !Object.hasOwn(values, key);
    return String(values[key]);
  });
  return unknown ? null : out;
}

export function parseCache(f) {
  const cache = { past: f.str('past'), present: f.str('present') };
  for (const key of ['past', 'present']) {
    const names = cacheNames(cache[key], 2);
    if (names.includes(null) || new Set(names).size !== 4 || formatTemplate(cache[key], { layer: 0, kind: 'key' }) === cache[key]) {
      f.fail(key, `a name template with {layer} and {kind} fields, got ${shown(cache[key])}`);
    }
  }
  return cache;
}

export function parseTextEncoder(f) {
  if (f.str('pooling', 'mean') !== 'mean') f.fail('pooling', `only mean pooling is supported, got ${shown(f.get('pooling'))}`);
  return { name: f.str('name'), tokenizer: f.str('tokenizer'), maxLength: f.int('max_length', 2, 65536), pooling: 'mean' };
}

/** Listed for reference (mode NORMALIZATION: the decoder applies them itself). */
export function parseNormalization(f, model) {
  if (f.str('mode') !== NORMALIZATION) f.fail('mode', `expected "${NORMALIZATION}", got ${shown(f.get('mode'))}`);
  const stats = {};
  for (const key of ['mean', 'std']) {
    const v = f.list(key);
    if (v.length !== model.featureDim || !v.every(Number.isFinite)) f.fail(key, `expected ${model.featureDim} finite numbers`);
    const least = Math.min(...v);
    // features are scaled by std: 0 flattens a feature, < 0 mirrors it
    if (key === 'std' && least <= 0) f.fail(key, `every value must be > 0, got ${least} at index ${v.indexOf(least)}`);
    stats[key] = Float64Array.from(v);
  }
  return stats;
}

/** The context of endless streams the model was trained for (docs/bundle.md, "Endless streams"). */
export function parseStreaming(f, model) {
  const spec = { window: f.int('window', 1), refresh: f.int('refresh', 1) };
  if (spec.window + spec.refresh > model.maxRelDist) {   // as trained: every distance to the prefix is distinct
    f.fail('refresh', `window + refresh is ${spec.window + spec.refresh}, more than model.max_rel_dist ${model.maxRelDist}`);
  }
  return spec;
}

/**
 * The `control` section: the step graph's control input, where the character should go (bundle/sections.py
 * ControlSpec; runtime/mogo_runtime/control/vector.py): the wanted root of the next `horizon` tokens.
 */
export function parseControl(f) {
  const spec = { horizon: f.int('horizon', 1, 64), dim: f.int('dim', 1, 1 + 4 * 64) };
  if (spec.dim !== 1 + 4 * spec.horizon) {
    f.fail('dim', `is ${spec.dim}; a horizon of ${spec.horizon} tokens makes ${1 + 4 * spec.horizon} (present, then x, z, `
      + 'sin, cos per token)');
  }
  return spec;
}

/**
 * Cache slots the loop can fill: a clip's BOS and max_tokens (one spare: a consumer may feed its last pick too),
 * an endless stream's BOS and window + refresh.
 */
export const requiredCapacity = (model, streaming) => Math.max(model.maxTokens + 1,
  streaming ? 1 + streaming.window + streaming.refresh : 0);

/** The portable variant's step graph (docs/bundle.md, "The portable variant"): a cache of `capacity` slots. */
export function parsePortable(f, model, streaming) {
  const need = requiredCapacity(model, streaming), capacity = f.get('capacity');
  if (Number.isInteger(capacity) && capacity >= 1 && capacity < need) {
    f.fail('capacity', `is ${capacity}; the generation loop can hold ${need} steps `
      + '(max(max_tokens + 1, 1 + streaming window + refresh))');
  }
  return { capacity: f.int('capacity', need), opset: f.int('opset', 7, PORTABLE_OPSET), step: parseGraph(f.sub('step')) };
}

/** Variants in onnxruntime's ORT format (ORT variant -> the variant it was converted from) and their operators. */
export function parseOrt(f) {
  const variants = f.sub('variants');
  if (!Object.keys(variants.obj).length) f.fail('variants', 'expected at least one ORT-format variant');
  const requiredOperators = f.str('required_operators');
  const sources = Object.fromEntries(Object.keys(variants.obj).map((v) => [v, variants.str(v)]));
  return { requiredOperators, variants: sources, onnxruntime: f.str('onnxruntime') };
}

/** The caption index of text condition alignment (docs/tca.md); keys nothing reads are ignored, as in Python. */
export function parseTca(f, model) {
  const defaults = { lexical_weight: 0.05, split_margin: 0.02 };
  for (const [key, fallback] of Object.entries(defaults)) {
    const v = f.get(key, fallback);
    if (typeof v !== 'number' || !(v >= 0 && v <= 1)) f.fail(key, `expected a number in [0, 1], got ${shown(v)}`);
  }
  if (!['int8', 'float16'].includes(f.get('dtype'))) f.fail('dtype', `expected "int8" or "float16", got ${shown(f.get('dtype'))}`);
  if (f.get('dim') !== model.textDim) f.fail('dim', `is ${shown(f.get('dim'))}, model.text_dim is ${model.textDim}`);
  if (typeof f.get('labels') !== 'boolean') f.fail('labels', `expected true or false, got ${shown(f.get('labels'))}`);
  return {
    file: f.str('file'), count: f.int('count', 1), dim: model.textDim, dtype: f.get('dtype'), encoder: f.str('encoder'),
    labels: f.get('labels'), split: f.str('split', 'train'),
    lexicalWeight: f.get('lexical_weight', defaults.lexical_weight), splitMargin: f.get('split_margin', defaults.split_margin),
  };
}

export function parseSampling(f) {
  const unknown = Object.keys(f.obj).filter((k) => !['temperature', 'top_k', 'top_p', 'guidance'].includes(k));
  if (unknown.length) f.fail(unknown.sort()[0], 'unknown sampling setting');
  try {
    return SamplingConfig.fromManifest(f.obj);
  } catch (e) {
    throw new BundleError(`${f.where}: field ${f.path}: ${e.message}`);
  }
}

/** name -> {bytes, sha256}; bundle files are plain names inside the bundle folder: no directories, no way out. */
export function parseFiles(f) {
  const files = {};
  for (const name of Object.keys(f.obj)) {
    const entry = f.sub(name);
    if (!name || name.includes('/') || name === '.' || name === '..' || name.includes('\\') || name.includes('\0')) {
      f.fail(name, 'a bundle file must be a plain file name inside the bundle folder');
    }
    if (new TextEncoder().encode(name).length > NAME_MAX) {
      f.fail(name, `a file name of more than ${NAME_MAX} bytes (no file system takes it)`);
    }
    const digest = entry.str('sha256');
    if (!SHA256.test(digest)) entry.fail('sha256', `expected 64 lowercase hex digits, got ${shown(digest)}`);
    files[name] = { bytes: entry.int('bytes', 0, 2 ** 40), sha256: digest };
  }
  if (!Object.keys(files).length) f.fail('', 'lists no files');
  return files;
}

/**
 * variant -> graph -> {file, quantization, quantized}. A quantization is {method, ...the exporter's options}:
 * `method` is what a reader acts on (the BATCH_INVARIANT methods run batched, any other one row per call:
 * docs/bundle.md).
 */
export function parseVariants(f) {
  if (!Object.hasOwn(f.obj, 'fp32')) f.fail('fp32', 'missing: every bundle has the fp32 variant');
  const variants = {};
  for (const v of Object.keys(f.obj)) {
    const graphs = f.sub(v);
    variants[v] = Object.fromEntries(presentGraphs(graphs.obj).map((g) => {
      const e = graphs.sub(g), q = e.get('quantization', null);
      if (q !== null && kind(q) !== 'object') e.fail('quantization', `expected an object or null, got ${kind(q)}`);
      const file = e.str('file'), quantized = q !== null && Object.keys(q).length > 0;
      if (quantized) e.sub('quantization').str('method');
      return [g, { file, quantization: quantized ? q : null, quantized }];
    }));
  }
  return variants;
}
