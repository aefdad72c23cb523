// manifest.json, typed and checked as runtime/mogo_runtime/bundle/manifest.py does (docs/bundle.md, "manifest.json"):
// the sections (sections.js) in Python's order, then their agreement, so a broken or foreign bundle is refused,
// with the file and the dotted field named, before any graph is opened. `parseManifest` returns a frozen object.

import { shown } from '../checks.js';
import { featureLayout } from '../kinematics/features.js';
import { SKELETONS, storedSkeleton } from '../kinematics/skeleton.js';
import {
  BATCH_INVARIANT, Fields, PER_ROW_INT8, WEIGHT_INT8, cacheNames, kind, parseCache, parseFiles, parseGraph, parseModel,
  parseControl, parseNormalization, parseOrt, parsePortable, parseSampling, parseStreaming, parseTca, parseTextEncoder,
  parseVariants, presentGraphs, sameJson,
} from './sections.js';

export const SCHEMA = 'mogo-bundle';
export const SCHEMA_VERSION = 2;   // 2: cache-name templates; `normalization` an object; numbers stored as numbers
// name -> rank of each graph's fixed inputs and outputs (the step graph's cache names come from `cache`)
const GRAPH_IO = {
  text_encoder: [{ input_ids: 2, attention_mask: 2 }, { text_embedding: 2 }],
  step: [{ text_embedding: 2, tokens: 3 }, { logits: 4 }],
  lookup: [{ tokens: 3 }, { latent: 3 }],
  decoder: [{ latent: 3 }, { features: 3 }],
};
const DECODER_STATE = ['decoder_state.', 'next_decoder_state.'];   // decoder_step's state inputs and outputs + i
const ORT_SUFFIX = '.ort';          // graph files in onnxruntime's ORT format (section `ort`)
const PORTABLE = 'portable';        // the variant whose step graph has a fixed-capacity cache (section `portable`)
const INT8_FIXED = 'int8_fixed';    // the same step graph in per-row int8: batch-invariant
const COMPACT = 'compact';          // the portable variant with int8-stored weights and float32 arithmetic (WEIGHT_INT8)
const FIXED_CACHE = [PORTABLE, INT8_FIXED, COMPACT];   // the variants whose step graph is the portable one (in some form)

/**
 * Check and type a manifest read from JSON.
 * @param {object} data the parsed manifest.json
 * @param {string} where the file, which starts every error message
 */
export function parseManifest(data, where) {
  const f = new Fields(data, where);
  if (f.get('schema', null) !== SCHEMA) {
    f.fail('schema', `is ${shown(f.get('schema', null))}, expected "${SCHEMA}" (not a mogo bundle)`);
  }
  if (f.get('schema_version', null) !== SCHEMA_VERSION) {
    f.fail('schema_version', `is ${shown(f.get('schema_version', null))}; this runtime reads version `
      + `${SCHEMA_VERSION} (re-export the bundle with \`mogo-export export\`)`);
  }
  const producer = f.get('producer', {});
  if (kind(producer) !== 'object') f.fail('producer', `expected an object, got ${kind(producer)}`);
  const model = parseModel(f.sub('model'));
  const streaming = f.optional('streaming', (s) => parseStreaming(s, model));
  const m = {
    producer, model, streaming,
    skeleton: parseSkeleton(f.sub('skeleton'), f.sub('features'), model),
    normalization: parseNormalization(f.sub('normalization'), model),
    textEncoder: parseTextEncoder(f.sub('text_encoder')),
    samplingDefaults: parseSampling(f.sub('sampling_defaults')),
    cache: parseCache(f.sub('cache')),
    files: parseFiles(f.sub('files')),
    graphs: Object.fromEntries(presentGraphs(f.get('graphs')).map((g) => [g, parseGraph(f.sub('graphs').sub(g))])),
    variants: parseVariants(f.sub('variants')),
    tca: f.optional('tca', (s) => parseTca(s, model)),
    ort: f.optional('ort', parseOrt),
    portable: f.optional('portable', (s) => parsePortable(s, model, streaming)),
    control: f.optional('control', parseControl),
  };
  for (const [io, more] of [['inputs', m.control ? 3 : 2], ['outputs', 1]]) {   // before n_layers' cache names are built (2**31 of them?)
    const n = m.graphs.step[io].length, want = more + 2 * model.nLayers;
    if (n !== want) {
      f.fail(`graphs.step.${io}`, `${n} tensors; model.n_layers ${model.nLayers} makes ${want} (a key and value each)`);
    }
  }
  m.pastNames = cacheNames(m.cache.past, model.nLayers);
  m.presentNames = cacheNames(m.cache.present, model.nLayers);
  checkAgreement(m, f);
  checkDecoderStep(m, f);
  checkFixedCache(m, f);
  checkOrt(m, f);
  return deepFreeze(m);
}

/**
 * Whether the variant's step graph is the portable one, its per-row int8 or its compact form (fixed-capacity cache,
 * `position`), or an ORT-format variant converted from one.
 */
export const fixedCache = (manifest, variant) => FIXED_CACHE.includes(manifest.ort?.variants[variant] ?? variant);

/** The graphs this bundle has (in every variant): GRAPHS, and the optional ones it has. */
export const graphNames = (manifest) => presentGraphs(manifest.graphs);

/** decoder_step's state, [reach, channels] per input (zeros at a motion's start); null: no decoder_step. */
export const decoderState = (manifest) => manifest.graphs.decoder_step?.inputs.slice(1).map((s) => s.shape.slice(1)) ?? null;

/** The graphs that run one row per call: those quantized per tensor, whose rows would depend on each other. */
export const rowByRow = (manifest, variant) => new Set(graphNames(manifest).filter((g) => manifest.variants[variant][g].quantized
  && !BATCH_INVARIANT.includes(manifest.variants[variant][g].quantization.method)));

/** The inputs and outputs a variant's graph has: the portable step's differ from `graphs.step`. */
export function graphSpec(manifest, graph, variant) {
  return graph === 'step' && fixedCache(manifest, variant) ? manifest.portable.step : manifest.graphs[graph];
}

/** The skeleton must be one this runtime knows, stored exactly: the joints code relies on its tables. */
function parseSkeleton(f, features, model) {
  const name = f.str('name');
  if (!Object.hasOwn(SKELETONS, name)) {
    f.fail('name', `unknown skeleton ${shown(name)}; this runtime knows ${Object.keys(SKELETONS).sort().join(', ')}`);
  }
  for (const [key, want] of Object.entries(storedSkeleton(SKELETONS[name]))) {
    if (!sameJson(f.get(key), want)) {
      f.fail(key, `differs from the ${JSON.stringify(name)} skeleton this runtime knows (${JSON.stringify(want).slice(0, 60)}...)`);
    }
  }
  const layout = featureLayout(SKELETONS[name].parents.length);
  if (!sameJson(features.obj, layout)) {
    features.fail('', `differs from the feature layout of the ${JSON.stringify(name)} skeleton this runtime knows`);
  }
  if (layout.dim !== model.featureDim) {
    f.fail('name', `${JSON.stringify(name)} has ${layout.dim} features per frame, model.feature_dim is ${model.featureDim}`);
  }
  return SKELETONS[name];
}

const each = (names, value) => Object.fromEntries(names.map((n) => [n, value]));

/** Files named by variants and sections are listed; each graph's I/O names and ranks; the step's I/O is the cache. */
function checkAgreement(m, f) {
  const names = graphNames(m);
  for (const [v, graphs] of Object.entries(m.variants)) {
    const odd = [...new Set([...Object.keys(graphs), ...names])].filter((g) => !Object.hasOwn(graphs, g) || !names.includes(g)).sort()[0];
    if (odd !== undefined) {
      f.fail(`variants.${v}.${odd}`, Object.hasOwn(graphs, odd) ? "the bundle's 'graphs' section does not describe this graph"
        : "missing: every variant has each graph the 'graphs' section describes");
    }
    for (const [g, { file }] of Object.entries(graphs)) {
      if (!Object.hasOwn(m.files, file)) f.fail(`variants.${v}.${g}.file`, `${shown(file)} is not in 'files'`);
    }
  }
  const named = { 'text_encoder.tokenizer': m.textEncoder.tokenizer, 'tca.file': m.tca?.file,
    'ort.required_operators': m.ort?.requiredOperators };
  for (const [field, name] of Object.entries(named)) {
    if (name !== undefined && !Object.hasOwn(m.files, name)) {
      f.fail(field, `${shown(name)} is named by the manifest but not listed in 'files'`);
    }
  }
  for (const [graph, [inputs, outputs]] of Object.entries(GRAPH_IO)) {
    const step = graph === 'step', control = step && m.control ? { control: 3 } : {};
    for (const [io, want] of [['inputs', { ...inputs, ...control, ...each(step ? m.pastNames : [], 4) }],
      ['outputs', { ...outputs, ...each(step ? m.presentNames : [], 4) }]]) {
      const got = Object.fromEntries(m.graphs[graph][io].map((s) => [s.name, s.shape.length]));
      if (!sameJson(Object.keys(got), Object.keys(want)) || !sameJson(got, want)) {
        f.fail(`graphs.${graph}.${io}`, `names and ranks are ${shown(got, 200)}, expected ${shown(want, 200)}`
          + `${step ? ' (n_layers and the cache templates)' : ''}`);
      }
    }
  }
  const control = m.graphs.step.inputs[2];
  if (m.control && (control.dtype !== 'float32' || control.shape[2] !== m.control.dim)) {
    f.fail('graphs.step.inputs[2]', `'control' is ${control.dtype} ${shown(control.shape)}, expected float32 [batch, steps, `
      + `${m.control.dim}] (control.dim)`);
  }
  const logits = m.graphs.step.outputs[0].shape, { numLevels: L, codebookSize: K } = m.model;
  if (logits.length !== 4 || logits[2] !== L || logits[3] !== K + 1) {
    f.fail('graphs.step.outputs[0].shape', `${shown(logits)} should end in [${L}, ${K + 1}] (levels, codes + END)`);
  }
}

/**
 * decoder_step: latent, then its state inputs decoder_state.0, 1, ...; features, then next_decoder_state.i of the same
 * fixed shapes [batch, reach, channels]: what a consumer allocates, zeros, for a new motion.
 */
function checkDecoderStep(m, f) {
  const spec = m.graphs.decoder_step;
  if (!spec) return;
  const n = spec.inputs.length - 1;
  const names = { inputs: ['latent', ...Array.from({ length: n }, (_, i) => `${DECODER_STATE[0]}${i}`)],
    outputs: ['features', ...Array.from({ length: n }, (_, i) => `${DECODER_STATE[1]}${i}`)] };
  for (const [io, want] of Object.entries(names)) {
    const got = spec[io].map((s) => s.name);
    if (!sameJson(got, want) || n < 1) {
      f.fail(`graphs.decoder_step.${io}`, `names are ${shown(got, 200)}, expected ${shown(want, 200)} (at least one state)`);
    }
  }
  const { latentDim, featureDim } = m.model;
  if (!spec.inputs.every((s) => s.shape.length === 3) || spec.inputs[0].shape[2] !== latentDim) {
    f.fail('graphs.decoder_step.inputs', `latent is [batch, tokens, ${latentDim}] and each state [batch, reach, channels]`);
  }
  spec.inputs.slice(1).forEach((sIn, i) => {
    const sOut = spec.outputs[i + 1], dims = sIn.shape.slice(1);
    if (sIn.dtype !== 'float32' || !dims.every((d) => Number.isInteger(d) && d >= 1 && d <= 4096)
      || !sameJson(sOut.shape, sIn.shape) || sOut.dtype !== sIn.dtype) {
      f.fail(`graphs.decoder_step.inputs[${i + 1}]`, `${shown(sIn.name)} is ${sIn.dtype} ${shown(sIn.shape)} and its output `
        + `${shown(sOut.shape)}; expected float32 [batch, reach, channels] with fixed sizes 1..4096, the same both ways`);
    }
  });
  const features = spec.outputs[0].shape;
  if (features.length !== 3 || features[2] !== featureDim) {
    f.fail('graphs.decoder_step.outputs[0]', `features is ${shown(features)}, expected [batch, frames, ${featureDim}]`);
  }
}

/** The portable section and the portable variant come together; the step's I/O is the fixed cache. */
function checkFixedCache(m, f) {
  const has = (v) => Object.hasOwn(m.variants, v);
  if ((m.portable === null) === has(PORTABLE)) {
    f.fail('portable', m.portable ? "the bundle has no 'portable' variant for it to describe"
      : "missing: variant 'portable' needs this section (its step graph's inputs, outputs and capacity)");
  }
  for (const v of [INT8_FIXED, COMPACT]) {
    if (has(v) && !has(PORTABLE)) f.fail(`variants.${v}`, `comes with variant "${PORTABLE}", whose section 'portable' describes its step graph`);
  }
  if (m.portable === null) return;
  const quantized = graphNames(m).find((g) => m.variants[PORTABLE][g].quantized);
  if (quantized) f.fail(`variants.${PORTABLE}.${quantized}.quantization`, 'the portable variant is fp32 only (no int8 operators)');
  const fixedStep = has(INT8_FIXED) ? m.variants[INT8_FIXED].step : null;
  if (fixedStep && fixedStep.quantization?.method !== PER_ROW_INT8) {
    f.fail(`variants.${INT8_FIXED}.step.quantization`, `its step graph is the portable step quantized per row (method `
      + `"${PER_ROW_INT8}"), got ${shown(fixedStep.quantization)}`);
  }
  for (const g of has(COMPACT) ? graphNames(m) : []) {
    const q = m.variants[COMPACT][g].quantization;
    if (q?.method !== WEIGHT_INT8) {
      f.fail(`variants.${COMPACT}.${g}.quantization`, 'every graph of the compact variant stores its weights in int8 '
        + `(method "${WEIGHT_INT8}"), got ${shown(q)}`);
    }
  }
  const { numLevels: L, nHeads, headDim, textDim, codebookSize: K } = m.model;
  const cache = ['float32', [L * nHeads, m.portable.capacity, headDim]];
  const want = {
    inputs: { text_embedding: ['float32', [textDim]], tokens: ['int64', [1, L]],
      ...(m.control ? { control: ['float32', [1, m.control.dim]] } : {}), position: ['int64', []], ...each(m.pastNames, cache) },
    outputs: { logits: ['float32', [1, L, K + 1]], ...each(m.presentNames, cache) },
  };
  for (const [io, expected] of Object.entries(want)) {
    const specs = m.portable.step[io], names = specs.map((s) => s.name);
    if (!sameJson(names, Object.keys(expected))) {
      f.fail(`portable.step.${io}`, `names are ${shown(names, 200)}, expected ${shown(Object.keys(expected), 200)} `
        + '(n_layers and the cache templates)');
    }
    specs.forEach(({ name, dtype, shape }, i) => {
      // every dim but the batch is fixed: a consumer allocates the cache once, from these numbers
      if (dtype !== expected[name][0] || !sameJson(shape.slice(1), expected[name][1])) {
        f.fail(`portable.step.${io}[${i}]`, `${shown(name)} is ${dtype} ${shown(shape)}, expected ${expected[name][0]} `
          + `[${['batch', ...expected[name][1]].join(', ')}]`);
      }
    });
  }
}

/** ORT-format variants: each listed with its source, every file an .ort, quantized as its source. */
function checkOrt(m, f) {
  const ort = m.ort?.variants ?? {}, has = (v) => Object.hasOwn(m.variants, v);
  for (const [v, graphs] of Object.entries(m.variants)) {
    const inOrt = Object.values(graphs).map((e) => e.file.endsWith(ORT_SUFFIX)), any = inOrt.includes(true);
    if (any !== Object.hasOwn(ort, v) || any !== !inOrt.includes(false)) {
      f.fail(`variants.${v}`, Object.hasOwn(ort, v) ? `an ORT-format variant has only ${ORT_SUFFIX} files`
        : `${ORT_SUFFIX} files belong to variants listed in ort.variants with their source`);
    }
  }
  for (const [v, source] of Object.entries(ort)) {
    if (!has(v) || !has(source) || Object.hasOwn(ort, source)) {
      f.fail(`ort.variants.${v}`, `${shown(v)} converted from ${shown(source)}: both must be variants, the source not itself in ORT format`);
    }
    for (const g of graphNames(m)) {
      if (!sameJson(m.variants[v][g].quantization, m.variants[source][g].quantization)) {
        f.fail(`variants.${v}.${g}.quantization`, `differs from variant ${shown(source)}, which it was converted from`);
      }
    }
  }
}

function deepFreeze(obj) {
  if (obj && typeof obj === 'object' && !ArrayBuffer.isView(obj) && !Object.isFrozen(obj)) {
    Object.freeze(obj);
    for (const v of Object.values(obj)) deepFreeze(v);
  }
  return obj;
}
