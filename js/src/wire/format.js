// The token-stream format: a character's motion as the integers it is, for a client that decodes it
// (runtime/mogo_runtime/wire/format.py, which says why; docs/bundle.md, "Token streams"). Records, each
// self-delimiting, all integers little-endian:
//
//   HELLO   u8 1, "MOGT", u8 version, u8 levels, u16 codebook_size, u8 downsample, 8 bytes decoder id
//   TOKENS  u8 2, u32 character, u32 seq, u8 count, count * levels u16 codes      (seq: the first token's index)
//   EVENT   u8 3, u32 character, u32 seq, u8 event, u16 n, n bytes UTF-8 text       (seq: the token it applies from)
//   WARP    u8 4, u32 character, u32 frame, u16 frames, 5 f64: pose x, pose z, turn, shift x, shift z
//   JOINTS  u8 5, u32 character, u32 frame, u16 n, u8 joints, n * joints * 3 f32    (a server's, on request)
//   TICK    u8 6, u64 tick, f64 time     (a server's: which of its ticks a message holds, its clock in seconds)
//   SYNC    u8 7, u32 character, u32 seq, u8 pending, u8 rows, u16 n, u8 eases, u8 flags, rows * levels u16 codes,
//           n f32 decoder state, 20 f64 (root, foot lock, planted feet), eases * (u32 start, u16 frames, 8 f64)
//                                        (a character's decoder side at token seq, for a client without it)
//
// Records are classes, told apart with instanceof as Python's with isinstance; a TOKENS record's codes are a flat
// Int32Array (count, levels), as tokens everywhere in this runtime. Messages are the Python reader's, so both
// runtimes refuse a broken stream with the same words.

import { concat, sha256 } from '../bundle/io.js';
import { BundleError, DECODING_GRAPHS } from '../bundle/sections.js';
import { oneLine, shown } from '../checks.js';

export const MAGIC = 'MOGT';
export const VERSION = 1;
export const HELLO = 1, TOKENS = 2, EVENT = 3, WARP = 4, JOINTS = 5, TICK = 6, SYNC = 7;
export const START = 1, PROMPT = 2, CONTROL = 3, RESTART = 4, END = 5;   // events
export const EVENT_NAMES = Object.freeze({ [START]: 'start', [PROMPT]: 'prompt', [CONTROL]: 'control',
  [RESTART]: 'restart', [END]: 'end' });
export const MAX_TOKENS_PER_RECORD = 255;
export const MAX_TEXT_BYTES = 4096;   // an event's text: a prompt (at most 1,000 characters) or a control request as JSON

// the fixed part of each record, in bytes (Python's struct sizes: "<" packs without padding)
const HELLO_SIZE = 18, TOKENS_SIZE = 10, EVENT_SIZE = 12, WARP_SIZE = 51, JOINTS_SIZE = 12, TICK_SIZE = 17;
const SYNC_SIZE = 15, SYNC_FLOATS = 20, EASE_SIZE = 70;
export const MAX_EASES = 3;   // control/warp.js RootWarp keeps 3
// a SYNC's flags
export const TOES = 1, LEFT_CONTACT = 2, RIGHT_CONTACT = 4, WARPED = 8, LEFT_PINNED = 16, RIGHT_PINNED = 32;
const EASE_REALS = ['phi', 'tx', 'tz', 'turn', 'sx', 'sz', 'px', 'pz'];

/** A token stream that breaks the format, or one this client cannot decode. */
export class WireError extends Error {
  name = 'WireError';
}

export class Hello {
  /** `decoderId`: 8 bytes (Uint8Array). */
  constructor(levels, codebookSize, downsample, decoderId, version = VERSION) {
    Object.assign(this, { levels, codebookSize, downsample, decoderId, version });
  }
}

export class Tokens {
  /** `codes`: Int32Array (count, levels), row-major. */
  constructor(character, seq, codes, levels) {
    Object.assign(this, { character, seq, codes, levels });
  }

  get count() { return this.codes.length / this.levels; }
}

export class Event {
  constructor(character, seq, event, text = '') {
    Object.assign(this, { character, seq, event, text });
  }
}

export class Joints {
  /** `joints`: Float32Array (n, J, 3) row-major, `count` frames of `numJoints` joints (metres, y up). */
  constructor(character, frame, joints, numJoints) {
    Object.assign(this, { character, frame, joints, numJoints });
  }

  get count() { return this.joints.length / (3 * this.numJoints); }
}

export class Tick {
  /** `tick`: a BigInt (u64 on the wire); `time`: the server's clock, seconds. */
  constructor(tick, time) {
    Object.assign(this, { tick, time });
  }
}

export class Warp {
  /** `pose` [x, z], `shift` [x, z]: control/warp.js RootWarp.plan's arguments. */
  constructor(character, frame, frames, pose, turn, shift) {
    Object.assign(this, { character, frame, frames, pose, turn, shift });
  }
}

/**
 * A character's decoder side once its tokens before `seq` were pushed (format.py Sync): `window` Int32Array (rows,
 * levels) of the last min(seq, receptiveField + pending) tokens, the last `pending` without frames yet;
 * `decoderState` Float32Array, the decoder_step state arrays flattened in order; `root` 8 numbers (half-angle,
 * position x z, previous rot_vel vel_x vel_z, the foot lock's offset x z); `toes` [[x, z], [x, z]] or null;
 * `contacts` [left, right]; `warped` RootWarp.active; `eases` RootWarp's ({start, phi, ..., frames}); `pinned`
 * [left, right] and `plant` 8 numbers: RootWarp.plant's state (plant.js).
 */
export class Sync {
  constructor(character, seq, pending, window, levels, decoderState, root, toes, contacts, warped, eases, pinned,
    plant) {
    Object.assign(this, { character, seq, pending, window, levels, decoderState, root, toes, contacts, warped, eases,
      pinned, plant });
  }

  get rows() { return this.window.length / this.levels; }
}

/**
 * 8 bytes naming the lookup and decoder graphs of `variant`: equal ids decode tokens to the same frames. The
 * manifest's sha256 of each file (hex), joined, hashed: no graph is read for it.
 */
export async function decoderId(manifest, variant) {
  if (!Object.hasOwn(manifest.variants, variant)) {
    throw new BundleError(`unknown variant ${shown(variant)}; this bundle has `
      + `${oneLine(Object.keys(manifest.variants).join(', '), 200)}`);
  }
  const graphs = DECODING_GRAPHS.filter((g) => Object.hasOwn(manifest.variants[variant], g));
  const hexes = graphs.map((graph) => manifest.files[manifest.variants[variant][graph].file].sha256);
  return (await sha256(new TextEncoder().encode(hexes.join('')))).slice(0, 8);
}

/** The HELLO a stream of `variant`'s tokens starts with. */
export async function helloFor(manifest, variant) {
  const d = manifest.model;
  return new Hello(d.numLevels, d.codebookSize, d.downsample, await decoderId(manifest, variant));
}

/** One record's bytes (Uint8Array). */
export function encode(record) {
  if (record instanceof Tokens) {
    const { codes, levels } = record, count = codes.length / levels;
    if (!Number.isInteger(count) || count < 1 || count > MAX_TOKENS_PER_RECORD) {
      throw new WireError(`a TOKENS record holds 1 to ${MAX_TOKENS_PER_RECORD} tokens (count, levels), `
        + `got (${Number.isInteger(count) ? count : `${codes.length} codes`}, ${levels})`);
    }
    if (codes.some((c) => !Number.isInteger(c) || c < 0 || c > 0xFFFF)) throw new WireError('token codes are u16 on the wire');
    const w = new Writer(TOKENS_SIZE + 2 * codes.length);
    w.u8(TOKENS).u32(record.character).u32(record.seq).u8(count);
    for (const c of codes) w.u16(c);
    return w.bytes;
  }
  if (record instanceof Event) {
    // a lone surrogate has no UTF-8 (TextEncoder would put U+FFFD in its place, Python refuses it)
    const text = record.text.isWellFormed() ? new TextEncoder().encode(record.text) : null;
    if (text === null || text.length > MAX_TEXT_BYTES || !Object.hasOwn(EVENT_NAMES, record.event)) {
      throw new WireError(`an EVENT has a known event and at most ${MAX_TEXT_BYTES} bytes of text`);
    }
    const w = new Writer(EVENT_SIZE + text.length);
    w.u8(EVENT).u32(record.character).u32(record.seq).u8(record.event).u16(text.length);
    w.bytes.set(text, EVENT_SIZE);
    return w.bytes;
  }
  if (record instanceof Warp) {
    const w = new Writer(WARP_SIZE);
    w.u8(WARP).u32(record.character).u32(record.frame).u16(record.frames);
    for (const x of [...record.pose, record.turn, ...record.shift]) w.f64(x);
    return w.bytes;
  }
  if (record instanceof Joints) {
    const n = record.count, J = record.numJoints;
    if (!Number.isInteger(n) || n < 1 || n > 0xffff || !(J >= 1 && J <= 255)) {
      throw new WireError(`a JOINTS record holds (1 to 65535 frames, 1 to 255 joints, 3), got ${n} x ${J}`);
    }
    const w = new Writer(JOINTS_SIZE + 12 * n * J);
    w.u8(JOINTS).u32(record.character).u32(record.frame).u16(n).u8(J);
    for (let i = 0; i < record.joints.length; i++) w.view.setFloat32(JOINTS_SIZE + 4 * i, record.joints[i], true);
    return w.bytes;
  }
  if (record instanceof Tick) {
    const w = new Writer(TICK_SIZE);
    w.u8(TICK);
    w.view.setBigUint64(1, BigInt(record.tick), true);
    w.view.setFloat64(9, record.time, true);
    return w.bytes;
  }
  if (record instanceof Sync) return encodeSync(record);
  if (record instanceof Hello) {
    const w = new Writer(HELLO_SIZE);
    w.u8(HELLO);
    for (const c of MAGIC) w.u8(c.charCodeAt(0));
    w.u8(record.version).u8(record.levels).u16(record.codebookSize).u8(record.downsample);
    w.bytes.set(record.decoderId.subarray(0, 8), HELLO_SIZE - 8);   // as struct's "8s": cut or padded with zeros
    return w.bytes;
  }
  throw new TypeError(`not a record: ${record?.constructor?.name ?? typeof record}`);
}

function encodeSync(r) {
  const rows = r.rows, n = r.decoderState.length, eases = r.eases.length;
  if (!Number.isInteger(rows) || rows > 255 || n > 0xFFFF || !(eases >= 1 && eases <= MAX_EASES)) {
    throw new WireError(`a SYNC holds at most 255 window tokens, 65535 state values and 1 to ${MAX_EASES} eases`);
  }
  if (r.window.some((c) => !Number.isInteger(c) || c < 0 || c > 0xFFFF)) throw new WireError('token codes are u16 on the wire');
  const flags = (r.toes !== null ? TOES : 0) | (r.contacts[0] ? LEFT_CONTACT : 0) | (r.contacts[1] ? RIGHT_CONTACT : 0)
    | (r.warped ? WARPED : 0) | (r.pinned[0] ? LEFT_PINNED : 0) | (r.pinned[1] ? RIGHT_PINNED : 0);
  const w = new Writer(SYNC_SIZE + 2 * r.window.length + 4 * n + 8 * SYNC_FLOATS + EASE_SIZE * eases);
  w.u8(SYNC).u32(r.character).u32(r.seq).u8(r.pending).u8(rows).u16(n).u8(eases).u8(flags);
  for (const c of r.window) w.u16(c);
  for (const x of r.decoderState) w.f32(x);
  for (const x of [...r.root, ...(r.toes === null ? [0, 0, 0, 0] : r.toes.flat()), ...r.plant]) w.f64(x);
  for (const e of r.eases) {
    w.u32(e.start).u16(e.frames);
    for (const k of EASE_REALS) w.f64(e[k]);
  }
  return w.bytes;
}

/** Little-endian fields written one after another; a value out of its field's range is refused, as struct does. */
class Writer {
  constructor(size) {
    this.bytes = new Uint8Array(size);
    this.view = new DataView(this.bytes.buffer);
    this.at = 0;
  }

  #int(bits, value, set) {
    if (!Number.isInteger(value) || value < 0 || value >= 2 ** bits) {
      throw new RangeError(`a u${bits} field must be an int in [0, ${2 ** bits - 1}], got ${shown(value)}`);
    }
    set(value);
    this.at += bits / 8;
    return this;
  }

  u8(v) { return this.#int(8, v, (x) => this.view.setUint8(this.at, x)); }

  u16(v) { return this.#int(16, v, (x) => this.view.setUint16(this.at, x, true)); }

  u32(v) { return this.#int(32, v, (x) => this.view.setUint32(this.at, x, true)); }

  f32(v) {
    this.view.setFloat32(this.at, v, true);
    this.at += 4;
    return this;
  }

  f64(v) {
    this.view.setFloat64(this.at, v, true);
    this.at += 8;
    return this;
  }
}

/** The length of the record starting at data[at], or null when its length field is not in `data` yet. */
function recordSize(data, at, levels) {
  const kind = data[at];
  if (kind === TOKENS) return data.length < at + TOKENS_SIZE ? null : TOKENS_SIZE + 2 * levels * data[at + TOKENS_SIZE - 1];
  if (kind === EVENT) return data.length < at + EVENT_SIZE ? null : EVENT_SIZE + (data[at + 10] | (data[at + 11] << 8));
  if (kind === WARP) return WARP_SIZE;
  if (kind === JOINTS) {
    return data.length < at + JOINTS_SIZE ? null : JOINTS_SIZE + 12 * (data[at + 9] | (data[at + 10] << 8)) * data[at + 11];
  }
  if (kind === TICK) return TICK_SIZE;
  if (kind === SYNC) {
    if (data.length < at + SYNC_SIZE) return null;
    const rows = data[at + 10], n = data[at + 11] | (data[at + 12] << 8), eases = data[at + 13];
    return SYNC_SIZE + 2 * rows * levels + 4 * n + 8 * SYNC_FLOATS + EASE_SIZE * eases;
  }
  if (kind === HELLO) return HELLO_SIZE;
  throw new WireError(`byte ${at}: unknown record type ${kind}`);
}

const UTF8 = new TextDecoder('utf-8', { fatal: true, ignoreBOM: true });   // a BOM is text, as Python's "utf-8" keeps it

function decodeRecord(data, at, size, levels) {
  const view = new DataView(data.buffer, data.byteOffset, data.byteLength), kind = data[at];
  const u32 = (o) => view.getUint32(at + o, true), u16 = (o) => view.getUint16(at + o, true);
  if (kind === TOKENS) {
    const count = data[at + 9];
    if (count === 0) throw new WireError(`byte ${at}: a TOKENS record of no tokens`);
    const codes = new Int32Array(count * levels);
    for (let i = 0; i < codes.length; i++) codes[i] = u16(TOKENS_SIZE + 2 * i);
    return new Tokens(u32(1), u32(5), codes, levels);
  }
  if (kind === EVENT) {
    const event = data[at + 9], n = u16(10);
    if (!Object.hasOwn(EVENT_NAMES, event)) throw new WireError(`byte ${at}: unknown event ${event}`);
    if (n > MAX_TEXT_BYTES) throw new WireError(`byte ${at}: an event's text of ${n} bytes (at most ${MAX_TEXT_BYTES})`);
    let text;
    try {
      text = UTF8.decode(data.subarray(at + EVENT_SIZE, at + size));
    } catch {
      throw new WireError(`byte ${at}: an event's text is not UTF-8`);
    }
    return new Event(u32(1), u32(5), event, text);
  }
  if (kind === WARP) {
    const [px, pz, turn, sx, sz] = [0, 1, 2, 3, 4].map((i) => view.getFloat64(at + 11 + 8 * i, true));
    if (![px, pz, turn, sx, sz].every(Number.isFinite)) throw new WireError(`byte ${at}: a WARP of non-finite numbers`);
    return new Warp(u32(1), u32(5), u16(9), [px, pz], turn, [sx, sz]);
  }
  if (kind === TICK) {
    const when = view.getFloat64(at + 9, true);
    if (!Number.isFinite(when)) throw new WireError(`byte ${at}: a TICK at a non-finite time`);
    return new Tick(view.getBigUint64(at + 1, true), when);
  }
  if (kind === JOINTS) {
    const n = u16(9), J = data[at + 11], joints = new Float32Array(n * J * 3);
    for (let i = 0; i < joints.length; i++) joints[i] = view.getFloat32(at + JOINTS_SIZE + 4 * i, true);
    if (!n || !J || !joints.every(Number.isFinite)) {
      throw new WireError(`byte ${at}: a JOINTS record of no frames, no joints or non-finite numbers`);
    }
    return new Joints(u32(1), u32(5), joints, J);
  }
  if (kind === SYNC) return decodeSync(data, view, at, levels);
  const magic = data.subarray(at + 1, at + 5), version = data[at + 5];
  if (String.fromCharCode(...magic) !== MAGIC) {
    throw new WireError(`byte ${at}: not a mogo token stream (magic ${pythonBytes(magic)})`);
  }
  if (version !== VERSION) {
    throw new WireError(`byte ${at}: token-stream version ${version}; this client reads version ${VERSION}`);
  }
  return new Hello(data[at + 6], u16(7), data[at + 9], data.slice(at + 10, at + 18), version);
}

function decodeSync(data, view, at, levels) {
  const seq = view.getUint32(at + 5, true), pending = data[at + 9], rows = data[at + 10];
  const n = view.getUint16(at + 11, true), eases = data[at + 13], flags = data[at + 14];
  if (!(eases >= 1 && eases <= MAX_EASES) || flags > 63 || pending > rows || rows > seq) {
    throw new WireError(`byte ${at}: a SYNC of ${rows} window tokens (${pending} pending) at token ${seq} with `
      + `${eases} eases and flags ${flags}`);
  }
  let o = at + SYNC_SIZE;
  const window = new Int32Array(rows * levels);
  for (let i = 0; i < window.length; i++, o += 2) window[i] = view.getUint16(o, true);
  const state = new Float32Array(n);
  for (let i = 0; i < n; i++, o += 4) state[i] = view.getFloat32(o, true);
  const floats = [];
  for (let i = 0; i < SYNC_FLOATS; i++, o += 8) floats.push(view.getFloat64(o, true));
  const kept = [];
  for (let k = 0; k < eases; k++, o += EASE_SIZE) {
    const e = { start: view.getUint32(o, true) };
    EASE_REALS.forEach((key, i) => { e[key] = view.getFloat64(o + 6 + 8 * i, true); });
    e.frames = view.getUint16(o + 4, true);
    kept.push(e);
    floats.push(...EASE_REALS.map((key) => e[key]));
  }
  if (!floats.every(Number.isFinite) || !state.every(Number.isFinite)) {
    throw new WireError(`byte ${at}: a SYNC of non-finite numbers`);
  }
  const toes = flags & TOES ? [floats.slice(8, 10), floats.slice(10, 12)] : null;
  return new Sync(view.getUint32(at + 1, true), seq, pending, window, levels, state, floats.slice(0, 8), toes,
    [Boolean(flags & LEFT_CONTACT), Boolean(flags & RIGHT_CONTACT)], Boolean(flags & WARPED), kept,
    [Boolean(flags & LEFT_PINNED), Boolean(flags & RIGHT_PINNED)], floats.slice(12, 20));
}

/** Bytes as Python's repr writes them (b'MOGT', b'\x00...'), so the messages are Python's. */
function pythonBytes(bytes) {
  const quote = bytes.includes(39) && !bytes.includes(34) ? '"' : "'";
  const chars = Array.from(bytes, (b) => {
    if (b === 92 || String.fromCharCode(b) === quote) return `\\${String.fromCharCode(b)}`;
    const named = { 9: '\\t', 10: '\\n', 13: '\\r' }[b];
    if (named) return named;
    return b >= 32 && b < 127 ? String.fromCharCode(b) : `\\x${b.toString(16).padStart(2, '0')}`;
  });
  return `b${quote}${chars.join('')}${quote}`;
}

/**
 * Bytes of a stream as a plain Uint8Array: a WebSocket gives ArrayBuffers (binaryType 'arraybuffer'), Node Buffers,
 * whose slices would be Buffers (a HELLO's decoder id is a Uint8Array whatever came in).
 */
function asBytes(data) {
  if (data?.constructor === Uint8Array) return data;
  if (data instanceof ArrayBuffer) return new Uint8Array(data);
  if (ArrayBuffer.isView(data)) return new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  throw new TypeError('a token stream\'s bytes are a Uint8Array or an ArrayBuffer, got '
    + `${data?.constructor?.name ?? typeof data}`);
}

/**
 * Bytes in, whole records out: `feed(data)` -> the records completed by `data`. The levels per token come from the
 * stream's HELLO (`levels` until then, for a reader that knows them); a record cut short stays buffered.
 */
export class RecordReader {
  constructor(levels = null, maxBuffer = 1 << 20) {
    this.levels = levels;
    this.maxBuffer = maxBuffer;
    this.buffer = new Uint8Array(0);
    this.offset = 0;   // bytes consumed before the buffer, for messages
  }

  feed(data) {
    data = asBytes(data);
    const view = this.buffer.length ? concat([this.buffer, data]) : data;
    this.buffer = view;
    if (view.length > this.maxBuffer) {
      throw new WireError(`${view.length} bytes buffered without a whole record (at most ${this.maxBuffer})`);
    }
    const out = [];
    let at = 0;
    while (at < view.length) {
      if (view[at] !== HELLO && this.levels === null) {
        throw new WireError(`byte ${this.offset + at}: a ${view[at]} record before the stream's HELLO`);
      }
      const size = recordSize(view, at, this.levels || 0);
      if (size === null || at + size > view.length) break;
      let record;
      try {
        record = decodeRecord(view, at, size, this.levels || 0);
      } catch (e) {
        if (!(e instanceof WireError)) throw e;
        throw new WireError(`${e.message} (stream offset ${this.offset})`);
      }
      if (record instanceof Hello) this.levels = record.levels;
      out.push(record);
      at += size;
    }
    this.buffer = view.slice(at);   // a copy: the caller may reuse the bytes it fed
    this.offset += at;
    return out;
  }

  /** Bytes of a record not yet whole. */
  get pending() { return this.buffer.length; }
}

/** The records of one message that holds whole records (a WebSocket message); a cut record is an error. */
export function readMessage(data, levels = null) {
  data = asBytes(data);
  const reader = new RecordReader(levels, Math.max(data.length, 1));
  const records = reader.feed(data);
  if (reader.pending) throw new WireError(`the message ends inside a record (${reader.pending} bytes left over)`);
  return records;
}
