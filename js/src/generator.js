// Text to motion with a bundle: `MotionGenerator` is the user's API (runtime/mogo_runtime/generator.py).
//
//   const gen = await MotionGenerator.load('bundles/base', { variant: 'int8' });
//   const motion = await gen.generate('a person walks forward', { seconds: 6, seed: 1 });
//   const s = await gen.stream('a person walks forward', { seed: 1 });
//   for await (const frame of s) { if (frame.time === 6) await s.setPrompt('a person turns left'); ... }
//   const both = await gen.generate('a person walks forward and then jumps');   // the actions one after another
//   both.alignedText   // 'a person walks forward | a person jumps': what the model was conditioned on, in order
//
// The recipe is decoding.js's GenerationTask (step for step Python's); this module checks what a user asks for,
// with Python's checks and defaults, and shapes the results.

import { Bundle } from './bundle/folder.js';
import { fileLoader } from './bundle/io.js';
import { SamplingConfig } from './bundle/sampling.js';
import { shown } from './checks.js';
import { legsOf } from './control/plant.js';
import { Steerable, Steering } from './control/steering.js';
import { GenerationTask } from './decoding.js';
import { OrtBackend } from './engine.js';
import { planActions } from './plan.js';
import { expandSeeds } from './policy.js';

export const MAX_SECONDS = 3600;   // the longest fixed length on an endless bundle: the whole motion is kept

export const MAX_PROMPT_CHARS = 10_000;   // characters (code points), as the Python runtime's text.MAX_PROMPT_CHARS

/**
 * Reject what would silently embed to nonsense or cost without bound (text.check_texts): an empty list,
 * non-strings, prompts over MAX_PROMPT_CHARS characters, blank prompts, lone surrogates (not Unicode text).
 */
export function checkTexts(texts) {
  if (!Array.isArray(texts)) throw new TypeError('expected a list of prompts');
  if (!texts.length) throw new RangeError('got an empty list of prompts');
  texts.forEach((t, i) => {
    if (typeof t !== 'string') throw new TypeError(`prompt ${i} is a ${t === null ? 'null' : typeof t}, expected a string`);
    const chars = t.length > MAX_PROMPT_CHARS ? [...t].length : t.length;   // UTF-16 units >= code points
    if (chars > MAX_PROMPT_CHARS) {
      throw new RangeError(`prompt ${i} has ${chars.toLocaleString('en-US')} characters; a prompt may have at most `
        + `${MAX_PROMPT_CHARS.toLocaleString('en-US')} (the text encoder reads only its first few hundred words)`);
    }
    if (!t.trim()) {
      throw new RangeError(`prompt ${i} is empty or whitespace only (${shown(t)}); describe a motion, e.g. 'a person walks forward'`);
    }
    if (!t.isWellFormed()) {
      const at = [...t].findIndex((c) => c.length === 1 && c >= '\ud800' && c <= '\udfff');
      throw new RangeError(`prompt ${i} is not valid Unicode text: character ${at} is a lone surrogate; pass UTF-8 text`);
    }
  });
  return texts;
}

export class MotionGenerator {
  /**
   * The generator of `variant` ('fp32', 'int8', ...) of the bundle at `source`, a folder or a loader (bundle/io.js).
   * `ort`: the onnxruntime module (default onnxruntime-node), `providers` its execution providers (default ['cpu'];
   * ['wasm'] with onnxruntime-web), `threads` intra-op threads per graph, `verifyHashes` each file read checked.
   */
  static async load(source, { variant = 'fp32', threads = 1, ort = null, providers, verifyHashes = true } = {}) {
    if (typeof variant !== 'string' || !variant) {
      throw new TypeError(`variant must be a variant name such as 'fp32' or 'int8', got ${shown(variant)}`);
    }
    const loader = typeof source === 'string' ? fileLoader(source) : source;
    const bundle = await Bundle.load(loader, { verifyHashes });
    const runtime = ort ?? (await import('onnxruntime-node'));
    const backend = await OrtBackend.open(bundle, variant, { ort: runtime, threads, providers });
    return new MotionGenerator(bundle, backend);
  }

  constructor(bundle, backend) {
    const { model: dims, skeleton, samplingDefaults } = bundle.manifest;
    Object.assign(this, { bundle, backend, variant: backend.variant, dims, skeleton, samplingDefaults });
    Object.assign(this, { fps: dims.fps, maxTokens: dims.maxTokens, maxSeconds: dims.maxSeconds });
  }

  /** Whether the bundle was trained for endless streams (stream without end, setPrompt, long lengths). */
  get endless() { return this.bundle.manifest.streaming !== null; }

  /**
   * One motion per prompt (an array for an array), all prompts in one batched loop; on an endless bundle a prompt
   * that names several actions ('walks forward and then jumps', plan.js) plays them one after another, each until
   * the model ends it or for its stated duration ('for 3 seconds'), run on its own; its `alignedText` shows the
   * actions joined by ' | ' (null for a prompt of one action, as typed).
   *
   * Prompt i of an array uses seed `seed + i` (or `seed[i]`), so it gets the motion a lone run with that seed
   * gets. `seconds` fixes the length (rounded half up to whole tokens); null lets the model end the motion, at
   * most `maxSeconds`. On an endless bundle a fixed length may be up to MAX_SECONDS, and a timeline
   * `[[prompt, startSeconds], ...]` (starts from 0, increasing; `seconds` required) gives one motion that
   * follows each prompt from its start. `sampling` null: the bundle's defaults.
   * @returns {Promise<Motion|Motion[]>} Motion: {text, alignedText, seed, fps, tokens, features, joints, numFrames,
   *   seconds},
   *   tokens {data: Int32Array, dims: [T, L]}, features {data, dims: [F, D]}, joints {data, dims: [F, J, 3]}
   */
  async generate(text, { seconds = null, seed = 0, sampling = null, onProgress = null } = {}) {
    if (Array.isArray(text) && text.length && text.every(Array.isArray)) {
      return this.#timeline(text, seconds, seed, sampling, onProgress);
    }
    const texts = checkTexts(typeof text === 'string' ? [text] : text);
    const { task, conds, seeds } = await this.#prepare(texts, seconds, seed, sampling);
    let results;
    if (conds.every((c) => c.single)) {
      results = await task.run(joined(conds.map((c) => c.emb)), seeds, onProgress);
    } else {   // a prompt of several actions plays them one after another: each prompt on its own
      results = [];
      for (const [i, c] of conds.entries()) {
        results.push(c.single ? (await task.run(c.emb, [seeds[i]], onProgress))[0]
          : await task.actions(c.emb, c.limits, seeds[i], onProgress));
      }
    }
    const motions = results.map((r, i) => this.#motion(texts[i], r, seeds[i], conds[i].aligned));
    return typeof text === 'string' ? motions[0] : motions;
  }

  async #timeline(timeline, seconds, seed, sampling, onProgress) {
    if (seconds === null || seconds === undefined) throw new RangeError('a timeline needs seconds, the length of the whole motion');
    if (!timeline.every((item) => item.length === 2 && typeof item[0] === 'string')) {
      throw new TypeError('a timeline is a list of [prompt, startSeconds] pairs');
    }
    const texts = checkTexts(timeline.map(([t]) => t));
    const total = this.tokensFor(seconds);
    let starts;
    try {
      starts = timeline.map(([, s]) => (s ? this.tokensFor(s) : 0));
    } catch (e) {
      throw new e.constructor(`a timeline start: ${e.message.replace('seconds must be', 'it must be')}`);
    }
    if (timeline[0][1] !== 0 || starts.some((s, i) => i > 0 && s <= starts[i - 1]) || starts[starts.length - 1] >= total) {
      throw new RangeError(`timeline starts must begin at 0 and increase, each before the end (${seconds} s); got `
        + `${shown(timeline.map(([, s]) => s), 200)}`);
    }
    const first = expandSeeds(seed, 1)[0];
    const { task, conds } = await this.#prepare(texts, seconds, texts.map(() => first), sampling, false);
    const r = await task.timeline(joined(conds.map((c) => c.emb)), starts, first, onProgress);
    return this.#motion(texts.join(' | '), r, first, null);
  }

  /**
   * Frames of one prompt's motion as its tokens are sampled and decoded. On an endless bundle the stream has no
   * end unless `seconds` is given, and `setPrompt` changes the prompt from the next token; `close()` ends it.
   * The first token's frames come at once, then `chunk` tokens at a time. Arguments are checked and the prompt
   * encoded here, before the first frame is asked for. A prompt of several actions (plan.js) plays them in order,
   * the last one held; the stream's `alignedText` shows them joined by ' | '.
   * @returns {Promise<FrameStream>} an async iterator of {index, time, features (D), joints (J * 3)}
   */
  async stream(text, { seconds = null, seed = 0, sampling = null, chunk = 4 } = {}) {
    if (typeof text !== 'string') {
      throw new TypeError(`stream() takes one prompt (a string), got ${typeof text}; use generate() for a batch`);
    }
    const { task, conds, seeds } = await this.#prepare(checkTexts([text]), seconds, seed, sampling);
    return new FrameStream(this, task, conds[0], seeds[0], chunk, text);
  }

  /** Seconds -> a fixed number of tokens (half up), or null; RangeError outside the bundle's range. */
  tokensFor(seconds) {
    if (seconds === null || seconds === undefined) return null;
    const perToken = this.dims.downsample / this.dims.fps;
    const [most, limit] = this.endless ? [MAX_SECONDS, 'endless streams'] : [this.maxSeconds, 'this bundle'];
    const allowed = `between ${perToken} and ${most} seconds for ${limit} (${this.dims.downsample} frames per token at `
      + `${this.dims.fps} fps)`;
    if (typeof seconds !== 'number') throw new TypeError(`seconds must be a number ${allowed}, got ${shown(seconds)}`);
    const tokens = Math.floor(seconds / perToken + 0.5 + 1e-9);   // the epsilon keeps 6.0 s from landing just below
    if (!(seconds >= perToken / 2 && seconds <= most + perToken && tokens >= 1
      && tokens <= (this.endless ? Math.round(most / perToken) : this.maxTokens))) {
      throw new RangeError(`seconds must be ${allowed}, got ${seconds}`);
    }
    return tokens;
  }

  /** What generate and stream share: checked arguments, the task, each prompt's conditioning and seeds. */
  async #prepare(texts, seconds, seed, sampling, split = true) {
    const fixedTokens = this.tokensFor(seconds);
    const config = sampling === null || sampling === undefined ? this.samplingDefaults : SamplingConfig.from(sampling);
    const seeds = expandSeeds(seed, texts.length);
    const conds = await this.condition(texts, split);
    const task = new GenerationTask({ backend: this.backend, skeleton: this.skeleton, sampling: config,
      maxTokens: this.maxTokens, fixedTokens, streaming: this.bundle.manifest.streaming });
    return { task, conds, seeds };
  }

  /**
   * What each prompt conditions the model on: {emb (actions, text_dim), limits (tokens each action lasts, null: until
   * the model ends it), aligned (the text shown as alignedText; null: the prompt as typed), single (one action, no
   * stated duration: run as it always was, batched with others)}. On an endless bundle (and `split`) a prompt that
   * names several actions is split into them (plan.js), encoded in one text-encoder call per prompt (its actions'
   * padding never mixes with another prompt's); elsewhere a prompt is one conditioning, as typed.
   */
  async condition(texts, split = true) {
    return this.encodePlans(texts, this.plan(texts, split));
  }

  /** Each prompt's actions [{text, seconds}] and their limits in tokens: checked now (RangeError), not encoded. */
  plan(texts, split = true) {
    return texts.map((t) => {
      const actions = split && this.endless ? planActions(t) : [{ text: t, seconds: null }];
      return { actions, limits: actions.map((a) => this.tokensFor(a.seconds)) };
    });
  }

  /** The prompts `texts` planned (`plan`) -> their conditioning (`condition`). */
  async encodePlans(texts, plans) {
    const E = this.dims.textDim;
    if (plans.every((p) => p.actions.length === 1 && p.limits[0] === null)) {
      const emb = await this.backend.encodeText(plans.map((p) => p.actions[0].text));
      return plans.map((p, i) => conditioning(emb.slice(i * E, (i + 1) * E), p.limits, null));
    }
    const out = [];
    for (const [i, { actions, limits }] of plans.entries()) {   // one encoder call per prompt
      const parts = actions.map((a) => a.text);
      const asTyped = parts.length === 1 && parts[0] === texts[i];
      out.push(conditioning(await this.backend.encodeText(parts), limits, asTyped ? null : parts.join(' | ')));
    }
    return out;
  }

  #motion(text, { tokens, features, joints, starts = null }, seed, alignedText) {
    const { numLevels: L, featureDim: D } = this.dims;
    const J = this.skeleton.parents.length, frames = features.length / D;
    // a prompt of several actions: each action's text and the frame it starts at, in order (else null)
    const actions = starts && alignedText.split(' | ').slice(0, starts.length).map((a, i) => [a, starts[i] * this.dims.downsample]);
    return {
      text, alignedText, actions, seed, fps: this.fps, numFrames: frames, seconds: frames / this.fps,
      tokens: { data: tokens, dims: [tokens.length / L, L] },
      features: { data: features, dims: [frames, D] },
      joints: { data: joints, dims: [frames, J, 3] },
    };
  }

  /** Free the onnxruntime sessions. */
  async release() { await this.backend.release(); }
}

/** A prompt's conditioning (MotionGenerator.condition). */
function conditioning(emb, limits, aligned) {
  return { emb, limits, aligned, single: limits.length === 1 && limits[0] === null };
}

/** Float32Arrays end to end. */
function joined(arrays) {
  const out = new Float32Array(arrays.reduce((n, a) => n + a.length, 0));
  arrays.reduce((at, a) => { out.set(a, at); return at + a.length; }, 0);
  return out;
}

/**
 * What `MotionGenerator.stream` returns: an async iterator of frames, the prompt it follows now (`text`, and
 * `alignedText`: its actions joined by ' | ' where it names several, else null), and, on an endless bundle,
 * `setPrompt` to change what the character does from the next token sampled; on one whose model has control, where
 * it goes too (`walkTo`, `followPath`, `steer`, `setRoot`, `release`: control/). A request made between two frames
 * lands at the next token sampled.
 */
export class FrameStream extends Steerable {
  constructor(gen, task, cond, seed, chunk, text) {
    super();
    this.gen = gen;
    this.text = text;
    this.alignedText = cond.aligned;
    this.switches = [];                 // {token, text, alignedText} of each prompt switch, where it landed
    this.closed = false;                // close() was called, or the motion ended: no more prompts
    this.shown = 0;                     // the number of the next frame handed out
    this.pending = Promise.resolve();   // prompt switches being encoded, one at a time; each step waits for them
    const emb = cond.emb.slice(0, gen.dims.textDim);   // the first action (a prompt of several: then the others)
    this.loop = task.streaming !== null ? task.loop(emb, [seed]) : null;
    if (this.loop !== null && !cond.single) this.loop.setActions(cond.emb, cond.limits);
    const control = task.backend.control;
    this.steering = control && this.loop
      ? new Steering(control, task.backend.dims, this.loop.streams[0], legsOf(task.skeleton)) : null;
    this.frames = this.#frames(task.stream(emb, seed, chunk, this.loop, () => this.pending, this.steering));
  }

  [Symbol.asyncIterator]() { return this; }

  next() { return this.frames.next(); }

  return() { return this.frames.return(); }

  /** Tokens sampled so far (frames lag behind by the decoding chunk). */
  get tokens() { return this.loop ? this.loop.count : 0; }

  /**
   * Follow `text` from the next token sampled on (frames already decoded do not change): a prompt of several actions
   * plays them in order (plan.js), the last one held. The switch lands at the next token even if this promise is not
   * awaited first; asked for while a step runs, at the token after it. A prompt that cannot be played (more than
   * plan.MAX_ACTIONS actions, a duration out of range) is refused here, at once, and the stream goes on.
   */
  setPrompt(text) {
    if (this.loop === null) {
      throw new Error("this bundle was not trained for endless streams (its manifest has no 'streaming' section), "
        + 'so its streams cannot change prompt');
    }
    if (this.closed) throw new Error('this stream is closed (close(), or its motion ended): it follows no more prompts');
    if (typeof text !== 'string') throw new TypeError(`setPrompt() takes one prompt (a string), got ${typeof text}`);
    const plans = this.gen.plan(checkTexts([text]));
    this.pending = this.pending.then(async () => {
      const [cond] = await this.gen.encodePlans([text], plans);
      const token = this.loop.setActions(cond.emb, cond.limits);
      this.text = text;
      this.alignedText = cond.aligned;
      this.switches.push({ token, text, alignedText: cond.aligned });
    });
    return this.pending;
  }

  nextShown() { return this.shown; }

  checkSteerable() {
    if (this.closed) throw new Error('this stream is closed (close(), or its motion ended): it goes nowhere any more');
  }

  whyNotSteerable() {
    return this.loop ? super.whyNotSteerable() : "this bundle was not trained for endless streams (its manifest has no "
      + "'streaming' section), so its streams cannot be steered";
  }

  /** End the stream (no more tokens are sampled). */
  async close() {
    this.closed = true;
    await this.frames.return();
  }

  /** Closing the stream (breaking out of the loop below) ends its token loop too. */
  async* #frames(chunks) {
    const { featureDim: D } = this.gen.dims, J3 = this.gen.skeleton.parents.length * 3;
    try {
      for await (const { index, features, joints } of chunks) {
        for (let i = 0; i < features.length / D; i++) {
          this.shown = index + i + 1;
          // on the game's capsule as placed up to now, when it owns the root (placed as the frame is handed out)
          const frame = joints.slice(i * J3, (i + 1) * J3);
          yield { index: index + i, time: (index + i) / this.gen.fps, features: features.slice(i * D, (i + 1) * D),
            joints: this.steering ? this.steering.place(index + i, frame) : frame };
        }
      }
    } finally {
      this.closed = true;
    }
  }
}
