// The step policy: what every loop (clips, endless streams) does with one step's logits, written once, as
// runtime/mogo_runtime/policy.py. A loop runs `rows` step rows per stream (its prompt, and with classifier-free
// guidance the all-zero text embedding the model was trained to see as "no text"), stream b's rows next to each
// other. From the newest step's logits the policy picks each stream's tokens: guidance, then END allowed to the
// coarsest level only (and there only where the loop allows the motion to end), then temperature, top-k and
// top-p, and one uniform draw per level from the stream's own PCG64 generator.
//
// A seed must give the tokens Python gives, so every operation follows numpy's, in numpy's order and
// precision: logits arrive as float32 (from onnxruntime), guidance is float32 arithmetic (numpy 2 keeps a
// Python float scalar "weak"), and the sampler works in float64: z / temperature, a stable sort by
// descending z, exp(z - max), a pairwise sum (numpy's np.sum), a sequential cumsum, and one uniform per
// level inverted through the CDF. The one place bits can differ is exp: numpy's SIMD exp and V8's Math.exp
// may round the last bit differently, which moves a pick only when a uniform lands within ~1e-16 of a CDF step
// (test/sampling.test.mjs measures the CDFs against numpy's).

import { shown } from './checks.js';
import { PCG64 } from './pcg64.js';

const SEED_LIMIT = 2n ** 63n;

/** `condition` and `feed` lay out a batch's step rows; `pick` turns their logits into tokens. */
export class StepPolicy {
  constructor(sampling, dims) {
    this.sampling = sampling;
    this.dims = dims;
    this.rows = sampling.guided ? 2 : 1;   // step rows per stream
  }

  /** (B, text_dim) prompt embeddings -> (B * rows, text_dim): each prompt, then its unconditional row. */
  condition(emb) { return this.rows === 1 ? emb : doubled(emb, emb.length / this.dims.textDim, false); }

  /** (B, S, L) tokens of `batch` streams -> the same for each of a stream's rows. */
  feed(tokens, batch) { return this.rows === 1 ? tokens : doubled(tokens, batch, true); }

  /**
   * The logits (B * rows, S, L, K + 1) of a step call, whether each stream may end (B), one generator per
   * stream -> the tokens (B, L) picked from the newest step.
   */
  pick(logits, mayEnd, rngs) {
    const { numLevels: L, endId } = this.dims, V = this.dims.codebookSize + 1, B = rngs.length;
    const newest = this.rows === 1 ? newestRows(logits, B, L * V, 0, 1)
      : applyGuidance(newestRows(logits, 2 * B, L * V, 0, 2), newestRows(logits, 2 * B, L * V, 1, 2), this.sampling.guidance);
    for (let b = 0; b < B; b++) {
      // only the coarsest level may end the motion
      for (let l = mayEnd[b] ? 1 : 0; l < L; l++) newest[(b * L + l) * V + endId] = -Infinity;
    }
    return sample(newest, L, this.sampling, rngs);
  }
}

/** (B, n) rows -> (2B, n): row b at 2b and, `twice`, at 2b + 1 too (else zeros there). */
function doubled(rows, batch, twice) {
  const n = rows.length / batch, out = new rows.constructor(2 * rows.length);
  for (let b = 0; b < batch; b++) {
    out.set(rows.subarray(b * n, (b + 1) * n), 2 * b * n);
    if (twice) out.set(rows.subarray(b * n, (b + 1) * n), (2 * b + 1) * n);
  }
  return out;
}

/** Rows first, first + every, ... of the last step of (rows, steps, width) logits, as a fresh (n, width) array. */
function newestRows(logits, rows, width, first, every) {
  const steps = logits.length / (rows * width), out = new Float32Array((rows / every) * width);
  for (let r = first, i = 0; r < rows; r += every, i++) {
    out.set(logits.subarray(((r + 1) * steps - 1) * width, (r + 1) * steps * width), i * width);
  }
  return out;
}

/**
 * Classifier-free guidance in float32, as numpy computes `uncond + scale * (cond - uncond)` on float32
 * arrays with a Python float scale: each operation rounded to float32 (a float64 result of one operation on
 * float32 inputs rounds to the correctly rounded float32).
 */
export function applyGuidance(cond, uncond, scale) {
  const g = Math.fround(scale);
  return cond.map((c, i) => uncond[i] + Math.fround(g * Math.fround(c - uncond[i])));
}

/** One token per row and level: logits (B, L, V), one generator per row (prompt) -> picks (B, L). */
export function sample(logits, L, config, rngs) {
  const B = rngs.length, V = logits.length / (B * L);
  if (!Number.isInteger(V) || V < 1) {
    throw new RangeError(`need one random generator per prompt: ${logits.length / L} rows of logits, ${B} generators`);
  }
  const picked = new Int32Array(B * L);
  for (let b = 0; b < B; b++) {
    for (let l = 0; l < L; l++) {
      const row = logits.subarray((b * L + l) * V, (b * L + l + 1) * V);
      picked[b * L + l] = config.greedy ? argmax(row) : draw(row, config, rngs[b]);
    }
  }
  return picked;
}

/** numpy's argmax: the first maximum (or the first NaN). */
export function argmax(row) {
  let best = 0;
  for (let i = 0; i < row.length; i++) {
    if (Number.isNaN(row[i])) return i;
    if (row[i] > row[best]) best = i;
  }
  return best;
}

/** One level's pick: the inverse CDF of the filtered distribution over codes sorted by descending logit. */
function draw(row, config, rng) {
  const V = row.length, z = Float64Array.from(row, (x) => x / config.temperature);
  const order = stableOrderDescending(z), probs = new Float64Array(V), top = z[order[0]];
  const keep = config.topK !== null && config.topK < V ? config.topK : V;
  for (let i = 0; i < V; i++) probs[i] = i < keep ? Math.exp(z[order[i]] - top) : 0;  // exp(-inf) = 0
  divideBy(probs, pairwiseSum(probs));
  if (config.topP !== null && config.topP < 1) {
    // keep a code while the mass before it is below top_p: the most likely code always survives
    let cumulative = 0;
    for (let i = 0; i < V; i++) {
      cumulative += probs[i];
      if (!(cumulative - probs[i] < config.topP)) probs[i] = 0;
    }
    divideBy(probs, pairwiseSum(probs));
  }
  const cdf = cumsum(probs), target = rng.random() * cdf[V - 1];
  let pick = 0;
  for (let i = 0; i < V; i++) if (cdf[i] < target) pick++;
  return order[Math.min(pick, V - 1)];
}

/**
 * Indices sorting z from largest to smallest, ties in index order, NaN last: np.argsort(-z, kind="stable").
 * A bottom-up merge sort on typed arrays (stable by construction): 4-5x faster than Array.prototype.sort
 * with a comparator, which was half the sampling time of a step on the base bundle.
 */
export function stableOrderDescending(z) {
  const n = z.length;
  let order = new Int32Array(n), spare = new Int32Array(n);
  for (let i = 0; i < n; i++) order[i] = i;
  const before = (a, b) => z[a] > z[b] || (Number.isNaN(z[b]) && !Number.isNaN(z[a]));   // strictly before
  for (let width = 1; width < n; width *= 2) {
    for (let lo = 0; lo < n; lo += 2 * width) {
      const mid = Math.min(lo + width, n), hi = Math.min(lo + 2 * width, n);
      let i = lo, j = mid, k = lo;
      while (i < mid && j < hi) spare[k++] = before(order[j], order[i]) ? order[j++] : order[i++];
      while (i < mid) spare[k++] = order[i++];
      while (j < hi) spare[k++] = order[j++];
    }
    [order, spare] = [spare, order];
  }
  return order;
}

/** np.sum of a contiguous float64 vector: numpy's pairwise summation (blocks of 128, 8 accumulators). */
export function pairwiseSum(a, start = 0, n = a.length) {
  if (n < 8) {
    let res = 0;   // numpy starts the reduction from the identity 0.0 (so -0 sums to +0)
    for (let i = start; i < start + n; i++) res += a[i];
    return res;
  }
  if (n <= 128) {
    const r = [a[start], a[start + 1], a[start + 2], a[start + 3], a[start + 4], a[start + 5], a[start + 6], a[start + 7]];
    let i = 8;
    for (; i < n - (n % 8); i += 8) {
      for (let j = 0; j < 8; j++) r[j] += a[start + i + j];
    }
    let res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
    for (; i < n; i++) res += a[start + i];
    return res;
  }
  let n2 = Math.floor(n / 2);
  n2 -= n2 % 8;
  return pairwiseSum(a, start, n2) + pairwiseSum(a, start + n2, n - n2);
}

const divideBy = (a, total) => a.forEach((x, i) => { a[i] = x / total; });

function cumsum(a) {
  let c = 0;
  return a.map((x) => (c += x));
}

/** One seed (BigInt) per prompt: prompt i of a batch with seed s draws exactly what a lone run with s + i does. */
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
  throw new RangeError(`seed must be an int >= 0 (a BigInt above 2**53) or a list of them, got ${shown(value)}`);
}

/** The random stream of each prompt: numpy's PCG64 seeded with the prompt's seed. */
export const makeRngs = (seeds) => seeds.map((s) => new PCG64(s));
