// The graphs of one bundle variant on onnxruntime: the backend the token loop drives, and its decoding half alone
// for a decode-only client (runtime/mogo_runtime/engine.py: MotionDecoder, OrtBackend and FixedCacheBackend).
//
// Arrays are flat typed arrays in row-major order with their shape given beside them. The KV cache is the
// list of `present.*` tensors a step returns, fed back as the next step's `past_key_values.*` as they are.
// Quantized graphs run one row (one prompt, one guidance branch) per call: dynamic int8 scales activations by
// the range of the whole input tensor, so in a batch a row's numbers would depend on its neighbours
// (docs/bundle.md, the generation loop, step 3). Their cache is then one list of tensors per row.

import { concat, createSession } from './bundle/io.js';
import { decoderState, fixedCache, graphNames, rowByRow } from './bundle/manifest.js';
import { BundleError, DECODING_GRAPHS } from './bundle/sections.js';
import { oneLine, shown } from './checks.js';
import { Tokenizer } from './tokenizer.js';

/** A graph returned NaN or inf: its bundle is broken, whatever the input. */
export class NonFiniteOutput extends BundleError {}

const MAX_THREADS = 64;
const TEXT_BATCH = 64;   // prompts per text-encoder call, as TextEncoderSession.encode

/**
 * The decoding half of a bundle variant: its codebook lookup and motion decoder, tokens in, features out
 * (engine.py MotionDecoder). All a client that only shows motion generated elsewhere needs (wire/client.js): it
 * reads no step graph, no text encoder and no tokenizer. A bundle with a decoder_step graph also decodes a stream's
 * new tokens from its decoder state (`decodeStep`; `decoderState` its shapes).
 */
export class MotionDecoder {
  /** The lookup and decoder sessions of `variant` of a Bundle on `ort` (onnxruntime-node or -web), each checked. */
  static async open(bundle, variant, { ort, threads = 1, providers }) {
    checkOpen(bundle, variant, threads);
    const graphs = DECODING_GRAPHS.filter((g) => graphNames(bundle.manifest).includes(g));
    const sessions = await openSessions(bundle, variant, graphs, { ort, threads, providers });
    return new MotionDecoder(ort, bundle.manifest, variant, sessions, rowByRow(bundle.manifest, variant));
  }

  /** `rowByRow`: the graphs that run one row per call (those quantized per tensor). */
  constructor(ort, manifest, variant, sessions, rowByRow) {
    Object.assign(this, { ort, manifest, dims: manifest.model, variant, sessions, rowByRow });
    this.decoderState = decoderState(manifest);   // null: streams decode windows of tokens
  }

  /** Codebook lookup + causal decoder: tokens (B, T, L), valid codes -> de-normalised features (B, T * ds, D). */
  async decode(tokens, batch) {
    if (!this.rowByRow.has('lookup') && !this.rowByRow.has('decoder')) return this.#decode(tokens, batch);
    const outs = [];
    for (let r = 0; r < batch; r++) outs.push(await this.#decode(rowOf(tokens, batch, r), 1));
    return concat(outs);
  }

  async #decode(tokens, batch) {
    const { features } = await runGraph(this, 'decoder', { latent: await this.#lookup(tokens, batch) });
    return this.#features('decoder', tokens, batch, features);
  }

  /** The codebook lookup: tokens (B, T, L) -> the decoders' input, a float32 tensor (B, T, latent_dim). */
  async #lookup(tokens, batch) {
    const L = this.dims.numLevels;
    const ids = new this.ort.Tensor('int64', BigInt64Array.from(tokens, BigInt), [batch, tokens.length / (batch * L), L]);
    const { latent } = await runGraph(this, 'lookup', { tokens: ids });
    finite(this, 'lookup', latent.data);
    return latent;
  }

  /** A decoder graph's output tensor for `tokens` (B, T, L), checked: (B, T * ds, D) flat, finite. */
  #features(graph, tokens, batch, features) {
    const T = tokens.length / (batch * this.dims.numLevels), want = [batch, T * this.dims.downsample, this.dims.featureDim];
    if (!sameDims(features.dims, want)) {   // a wrong model.downsample would drop or invent frames
      throw new BundleError(`${graphFile(this, graph)}: decoded ${T} tokens to `
        + `[${features.dims.slice(1)}] frames x features; manifest model.downsample ${this.dims.downsample} and `
        + `model.feature_dim ${this.dims.featureDim} promise [${want.slice(1)}]`);
    }
    return finite(this, graph, features.data);
  }

  /**
   * Streams' next tokens (B, T, L) from their decoder state (per state (B, reach, channels) float32, zeros at a
   * motion's start) -> {features (B, T * ds, D), state: the state after them} (engine.py decode_step).
   */
  async decodeStep(tokens, batch, state) {
    if (this.rowByRow.has('decoder_step') || this.rowByRow.has('lookup')) {
      const rows = [];
      for (let r = 0; r < batch; r++) rows.push(await this.decodeStep(rowOf(tokens, batch, r), 1, state.map((s) => rowOf(s, batch, r))));
      return { features: concat(rows.map((o) => o.features)), state: state.map((_, i) => concat(rows.map((o) => o.state[i]))) };
    }
    const feed = { latent: await this.#lookup(tokens, batch) };
    this.decoderState.forEach(([reach, channels], i) => {
      feed[`decoder_state.${i}`] = new this.ort.Tensor('float32', state[i], [batch, reach, channels]);
    });
    const out = await runGraph(this, 'decoder_step', feed);
    return { features: this.#features('decoder_step', tokens, batch, out.features),
      state: this.decoderState.map((_, i) => out[`next_decoder_state.${i}`].data) };
  }

  /** Free the sessions' native memory (the backend cannot be used afterwards). */
  async release() {
    for (const session of Object.values(this.sessions)) await session.release?.();
  }
}

export class OrtBackend extends MotionDecoder {
  /** The sessions of `variant` ('fp32', 'int8', ...) of a Bundle on `ort` (onnxruntime-node or -web), each checked. */
  static async open(bundle, variant, { ort, threads = 1, providers }) {
    const manifest = bundle.manifest;
    checkOpen(bundle, variant, threads);
    const tokenizerFile = manifest.textEncoder.tokenizer;
    const tokenizer = Tokenizer.fromText(await bundle.read(tokenizerFile), bundle.path(tokenizerFile));
    if (tokenizer.maxLength !== manifest.textEncoder.maxLength) {
      throw new BundleError(`${tokenizer.source}: cuts at ${tokenizer.maxLength} tokens; manifest text_encoder.max_length is `
        + `${manifest.textEncoder.maxLength}`);
    }
    const sessions = await openSessions(bundle, variant, graphNames(manifest), { ort, threads, providers });
    return new OrtBackend(ort, manifest, variant, tokenizer, sessions, rowByRow(manifest, variant));
  }

  /** `rowByRow`: the graphs that run one row per call (those quantized per tensor). */
  constructor(ort, manifest, variant, tokenizer, sessions, rowByRow) {
    super(ort, manifest, variant, sessions, rowByRow);
    this.tokenizer = tokenizer;
    this.control = manifest.control;   // the step graph's control input {horizon, dim}; null: none
    this.cacheHeads = this.dims.numLevels * this.dims.nHeads;   // past: [rows, L * n_heads, past, head_dim]
    // the portable variant: one time step per call into a cache of fixed capacity, written at `position`
    this.capacity = fixedCache(manifest, variant) ? manifest.portable.capacity : null;
  }

  /** Prompts -> (N, text_dim) float32 embeddings, 64 prompts per call (one per call when quantized). */
  async encodeText(texts) {
    const E = this.dims.textDim;
    const out = new Float32Array(texts.length * E);
    const size = this.rowByRow.has('text_encoder') ? 1 : TEXT_BATCH;
    for (let i = 0; i < texts.length; i += size) {
      const { inputIds, attentionMask, dims } = this.tokenizer.encodeBatch(texts.slice(i, i + size));
      const { text_embedding: emb } = await runGraph(this, 'text_encoder', {
        input_ids: new this.ort.Tensor('int64', inputIds, dims),
        attention_mask: new this.ort.Tensor('int64', attentionMask, dims),
      });
      if (!sameDims(emb.dims, [dims[0], E])) {
        throw new BundleError(`${graphFile(this, 'text_encoder')}: returned embeddings [${emb.dims}] for ${dims[0]} prompt(s); `
          + `manifest model.text_dim is ${E}`);
      }
      out.set(finite(this, 'text_encoder', emb.data), i * E);
    }
    return out;
  }

  /** The cache of `rows` rows before the first step: every past tensor empty. */
  emptyPast(rows) {
    if (this.capacity !== null) {   // one zero buffer serves every layer: the graph returns new tensors
      const zeros = new this.ort.Tensor('float32', new Float32Array(rows * this.cacheHeads * this.capacity * this.dims.headDim),
        [rows, this.cacheHeads, this.capacity, this.dims.headDim]);
      return { tensors: this.manifest.pastNames.map(() => zeros), length: 0 };
    }
    const one = (n) => {
      const empty = new this.ort.Tensor('float32', new Float32Array(0), [n, this.cacheHeads, 0, this.dims.headDim]);
      return this.manifest.pastNames.map(() => empty);
    };
    return this.rowByRow.has('step') ? Array.from({ length: rows }, () => one(1)) : one(rows);
  }

  /** The cache with slots first .. first + count - 1 moved to 1 .. count (an endless stream's compaction, endless.js):
   * new tensors, nothing after those slots (the fixed cache keeps its capacity and its length says what counts). */
  compact(past, first, count) {
    const move = (t, size) => moveSlots(this.ort, t, first, count, size);
    if (this.capacity !== null) return { tensors: past.tensors.map((t) => move(t, this.capacity)), length: 1 + count };
    if (this.rowByRow.has('step')) return past.map((row) => row.map((t) => move(t, 1 + count)));
    return past.map((t) => move(t, 1 + count));
  }

  /**
   * One step call: textEmb (rows, text_dim), tokens (rows, steps, L), past from emptyPast or the previous step,
   * control (rows, steps, control.dim) or null (see `controls`) -> {logits (rows, steps, L, K + 1), past}.
   */
  async step(textEmb, tokens, rows, past, control = null) {
    control = this.controls(tokens, rows, control);
    if (this.capacity !== null) return this.#fixedStep(textEmb, tokens, rows, past, control);
    if (!this.rowByRow.has('step')) return this.#step(textEmb, tokens, rows, past, null, control);
    const outs = [];
    for (let r = 0; r < rows; r++) {
      outs.push(await this.#step(rowOf(textEmb, rows, r), rowOf(tokens, rows, r), 1, past[r], null,
        control && rowOf(control, rows, r)));
    }
    return { logits: concat(outs.map((o) => o.logits)), past: outs.map((o) => o.past) };
  }

  /**
   * The control input of a step on `tokens` (rows, steps, L): `control` (rows, steps, control.dim) checked, zeros
   * ("no control") for null; null for a model without control, which takes none (engine.py `controls`).
   */
  controls(tokens, rows, control) {
    if (this.control === null) {
      if (control !== null) throw new Error("this bundle's model was trained without control (its manifest has no 'control' section)");
      return null;
    }
    const want = (tokens.length / this.dims.numLevels) * this.control.dim;
    if (control === null) return new Float32Array(want);
    if (!(control instanceof Float32Array) || control.length !== want) {
      throw new RangeError(`control must be float32 (${rows}, ${tokens.length / (rows * this.dims.numLevels)}, `
        + `${this.control.dim}) for the tokens fed, got ${control.length} values`);
    }
    return control;
  }

  async #step(textEmb, tokens, rows, past, position = null, control = null) {
    const { numLevels: L, codebookSize: K, headDim } = this.dims, steps = tokens.length / (rows * L);
    const feed = {
      text_embedding: new this.ort.Tensor('float32', textEmb, [rows, this.dims.textDim]),
      tokens: new this.ort.Tensor('int64', BigInt64Array.from(tokens, BigInt), [rows, steps, L]),
    };
    if (position !== null) feed.position = new this.ort.Tensor('int64', new BigInt64Array(rows).fill(BigInt(position)), [rows]);
    // a model with control reads where the character should go; all zeros: no control (control/vector.js)
    if (control !== null) feed.control = new this.ort.Tensor('float32', control, [rows, steps, this.control.dim]);
    this.manifest.pastNames.forEach((name, i) => { feed[name] = past[i]; });
    const out = await runGraph(this, 'step', feed), presents = this.manifest.presentNames.map((name) => out[name]);
    // What the graph returns is held to the manifest every step: a cache that grew by more than the steps fed (or
    // logits of another width) would be read wrongly, or fill the memory over minutes. The loop reads the last
    // position's logits: a graph may return only those. The fixed cache keeps its shape.
    const [n, returned, ...levels] = out.logits.dims, before = position ?? past[0].dims[2];
    const cache = [rows, this.cacheHeads, position === null ? before + steps : this.capacity, headDim];
    if (n !== rows || !(returned >= 1 && returned <= steps) || !sameDims(levels, [L, K + 1])
      || presents.some((p) => !sameDims(p.dims, cache))) {
      throw new BundleError(`${graphFile(this, 'step')}: returned logits [${out.logits.dims}] and a cache `
        + `[${presents[0].dims}] for ${steps} step(s) after ${before}; the manifest's model says [${rows}, ${steps}, ${L}, `
        + `${K + 1}] and [${cache}]`);
    }
    return { logits: finite(this, 'step', out.logits.data), past: presents };
  }

  /** The portable step: S tokens are S calls, each writing its slot; logits come back as (rows, S, L, K + 1). */
  async #fixedStep(textEmb, tokens, rows, past, control) {
    const L = this.dims.numLevels, S = tokens.length / (rows * L), V = this.dims.codebookSize + 1;
    if (past.length + S > this.capacity) {
      throw new RangeError(`the portable step's cache holds ${this.capacity} steps; ${past.length} are cached and ${S} `
        + "more were fed (the manifest's portable.capacity covers the generation loop)");
    }
    const logits = new Float32Array(rows * S * L * V);
    let cache = past.tensors;
    const C = this.control?.dim ?? 0;
    for (let s = 0; s < S; s++) {
      const ids = new Int32Array(rows * L), at = control && new Float32Array(rows * C);
      for (let r = 0; r < rows; r++) {
        ids.set(tokens.subarray((r * S + s) * L, (r * S + s + 1) * L), r * L);
        at?.set(control.subarray((r * S + s) * C, (r * S + s + 1) * C), r * C);
      }
      const out = await this.#step(textEmb, ids, rows, cache, past.length + s, at);
      for (let r = 0; r < rows; r++) logits.set(out.logits.subarray(r * L * V, (r + 1) * L * V), (r * S + s) * L * V);
      cache = out.past;
    }
    return { logits, past: { tensors: cache, length: past.length + S } };
  }
}

const sameDims = (dims, want) => dims.length === want.length && dims.every((d, i) => d === want[i]);

const rowOf = (array, rows, r) => array.slice((r * array.length) / rows, ((r + 1) * array.length) / rows);

/** A variant the bundle has, and a thread count onnxruntime is given. */
function checkOpen(bundle, variant, threads) {
  if (!Object.hasOwn(bundle.manifest.variants, variant)) {
    throw new BundleError(`unknown variant ${shown(variant)}; bundle ${oneLine(bundle.where)} has `
      + `${oneLine(Object.keys(bundle.manifest.variants).join(', '), 200)}`);
  }
  if (!Number.isInteger(threads) || threads < 1 || threads > MAX_THREADS) {
    throw new RangeError(`threads must be an int in [1, ${MAX_THREADS}], got ${threads}`);
  }
}

/** graph -> session, for `graphs` of the variant: each file read (size and hash checked), loaded and checked. */
async function openSessions(bundle, variant, graphs, { ort, threads, providers }) {
  const sessions = {};
  for (const graph of graphs) {
    const { file } = bundle.manifest.variants[variant][graph];
    const bytes = await bundle.read(file);
    try {
      sessions[graph] = await createSession(ort, bytes, { threads, providers });
    } catch (e) {
      throw new BundleError(`${bundle.path(file)}: onnxruntime cannot load it (${oneLine(e.message, 300)})`);
    }
    bundle.checkSession(graph, file, sessions[graph], variant);
  }
  return sessions;
}

const graphFile = (backend, graph) => oneLine(backend.manifest.variants[backend.variant][graph].file);

/**
 * The `graph` session of a backend run on `feed`. onnxruntime failing to (an output it cannot allocate, shapes that
 * do not fit) is a BundleError naming the graph, as the bundle's graphs are what is wrong (engine.py _run).
 */
async function runGraph(backend, graph, feed) {
  try {
    return await backend.sessions[graph].run(feed);
  } catch (e) {
    throw new BundleError(`${graphFile(backend, graph)}: onnxruntime could not run the ${graph} graph `
      + `(${oneLine(e.message, 300)}); the bundle is broken`);
  }
}

/** `data`, or a NonFiniteOutput naming the graph: NaN or inf must never reach a motion (as the Python engine). */
function finite(backend, graph, data) {
  let bad = 0;
  for (let i = 0; i < data.length; i++) if (!Number.isFinite(data[i])) bad++;
  if (bad) {
    throw new NonFiniteOutput(`${graphFile(backend, graph)}: the ${graph} graph produced NaN or inf (${bad} of `
      + `${data.length} values); the bundle is broken (its weights or its export)`);
  }
  return data;
}

/** A cache tensor [rows, heads, P, head_dim] as a new one of `size` slots: slot 0, then slots first .. first + count
 * - 1 at 1 .. count, then (a fixed cache) what the old one held after them. */
function moveSlots(ort, tensor, first, count, size) {
  const [R, H, P, D] = tensor.dims, src = tensor.data, out = new Float32Array(R * H * size * D);
  for (let rh = 0; rh < R * H; rh++) {
    const from = rh * P * D, to = rh * size * D;
    if (size === P) out.set(src.subarray(from, from + P * D), to);
    else out.set(src.subarray(from, from + D), to);
    out.set(src.subarray(from + first * D, from + (first + count) * D), to + D);
  }
  return new ort.Tensor('float32', out, [R, H, size, D]);
}
