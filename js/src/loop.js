// The token loops, step for step as runtime/mogo_runtime/decoding.py: `generateTokens` (generate_tokens,
// a batch of clips that end when the model picks END) and `EndlessLoop` (endless streams with a bounded,
// rebuilt context; docs/bundle.md, "Endless streams").
//
// Tokens are Int32Array rows of L levels; logits (rows, steps, L, K + 1) float32 as onnxruntime returns them.
// Every random draw comes from the prompt's own PCG64 stream (numpy's, bit for bit), one uniform per level
// per step, so a prompt, a seed and the settings give Python's tokens.

import { PCG64 } from './pcg64.js';
import { applyGuidance, sample } from './sampling.js';

const SEED_LIMIT = 2n ** 63n;

/**
 * One seed per prompt: prompt i of a batch with seed s draws exactly what a lone run with s + i does.
 * @param {number|bigint|Array<number|bigint>} seed
 * @returns {bigint[]}
 */
export function expandSeeds(seed, batch) {
  const seeds = Array.isArray(seed) ? seed.map(toSeed) : Array.from({ length: batch }, (_, i) => toSeed(seed) + BigInt(i));
  if (seeds.length !== batch) throw new RangeError(`got ${seeds.length} seeds for ${batch} prompts`);
  for (const s of seeds) {
    if (s < 0n || s >= SEED_LIMIT) throw new RangeError(`seeds must be ints in [0, 2**63), got ${s}`);
  }
  return seeds;
}

function toSeed(value) {
  if (typeof value === 'bigint') return value;
  if (typeof value === 'number' && Number.isSafeInteger(value)) return BigInt(value);
  throw new RangeError(`seed must be an int >= 0 (a BigInt above 2**53) or a list of them, got ${String(value)}`);
}

/** The random stream of each prompt: numpy's PCG64 seeded with the prompt's seed. */
export function makeRngs(seeds) {
  return seeds.map((s) => new PCG64(s));
}

/** Rows of logits for the last step of a call: (rows, steps, L, V) -> (rows, L, V), a fresh copy. */
function lastStep(logits, rows, width) {
  const steps = logits.length / (rows * width);
  const out = new Float32Array(rows * width);
  for (let r = 0; r < rows; r++) out.set(logits.subarray((r * steps + steps - 1) * width, (r * steps + steps) * width), r * width);
  return out;
}

/** `rows` followed by as many all-zero rows: the unconditional branch, the embedding the model was trained to see. */
function withUnconditional(rows) {
  const out = new Float32Array(2 * rows.length);
  out.set(rows);
  return out;
}

/** The same tokens for both guidance branches. */
function twice(tokens) {
  const out = new Int32Array(2 * tokens.length);
  out.set(tokens);
  out.set(tokens, tokens.length);
  return out;
}

/** Guidance on (2B, L, V) logits: rows B.. are the unconditional branch. */
function guided(logits, scale) {
  const half = logits.length / 2;
  return applyGuidance(logits.subarray(0, half), logits.subarray(half), scale);
}

/** END is allowed to level 0 only, and there only when `endAllowed`. */
function maskEnd(logits, rows, dims, endAllowed) {
  const L = dims.numLevels, V = dims.codebookSize + 1;
  for (let r = 0; r < rows; r++) {
    for (let l = endAllowed ? 1 : 0; l < L; l++) logits[(r * L + l) * V + dims.endId] = -Infinity;
  }
}

/**
 * Yields {picked (B, L), alive (B)} once per time step until every prompt has ended (generate_tokens).
 * alive[b] is 0 from the step where prompt b chose END (its tokens that step are meaningless). With
 * `fixedTokens` END is forbidden and every prompt runs exactly that many steps.
 * @param {import('./engine.js').OrtBackend} backend
 * @param {Float32Array} textEmb (B, text_dim)
 */
export async function* generateTokens(backend, textEmb, sampling, rngs, maxTokens, fixedTokens = null, minTokens = 1) {
  const dims = backend.dims, L = dims.numLevels, V = dims.codebookSize + 1, B = rngs.length;
  const limit = fixedTokens ?? maxTokens;
  const withGuidance = sampling.guidance !== 1;
  const rowsEmb = withGuidance ? withUnconditional(textEmb) : textEmb;
  const rows = withGuidance ? 2 * B : B;
  let tokens = new Int32Array(rows * L).fill(dims.bosId);
  let past = backend.emptyPast(rows);
  const alive = new Uint8Array(B).fill(1);
  for (let t = 0; t < limit; t++) {
    const out = await backend.step(rowsEmb, tokens, rows, past);
    past = out.past;
    let logits = lastStep(out.logits, rows, L * V);
    if (withGuidance) logits = guided(logits, sampling.guidance);
    maskEnd(logits, B, dims, fixedTokens === null && t >= minTokens);
    const picked = sample(logits, L, sampling, rngs);
    for (let b = 0; b < B; b++) if (picked[b * L] === dims.endId) alive[b] = 0;
    yield { picked, alive: alive.slice() };
    if (!alive.some(Boolean)) return;
    // ended prompts keep feeding a valid code; their rows are independent and their output is ignored
    const feed = picked.map((v, i) => (alive[Math.floor(i / L)] ? v : 0));
    tokens = withGuidance ? twice(feed) : feed;
  }
}

/**
 * The token loop of endless streams (decoding.EndlessLoop): never ends by itself, follows a new prompt from
 * the next token, and keeps a bounded context. Each stream's context is its prompt's prefix (BOS) plus motion
 * tokens, rebuilt (one step call with an empty cache on [BOS, kept tokens]) when:
 * - the prompt changed: nothing kept (the new prompt starts a motion as it would alone);
 * - level 0 picked END: the motion ended where a clip would end; that step's tokens are dropped (their draws
 *   stay consumed), the prompt starts again with nothing kept, and the step picks again, END forbidden;
 * - the cache holds window + refresh motion tokens: the last `window` are kept.
 * Until its first END a stream computes exactly what generateTokens computes. Streams of a batch are
 * independent (their contexts rebuild at different steps): each runs its own step calls.
 */
export class EndlessLoop {
  /**
   * @param {Float32Array} textEmb (B, text_dim), one row per stream
   * @param {bigint[]} seeds one per stream
   */
  constructor(backend, textEmb, sampling, seeds, window, refresh, minTokens = 1) {
    this.backend = backend;
    this.sampling = sampling;
    this.window = window;
    this.refresh = refresh;
    this.minTokens = minTokens;   // END allowed once a motion has this many tokens, as in generateTokens
    this.rngs = makeRngs(seeds);
    this.batch = seeds.length;
    this.guided = sampling.guidance !== 1;
    const L = backend.dims.numLevels;
    // a ring of the last window + refresh picked tokens: token t sits at t % (window + refresh)
    this.history = Array.from({ length: this.batch }, () => new Int32Array((window + refresh) * L));
    this.last = new Int32Array(this.batch * L);
    this.count = 0;                                   // tokens picked so far (every stream picks one per step)
    this.cached = new Array(this.batch).fill(0);      // motion tokens in each stream's cache (after the prefix)
    this.motion = new Array(this.batch).fill(0);      // tokens since each stream's motion (re)started
    this.past = new Array(this.batch).fill(null);     // null: the stream's next step rebuilds with nothing kept
    this.restarts = 0;                                // motions ended by END and started again, over all streams
    this.setPrompt(textEmb);
  }

  /** (B, text_dim) embeddings to follow from the next token on. */
  setPrompt(textEmb) {
    const E = this.backend.dims.textDim;
    if (textEmb.length !== this.batch * E) {
      throw new RangeError(`expected (${this.batch}, ${E}) text embeddings, got ${textEmb.length} values`);
    }
    this.rowsEmb = Array.from({ length: this.batch }, (_, b) => {
      const row = textEmb.slice(b * E, (b + 1) * E);
      return this.guided ? withUnconditional(row) : row;
    });
    this.past.fill(null);
  }

  /** -> the next tokens (B, L) of every stream. */
  async step() {
    const L = this.backend.dims.numLevels, H = this.window + this.refresh;
    const picked = new Int32Array(this.batch * L);
    for (let b = 0; b < this.batch; b++) picked.set(await this.#step(b), b * L);
    for (let b = 0; b < this.batch; b++) this.history[b].set(picked.subarray(b * L, (b + 1) * L), (this.count % H) * L);
    this.last = picked;
    this.count += 1;
    return picked;
  }

  async #step(b) {
    const dims = this.backend.dims, L = dims.numLevels, V = dims.codebookSize + 1, H = this.window + this.refresh;
    const rows = this.guided ? 2 : 1;
    for (const retry of [false, true]) {
      let tokens;
      if (this.past[b] === null || this.cached[b] === H) {
        const n = this.past[b] === null ? 0 : this.window;
        if (n === 0) this.motion[b] = 0;
        tokens = new Int32Array((n + 1) * L).fill(dims.bosId);
        for (let i = 0; i < n; i++) {   // the last n picked, oldest first
          const slot = (((this.count - n + i) % H) + H) % H;
          tokens.set(this.history[b].subarray(slot * L, (slot + 1) * L), (i + 1) * L);
        }
        this.past[b] = this.backend.emptyPast(rows);
        this.cached[b] = n;
      } else {
        tokens = this.last.slice(b * L, (b + 1) * L);
        this.cached[b] += 1;
      }
      if (this.guided) tokens = twice(tokens);
      const out = await this.backend.step(this.rowsEmb[b], tokens, rows, this.past[b]);
      this.past[b] = out.past;
      let logits = lastStep(out.logits, rows, L * V);
      if (this.guided) logits = guided(logits, this.sampling.guidance);
      maskEnd(logits, 1, dims, !retry && this.motion[b] >= this.minTokens);
      const picked = sample(logits, L, this.sampling, [this.rngs[b]]);
      if (picked[0] !== dims.endId) {
        this.motion[b] += 1;
        return picked;
      }
      this.past[b] = null;   // the motion ended: start the prompt again
      this.restarts += 1;
    }
    throw new Error('unreachable: END is forbidden on the retry');
  }
}
