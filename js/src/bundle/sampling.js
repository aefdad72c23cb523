// The sampling settings (runtime/mogo_runtime/bundle/sampling.py): what a user passes to generate or stream, and
// what a manifest's `sampling_defaults` section holds. The policy that applies them is policy.js.

import { asReal, shown } from '../checks.js';

export class SamplingConfig {
  /**
   * temperature: 0 = greedy (argmax), no randomness; topK: keep the k most likely codes (null or 0: all); topP:
   * nucleus, keep the smallest set with this much mass (null: all); guidance: the classifier-free guidance scale,
   * 1 = off (no unconditional pass). One check for the API and the manifest, with Python's messages.
   */
  constructor({ temperature = 1.0, topK = null, topP = null, guidance = 1.0, ...unknown } = {}) {
    const extra = Object.keys(unknown);
    if (extra.length) {
      throw new TypeError(`unknown sampling setting ${shown(extra[0])} (known: temperature, topK, topP, guidance)`);
    }
    if (topK !== null && !(Number.isInteger(topK) && topK >= 0)) {
      throw new RangeError(`top_k must be an int >= 1 (0 or None: no top-k cut), got ${shown(topK)}`);
    }
    this.temperature = asReal('temperature', temperature, 'in [0, 100] (0 = greedy)', 0, 100);
    this.topK = topK || null;
    this.topP = topP === null ? null : asReal('top_p', topP, 'in (0, 1] or None', Number.MIN_VALUE, 1);
    this.guidance = asReal('guidance', guidance, 'in [0, 100] (1 = off)', 0, 100);
    Object.freeze(this);
  }

  /** A SamplingConfig from one (returned as is) or from a plain object of settings. */
  static from(value) { return value instanceof SamplingConfig ? value : new SamplingConfig(value); }

  /** The manifest's `sampling_defaults` (snake_case keys as Python writes them; missing ones take the defaults). */
  static fromManifest({ top_k: topK, top_p: topP, ...settings }) {
    return new SamplingConfig({ ...settings, topK, topP });
  }

  get greedy() { return this.temperature === 0; }

  /** Whether each stream runs a second, unconditional step row (classifier-free guidance). */
  get guided() { return this.guidance !== 1; }
}
