// Tokens -> de-normalised motion features with the lookup and the causal decoder, all at once
// (`decodeTokens`) or window by window as tokens arrive (`FrameStreamer`), as decoding.py does: a frame
// depends only on its token and the `receptive_field` tokens before it, so a stream decodes only that window.

export const MAX_CHUNK = 1024;   // tokens per decode; more only delays frames (and the window is allocated up front)

/**
 * All prompts through the decoder in one batch, padded on the right (harmless: the decoder is causal).
 * @param {Int32Array[]} tokenSeqs one (T_b, L) array per prompt
 * @returns {Promise<Float32Array[]>} one (T_b * downsample, feature_dim) array per prompt
 */
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
 * Turns tokens into frames as they arrive. The first token is decoded at once (time to first frame); later
 * tokens `chunk` at a time, each decode reading receptive_field + chunk tokens, so the frames come in bursts of
 * chunk * downsample, equal to the frames of a decode of the whole motion. Holds a fixed ring of recent tokens.
 */
export class FrameStreamer {
  constructor(backend, batch, chunk = 1) {
    if (!Number.isInteger(chunk) || chunk < 1 || chunk > MAX_CHUNK) {
      throw new RangeError(`chunk must be an int in [1, ${MAX_CHUNK}], got ${chunk}`);
    }
    this.backend = backend;
    this.batch = batch;
    this.chunk = chunk;
    this.window = backend.dims.receptiveField + chunk;
    this.tokens = new Int32Array(batch * this.window * backend.dims.numLevels);
    this.count = 0;     // tokens pushed
    this.pending = 0;   // tokens pushed whose frames were not returned yet
  }

  /**
   * @param {Int32Array} picked (B, L) of the newest step
   * @returns {Promise<{features: Float32Array, frames: number}>} features (B, frames, D) of the frames now ready
   *   (frames = 0 while a chunk fills up)
   */
  async push(picked) {
    const { numLevels: L, codebookSize: K } = this.backend.dims;
    const W = this.window;
    for (let b = 0; b < this.batch; b++) {
      const row = this.tokens.subarray(b * W * L, (b + 1) * W * L);
      row.copyWithin(0, L);
      // a prompt that just ended carries END; decode a valid code in its place (its frames are dropped)
      for (let l = 0; l < L; l++) row[(W - 1) * L + l] = picked[b * L + l] < K ? picked[b * L + l] : 0;
    }
    this.count += 1;
    this.pending += 1;
    if (this.count > 1 && this.pending < this.chunk) return { features: new Float32Array(0), frames: 0 };
    return this.flush();
  }

  /** The frames of every token pushed and not yet returned: call once the motion has ended. */
  async flush() {
    const { numLevels: L, receptiveField, downsample: ds, featureDim: D } = this.backend.dims;
    if (!this.pending) return { features: new Float32Array(0), frames: 0 };
    const n = Math.min(this.count, receptiveField + this.pending), W = this.window;
    const window = new Int32Array(this.batch * n * L);
    for (let b = 0; b < this.batch; b++) window.set(this.tokens.subarray((b * W + W - n) * L, (b + 1) * W * L), b * n * L);
    const features = await this.backend.decode(window, this.batch);           // (B, n * ds, D)
    const frames = this.pending * ds;
    const out = new Float32Array(this.batch * frames * D);
    for (let b = 0; b < this.batch; b++) out.set(features.subarray(((b + 1) * n * ds - frames) * D, (b + 1) * n * ds * D), b * frames * D);
    this.pending = 0;
    return { features: out, frames };
  }
}
