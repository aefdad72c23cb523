// numpy's `np.random.Generator(np.random.PCG64(seed))`, bit for bit, for `random()`.
//
// The Python runtime draws one uniform per level per step from PCG64 seeded with the prompt's seed, so a
// JavaScript consumer must reproduce numpy's stream exactly to pick the same tokens:
//   1. SeedSequence(seed) mixes the seed's 32-bit words into a pool of 4 words and hashes the pool into
//      4 uint64 words (numpy/random/bit_generator.pyx);
//   2. PCG64 takes words 0-1 as the 128-bit initial state and words 2-3 as the stream (increment);
//   3. each draw steps the 128-bit LCG and outputs XSL-RR (xor the halves, rotate by the top 6 bits);
//   4. random() = (next_uint64 >> 11) * 2**-53.
// BigInt keeps the 128-bit arithmetic exact; a draw costs a few microseconds, far below a model step.

const MASK32 = 0xffffffffn;
const MASK64 = (1n << 64n) - 1n;
const MASK128 = (1n << 128n) - 1n;
const PCG_MULTIPLIER = 0x2360ed051fc65da44385df649fccf645n;   // PCG_DEFAULT_MULTIPLIER_128

// SeedSequence constants (numpy/random/bit_generator.pyx)
const POOL_SIZE = 4;
const INIT_A = 0x43b0d7e5;
const MULT_A = 0x931e8875;
const INIT_B = 0x8b51f9dd;
const MULT_B = 0x58f38ded;
const MIX_MULT_L = 0xca01f9dd;
const MIX_MULT_R = 0x4973f715;
const XSHIFT = 16;

/** The seed's 32-bit words, least significant first ([0] for 0), as numpy's _coerce_to_uint32_array. */
function seedWords(seed) {
  let s = BigInt(seed);
  if (s < 0n) throw new RangeError(`seed must be >= 0, got ${seed}`);
  const words = [];
  do {
    words.push(Number(s & MASK32));
    s >>= 32n;
  } while (s > 0n);
  return words;
}

/** SeedSequence(seed).generate_state(4, uint64) -> four BigInt words. */
export function seedSequenceState(seed) {
  const entropy = seedWords(seed);
  let hashConst = INIT_A;
  const hashmix = (value) => {
    value = (value ^ hashConst) >>> 0;
    hashConst = Math.imul(hashConst, MULT_A) >>> 0;
    value = Math.imul(value, hashConst) >>> 0;
    return (value ^ (value >>> XSHIFT)) >>> 0;
  };
  const mix = (x, y) => {
    const r = (Math.imul(MIX_MULT_L, x) - Math.imul(MIX_MULT_R, y)) >>> 0;
    return (r ^ (r >>> XSHIFT)) >>> 0;
  };
  const pool = new Array(POOL_SIZE);
  for (let i = 0; i < POOL_SIZE; i++) pool[i] = hashmix(i < entropy.length ? entropy[i] : 0);
  for (let src = 0; src < POOL_SIZE; src++) {
    for (let dst = 0; dst < POOL_SIZE; dst++) {
      if (src !== dst) pool[dst] = mix(pool[dst], hashmix(pool[src]));
    }
  }
  for (let src = POOL_SIZE; src < entropy.length; src++) {
    for (let dst = 0; dst < POOL_SIZE; dst++) pool[dst] = mix(pool[dst], hashmix(entropy[src]));
  }
  // generate_state: 8 uint32 words from the pool, read back as 4 little-endian uint64
  let hashB = INIT_B;
  const words32 = [];
  for (let i = 0; i < 2 * POOL_SIZE; i++) {
    let v = (pool[i % POOL_SIZE] ^ hashB) >>> 0;
    hashB = Math.imul(hashB, MULT_B) >>> 0;
    v = Math.imul(v, hashB) >>> 0;
    words32.push((v ^ (v >>> XSHIFT)) >>> 0);
  }
  const out = [];
  for (let i = 0; i < POOL_SIZE; i++) out.push((BigInt(words32[2 * i + 1]) << 32n) | BigInt(words32[2 * i]));
  return out;
}

export class PCG64 {
  /** @param {number|bigint} seed an integer >= 0 (numpy accepts any size; the runtime uses [0, 2**63)) */
  constructor(seed) {
    const [s0, s1, i0, i1] = seedSequenceState(seed);
    const initState = (s0 << 64n) | s1;
    const initSeq = (i0 << 64n) | i1;
    // pcg_setseq_128_srandom_r
    this.inc = ((initSeq << 1n) | 1n) & MASK128;
    this.state = 0n;
    this.#step();
    this.state = (this.state + initState) & MASK128;
    this.#step();
  }

  #step() { this.state = (this.state * PCG_MULTIPLIER + this.inc) & MASK128; }

  /** The next 64-bit output, as a BigInt. */
  nextUint64() {
    this.#step();
    const s = this.state;
    const xored = ((s >> 64n) ^ s) & MASK64;
    const rot = s >> 122n;
    return ((xored >> rot) | (xored << ((64n - rot) & 63n))) & MASK64;
  }

  /** A float64 in [0, 1), as numpy's Generator.random(). */
  random() { return Number(this.nextUint64() >> 11n) * 2 ** -53; }
}
