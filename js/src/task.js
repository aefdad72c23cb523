// The generation recipe for one backend and one set of settings (decoding.py, GenerationTask): embeddings and
// seeds in; tokens, features and joints out, all at once (`run`, `timeline`) or frame by frame (`stream`).
//
// `fixedTokens` fixes the length; null lets the model end each motion, at most `maxTokens`. Without `streaming`
// a fixed length never picks END. With it (a bundle trained for endless streams), fixed lengths and streams run
// the EndlessLoop: any length, bounded context, END restarts the prompt.

import { decodeTokens, FrameStreamer } from './decode.js';
import { FootLock, recoverFromRic, RootIntegrator } from './features.js';
import { EndlessLoop, generateTokens, makeRngs } from './loop.js';

export class GenerationTask {
  constructor({ backend, sampling, maxTokens, fixedTokens = null, streaming = null }) {
    this.backend = backend;
    this.sampling = sampling;
    this.maxTokens = maxTokens;
    this.fixedTokens = fixedTokens;
    this.streaming = streaming;
  }

  get numJoints() {
    return (this.backend.dims.featureDim + 1) / 12;   // HumanML3D layout: D = 12 J - 1
  }

  loop(textEmb, seeds) {
    if (this.streaming === null) {
      throw new Error("this bundle was not trained for endless streams (its manifest has no 'streaming' section): "
        + 're-export it from checkpoints trained on data with timed captions');
    }
    return new EndlessLoop(this.backend, textEmb, this.sampling, seeds, this.streaming.window, this.streaming.refresh);
  }

  /** Yields {picked (B, L), alive (B)} per step; `beforeStep` (optional) is awaited before each step. */
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

  /** -> one (T_b, L) Int32Array per prompt; `onProgress(step, limit)` after every step. */
  async tokens(textEmb, seeds, onProgress = null) {
    return this.#collect(this.steps(textEmb, seeds), seeds.length, onProgress);
  }

  async #collect(steps, batch, onProgress) {
    const L = this.backend.dims.numLevels, limit = this.fixedTokens ?? this.maxTokens;
    const out = Array.from({ length: batch }, () => []);
    let t = 0;
    for await (const { picked, alive } of steps) {
      for (let b = 0; b < batch; b++) if (alive[b]) out[b].push(...picked.subarray(b * L, (b + 1) * L));
      t += 1;
      onProgress?.(t, limit);
    }
    return out.map((o) => Int32Array.from(o));
  }

  /** -> one {tokens, features, joints} per prompt. */
  async run(textEmb, seeds, onProgress = null) {
    return this.#decoded(await this.tokens(textEmb, seeds, onProgress));
  }

  /**
   * One character following prompt i (row i of textEmbs) from token starts[i] on (starts[0] = 0).
   * @param {Float32Array} textEmbs (N, text_dim)
   */
  async timeline(textEmbs, starts, seed, onProgress = null) {
    const E = this.backend.dims.textDim;
    const row = (i) => textEmbs.slice(i * E, (i + 1) * E);
    const loop = this.loop(row(0), [seed]);
    const switchAt = new Map(starts.slice(1).map((s, i) => [s, i + 1]));
    const self = this;
    async function* steps() {
      let t = 0;
      for await (const item of self.steps(row(0), [seed], loop)) {
        yield item;
        t += 1;
        if (switchAt.has(t)) loop.setPrompt(row(switchAt.get(t)));
      }
    }
    return (await this.#decoded(await this.#collect(steps(), 1, onProgress)))[0];
  }

  async #decoded(tokenSeqs) {
    const features = await decodeTokens(this.backend, tokenSeqs);
    return tokenSeqs.map((tokens, b) => ({
      tokens, features: features[b],
      joints: new FootLock(this.numJoints).push(recoverFromRic(features[b], this.numJoints), features[b]),
    }));
  }

  /**
   * One prompt's frames as its tokens are sampled: yields {features (n, D), joints (n, J, 3), frames: n}, n >= 1.
   * With `loop` (an EndlessLoop of this prompt) the stream follows that loop's prompt changes; `beforeStep` is
   * awaited before each token (a pending prompt switch lands there).
   */
  stream(textEmb, seed, chunk = 4, loop = null, beforeStep = null) {
    const streamer = new FrameStreamer(this.backend, 1, chunk);   // checks chunk now, not at the first frame
    return this.#stream(this.steps(textEmb, [seed], loop, beforeStep), streamer);
  }

  async* #stream(steps, streamer) {
    const integrator = new RootIntegrator(this.numJoints), lock = new FootLock(this.numJoints);
    for await (const { picked, alive } of steps) {
      if (!alive[0]) break;
      const { features, frames } = await streamer.push(picked);
      if (frames) yield { features, joints: lock.push(integrator.push(features), features), frames };
    }
    const { features, frames } = await streamer.flush();
    if (frames) yield { features, joints: lock.push(integrator.push(features), features), frames };
  }
}
