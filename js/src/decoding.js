// The generation recipe, step for step as runtime/mogo_runtime/decoding.py. Per step the backend's transformer step
// emits the logits of every level for the next time step; the step policy (policy.js) picks the tokens; level 0
// choosing END stops a clip (`generateTokens`) or restarts an endless stream's prompt (endless.js). Frames come from
// the causal decoder, once at the end (`decodeTokens`) or as tokens arrive (`FrameMaker`): from the decoder's state
// (a bundle's decoder_step graph) or by decoding a window of the last receptive_field + 1 tokens, on which a frame
// alone depends; the same frames within float32 rounding.
//
// Tokens are Int32Array rows of L levels; logits (rows, steps, L, K + 1) float32 as onnxruntime returns them.

import { concat } from './bundle/io.js';
import { EndlessLoop } from './endless.js';
import { recoverFromRic } from './kinematics/features.js';
import { FootLock, FrameJoints } from './kinematics/frames.js';
import { StepPolicy, makeRngs } from './policy.js';

export const MAX_CHUNK = 1024;   // tokens per decode; more only delays frames (and the window is allocated up front)

/** Tokens per decode: an int in [1, MAX_CHUNK], else a RangeError (decoding.py check_chunk). */
export function checkChunk(chunk) {
  if (!Number.isInteger(chunk) || chunk < 1 || chunk > MAX_CHUNK) {
    throw new RangeError(`chunk must be an int in [1, ${MAX_CHUNK}], got ${chunk}`);
  }
  return chunk;
}

/**
 * Yields {picked (B, L), alive (B)} once per time step until every prompt has ended. alive[b] is 0 from the step
 * where prompt b chose END (its tokens that step are meaningless). With `fixedTokens` END is forbidden and every
 * prompt runs exactly that many steps.
 * @param {Float32Array} textEmb (B, text_dim)
 */
export async function* generateTokens(backend, textEmb, sampling, rngs, maxTokens, fixedTokens = null) {
  const dims = backend.dims, policy = new StepPolicy(sampling, dims), B = rngs.length, L = dims.numLevels;
  const rowsEmb = policy.condition(textEmb), rows = B * policy.rows;
  let tokens = new Int32Array(rows * L).fill(dims.bosId);
  let past = backend.emptyPast(rows);
  const alive = new Uint8Array(B).fill(1);
  for (let t = 0; t < (fixedTokens ?? maxTokens); t++) {
    const out = await backend.step(rowsEmb, tokens, rows, past);
    past = out.past;
    const picked = policy.pick(out.logits, new Array(B).fill(fixedTokens === null && t >= 1), rngs);
    for (let b = 0; b < B; b++) if (picked[b * L] === dims.endId) alive[b] = 0;
    yield { picked, alive: alive.slice() };
    if (!alive.some(Boolean)) return;
    // ended prompts keep feeding a valid code; their rows are independent and their output is ignored
    tokens = policy.feed(picked.map((v, i) => (alive[Math.floor(i / L)] ? v : 0)), B);
  }
}

/** Runs the loop to the end: -> one (T_b, L) Int32Array per prompt; `onProgress(step)` as each step's tokens come. */
export async function collectTokens(steps, batch, numLevels, onProgress = null) {
  const out = Array.from({ length: batch }, () => []);
  let step = 0;
  for await (const { picked, alive } of steps) {
    onProgress?.(++step);
    for (let b = 0; b < batch; b++) if (alive[b]) out[b].push(...picked.subarray(b * numLevels, (b + 1) * numLevels));
  }
  return out.map((o) => Int32Array.from(o));
}

/** One (T_b, L) token array per prompt -> its (T_b * downsample, D) features, all prompts in one padded batch. */
export async function decodeTokens(backend, tokenSeqs) {
  const { numLevels: L, downsample, featureDim: D } = backend.dims;
  const lengths = tokenSeqs.map((s) => s.length / L);
  const T = Math.max(...lengths);
  if (T === 0) return tokenSeqs.map(() => new Float32Array(0));
  const batch = new Int32Array(tokenSeqs.length * T * L);
  tokenSeqs.forEach((seq, b) => batch.set(seq, b * T * L));
  const features = await backend.decode(batch, tokenSeqs.length);           // (B, T * ds, D)
  return lengths.map((n, b) => features.slice(b * T * downsample * D, (b * T + n) * downsample * D));
}

/**
 * One stream's tokens -> its frames as they come: the causal decoder, then joints integrated frame by frame
 * (FrameJoints). The first token is decoded at once (time to first frame); later tokens `chunk` at a time, so frames
 * come in bursts of chunk * downsample (decoding.py says why 4). With `decoderState` (the shapes of a decoder_step
 * graph's state) each decode feeds the new tokens alone and carries the decoder's state; without it, each decode
 * reads a window of receptive_field + chunk tokens. The caller runs the decoder (`decodeDue`), then `framesFrom`.
 */
export class FrameMaker {
  constructor(dims, skeleton, chunk = 1, decoderState = null) {
    this.dims = dims;
    this.chunk = checkChunk(chunk);
    // the decoder_step graph's state, zeros at a motion's start (the left padding of a whole-motion decode)
    this.state = decoderState && decoderState.map(([reach, channels]) => new Float32Array(reach * channels));
    this.tokens = new Int32Array((dims.receptiveField + chunk) * dims.numLevels);
    this.count = 0;     // tokens pushed
    this.pending = 0;   // tokens pushed whose frames were not made yet
    this.frames = 0;    // frames made
    this.joints = new FrameJoints(skeleton);
  }

  /** The stream's next token (L) -> how many tokens to decode now (`due`). */
  push(picked) {
    this.tokens.copyWithin(0, picked.length);
    this.tokens.set(picked, this.tokens.length - picked.length);
    this.count += 1;
    this.pending += 1;
    return this.due();
  }

  /** Tokens to decode for the frames now ready, 0 while a chunk fills up; `final`: every pending token's frames. */
  due(final = false) {
    if (!this.pending || !(final || this.count === 1 || this.pending >= this.chunk)) return 0;
    return this.state ? this.pending : Math.min(this.count, this.dims.receptiveField + this.pending);
  }

  /** The last n tokens (n, L), oldest first: the decoder's input for the frames due. */
  window(n) { return this.tokens.subarray(this.tokens.length - n * this.dims.numLevels); }

  /** The decoder's features for the n tokens due (`decodeDue`) -> the new frames {index, features (n, D), joints (n, J, 3)}. */
  framesFrom(features) {
    const fresh = features.subarray(features.length - this.pending * this.dims.downsample * this.dims.featureDim);
    const frames = { index: this.frames, features: fresh, joints: this.joints.push(fresh) };
    this.frames += this.pending * this.dims.downsample;
    this.pending = 0;
    return frames;
  }
}

/**
 * The features of the `n` tokens due (FrameMaker.due) of each of `makers`, in one decoder call: (B, n * ds, D) flat.
 * From each maker's decoder state, which moves on (decoder_step), else from its window (decoding.py decode_due).
 */
export async function decodeDue(decoder, makers, n) {
  const tokens = concat(makers.map((m) => m.window(n)));
  if (!makers[0].state) return decoder.decode(tokens, makers.length);
  const state = makers[0].state.map((_, i) => concat(makers.map((m) => m.state[i])));
  const out = await decoder.decodeStep(tokens, makers.length, state);
  makers.forEach((m, b) => {
    m.state = out.state.map((s, i) => s.slice(b * m.state[i].length, (b + 1) * m.state[i].length));
  });
  return out.features;
}

/**
 * The generation recipe for one backend and one set of settings: embeddings and seeds in; tokens, features and
 * joints out, all at once (`run`, `timeline`, `actions`) or frame by frame (`stream`).
 *
 * `fixedTokens` fixes the length; null lets the model end each motion, at most `maxTokens`. Without `streaming`
 * a fixed length never picks END. With it (a bundle trained for endless streams), fixed lengths and streams run
 * the EndlessLoop: any length, bounded context, END restarts the prompt.
 */
export class GenerationTask {
  constructor({ backend, skeleton, sampling, maxTokens, fixedTokens = null, streaming = null }) {
    Object.assign(this, { backend, skeleton, sampling, maxTokens, fixedTokens, streaming });
  }

  loop(textEmb, seeds) {
    if (this.streaming === null) {
      throw new Error("this bundle was not trained for endless streams (its manifest has no 'streaming' section): "
        + 're-export it from checkpoints trained on data with timed captions');
    }
    return new EndlessLoop(this.backend, textEmb, this.sampling, seeds, this.streaming);
  }

  /** Yields {picked (B, L), alive (B)} per step; `beforeStep` (optional) is awaited before each step of a loop. */
  async* steps(textEmb, seeds, loop = null, beforeStep = null) {
    if (loop === null && this.streaming !== null && this.fixedTokens !== null) loop = this.loop(textEmb, seeds);
    if (loop === null) {
      yield* generateTokens(this.backend, textEmb, this.sampling, makeRngs(seeds), this.maxTokens, this.fixedTokens);
      return;
    }
    const alive = new Uint8Array(seeds.length).fill(1);
    for (let t = 0; this.fixedTokens === null || t < this.fixedTokens; t++) {
      if (beforeStep) await beforeStep();
      yield { picked: await loop.step(), alive };
    }
  }

  /** -> one {tokens, features, joints} per prompt; `onProgress(step, limit)` after every step. */
  async run(textEmb, seeds, onProgress = null) {
    return this.#decoded(await this.#collect(this.steps(textEmb, seeds), seeds.length, onProgress));
  }

  #collect(steps, batch, onProgress, most = null) {
    const limit = most || this.fixedTokens || this.maxTokens;
    return collectTokens(steps, batch, this.backend.dims.numLevels, onProgress && ((step) => onProgress(step, limit)));
  }

  /** One character following prompt i (row i of textEmbs (N, text_dim)) from token starts[i] on (starts[0] = 0). */
  async timeline(textEmbs, starts, seed, onProgress = null) {
    const E = this.backend.dims.textDim, row = (i) => textEmbs.slice(i * E, (i + 1) * E);
    const loop = this.loop(row(0), [seed]), switchAt = new Map(starts.slice(1).map((s, i) => [s, i + 1]));
    const steps = this.steps(row(0), [seed], loop, () => {
      if (switchAt.has(loop.count)) loop.setPrompt(row(switchAt.get(loop.count)));
    });
    return (await this.#decoded(await this.#collect(steps, 1, onProgress)))[0];
  }

  /**
   * One character playing the actions of textEmbs (P, text_dim) in order (endless.js StreamContext.condition): until
   * the last one ends (END, or its stated length; at most as long as every action's limit, or the model's longest
   * motion, added up), or for `fixedTokens` exactly (the last action held). limits: P token counts or null.
   */
  async actions(textEmbs, limits, seed, onProgress = null) {
    const loop = this.loop(textEmbs.slice(0, this.backend.dims.textDim), [seed]);
    loop.setActions(textEmbs, limits);
    const stream = loop.streams[0], alive = new Uint8Array(1).fill(1), fixed = this.fixedTokens;
    const most = fixed || limits.reduce((n, limit) => n + (limit || this.maxTokens), 0);
    async function* steps() {
      for (let t = 0; t < most; t++) {
        const picked = await loop.step();
        if (fixed === null && stream.finished && stream.count > stream.finishedAt) return;   // END, and started again
        yield { picked, alive };
        if (fixed === null && stream.finished) return;
      }
    }
    const out = (await this.#decoded(await this.#collect(steps(), 1, onProgress, most)))[0];
    out.starts = stream.starts.filter((t) => t < out.tokens.length / this.backend.dims.numLevels);
    return out;
  }

  async #decoded(tokenSeqs) {
    const features = await decodeTokens(this.backend, tokenSeqs), J = this.skeleton.parents.length;
    return tokenSeqs.map((tokens, b) => ({
      tokens, features: features[b], joints: new FootLock(this.skeleton).push(recoverFromRic(features[b], J), features[b]),
    }));
  }

  /**
   * One prompt's frames as its tokens are sampled, a chunk at a time: yields {index, features (n, D),
   * joints (n, J, 3)}, n >= 1. With `loop` (an EndlessLoop of this prompt) the stream follows that loop's prompt
   * switches; `beforeStep` is awaited before each token (a prompt switch being encoded lands there); with
   * `steering` (of that loop's stream) it goes where the steering's target leads, and makes its frames every token
   * while it has a target.
   */
  stream(textEmb, seed, chunk = 4, loop = null, beforeStep = null, steering = null) {
    // checks chunk now, not at the first frame
    const maker = new FrameMaker(this.backend.dims, this.skeleton, chunk, this.backend.decoderState ?? null);
    return this.#stream(this.steps(textEmb, [seed], loop, beforeStep), maker, steering);
  }

  async* #stream(steps, maker, steering) {
    for await (const { picked, alive } of steps) {
      if (!alive[0]) break;
      if (steering?.target) maker.chunk = 1;   // the next token's control reads the pose the frames so far fix
      const n = maker.push(picked);
      if (n) yield await this.#frames(maker, n, steering);
    }
    const n = maker.due(true);
    if (n) yield await this.#frames(maker, n, steering);
  }

  async #frames(maker, n, steering) {
    const frames = maker.framesFrom(await decodeDue(this.backend, [maker], n));
    if (steering) steering.update(maker.frames, maker.joints);   // maker.frames: the next frame's number
    return frames;
  }
}
