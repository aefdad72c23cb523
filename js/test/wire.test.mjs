// Token streams (js/src/wire/) against the Python runtime's (mogo_runtime/wire): a crowd's stream and a steered one,
// written by Python (test/make_wire_reference.py), decoded by the JavaScript client to Python's client's joints,
// with the lookup and decoder graphs alone; the same broken streams refused with the same messages.

import test from 'node:test';
import assert from 'node:assert/strict';
import { copyFileSync, mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { MotionGenerator } from '../src/generator.js';
import { fileLoader, toHex } from '../src/bundle/io.js';
import { DECODING_GRAPHS } from '../src/bundle/sections.js';
import { MotionDecoder, OrtBackend } from '../src/engine.js';
import { FootPlant, legsOf } from '../src/control/plant.js';
import { SKELETONS } from '../src/kinematics/skeleton.js';
import { MotionClient } from '../src/wire/client.js';
import {
  END, Event, Hello, Joints, PROMPT, RecordReader, Sync, Tick, Tokens, Warp, WireError, encode, readMessage,
} from '../src/wire/format.js';
import { maxAbsDiff, readReference, report } from './reference.mjs';

const ref = readReference('wire.json');
const streams = Object.fromEntries(ref.streams.map((s) => [s.name, s]));
const bytes = (b64) => new Uint8Array(Buffer.from(b64, 'base64'));
const messagesOf = (s) => s.messages.map(bytes);
const client = (s, chunk = 1) => MotionClient.load(s.bundle, { variant: s.variant, chunk });

/** The client on `messages` -> per message [[ident, index, frames], ...], and each character's joints joined. */
async function run(c, messages) {
  const received = [], joints = new Map(), frameSize = c.skeleton.parents.length * 3;
  for (const m of messages) {
    const out = await c.receive(m);
    received.push([...out].map(([ident, f]) => [ident, f.index, f.joints.length / frameSize]));
    for (const [ident, f] of out) joints.set(ident, [...(joints.get(ident) ?? []), ...f.joints]);
  }
  return { received, joints };
}

test("a decode-only client makes the Python client's joints, with the decoding graphs alone", async () => {
  let worst = 0, frames = 0;
  for (const s of ref.streams) {
    for (const want of s.runs) {
      const c = await client(s, want.chunk);
      assert.ok(c.decoder instanceof MotionDecoder && !(c.decoder instanceof OrtBackend));
      const decoding = DECODING_GRAPHS.filter((g) => Object.hasOwn(c.bundle.manifest.variants[c.decoder.variant], g));
      assert.deepEqual(Object.keys(c.decoder.sessions).sort(), decoding.sort());
      assert.equal(toHex(c.id), s.decoder_id, `${s.name}: decoder id`);
      const got = await run(c, messagesOf(s));
      assert.deepEqual(got.received, want.received, `${s.name}, chunk ${want.chunk}: frames per message`);
      assert.deepEqual([...got.joints.keys()].map(String).sort(), Object.keys(want.joints).sort());
      for (const [ident, joints] of got.joints) {
        worst = Math.max(worst, maxAbsDiff(joints, want.joints[ident]));
        frames += joints.length / (c.skeleton.parents.length * 3);
      }
      if (s.name === 'crowd') assert.ok(!c.characters.has(2), "the leaver's END freed it");
      await c.release();
    }
  }
  report(`token streams: ${ref.streams.length} streams (a crowd on compact, chunk 1 and 3; a steered crowd with WARP `
    + 'records on portable; a character joined late, from its SYNC, on each), '
    + `${frames} frames decoded from Python's messages: joints max |diff| ${worst.toExponential(1)} m`);
  assert.ok(worst <= 1e-5, `joints differ from Python's by ${worst} m`);
});

test("a steered character's WARP records are what places it", async () => {
  const s = streams.steered, records = new RecordReader().feed(Buffer.concat(messagesOf(s)));
  assert.ok(records.filter((r) => r instanceof Warp).length >= 20);
  const c = await client(s), raw = [];
  const out = await c.apply(records.filter((r) => !(r instanceof Warp)));
  raw.push(...out.get(0).joints);
  const want = s.runs[0].joints['0'], n = Math.min(raw.length, want.length);
  assert.ok(maxAbsDiff(raw.slice(0, n), want.slice(0, n)) > 1e-3);
  await c.release();
});

test('records cut anywhere are reassembled, and encode writes the bytes Python wrote', () => {
  for (const s of [streams.late, streams['late steered']]) {   // a SYNC's bytes, decoded and written again
    const late = Buffer.concat(messagesOf(s)), records = new RecordReader().feed(late);
    assert.ok(records[2] instanceof Sync && records[2].rows > 0, `${s.name}: START then SYNC after the HELLO`);
    assert.deepEqual(Buffer.concat(records.map(encode)), late);
  }
  const data = Buffer.concat(messagesOf(streams.crowd)), whole = new RecordReader().feed(data);
  assert.deepEqual(Buffer.concat(whole.map(encode)), data);
  const reader = new RecordReader(), records = [];
  for (let i = 0; i < data.length; i += 7) records.push(...reader.feed(data.subarray(i, i + 7)));
  assert.equal(reader.pending, 0);
  assert.deepEqual(Buffer.concat(records.map(encode)), data);
  // a message holds whole records: a cut one is an error
  assert.throws(() => readMessage(bytes(ref.cut.message), ref.cut.levels),
    (e) => e instanceof WireError && e.message === ref.cut.error);
});

test('records round-trip; what the wire cannot carry is refused', () => {
  const records = [new Hello(2, 16, 4, Uint8Array.from([1, 2, 3, 4, 5, 6, 7, 8])),
    new Tokens(3, 9, Int32Array.from([1, 2, 15, 0]), 2), new Event(3, 9, PROMPT, '\ufeffa person waves ✋'),
    new Event(3, 11, END), new Warp(3, 44, 4, [1.5, -2], 0.25, [0.01, 0]),
    new Joints(3, 44, Float32Array.from([0.5, 1, -2, 0, 0.25, 3]), 2), new Tick(2n ** 40n + 7n, 1234.5),
    new Sync(3, 12, 2, Int32Array.from([0, 1, 2, 3, 4, 5]), 2, Float32Array.from([-1, 0.5, 2]),
      [0, 1, 2, 3, 4, 5, 6, 7].map((x) => x / 3), [[0.1, 0.2], [-0.3, 0.4]], [true, false], true,
      [{ start: 0, phi: 0, tx: 0, tz: 0, turn: 0, sx: 0, sz: 0, px: 0, pz: 0, frames: 0 },
        { start: 40, phi: 0.5, tx: 1, tz: -1, turn: 0.25, sx: 0.01, sz: 0, px: 2, pz: 3, frames: 12 }],
      [false, true], [0, 1, 2, 3, 4, 5, 6, 7].map((x) => x / 9))];
  const back = readMessage(Buffer.concat(records.map(encode)));
  assert.deepEqual(back, records);   // the BOM is text, kept as Python keeps it
  assert.throws(() => encode(new Tokens(0, 0, new Int32Array(0), 2)),
    /a TOKENS record holds 1 to 255 tokens \(count, levels\), got \(0, 2\)/);
  assert.throws(() => encode(new Tokens(0, 0, Int32Array.from([70000, 0]), 2)), /token codes are u16 on the wire/);
  assert.throws(() => encode(new Event(0, 0, 99)), /an EVENT has a known event and at most 4096 bytes of text/);
  assert.throws(() => encode(new Event(0, 0, PROMPT, 'x'.repeat(4097))), WireError);
  assert.throws(() => encode(new Event(0, 0, PROMPT, '\ud800')), WireError);
  assert.throws(() => encode(new Tokens(-1, 0, Int32Array.from([1, 2]), 2)), RangeError);
  assert.throws(() => new RecordReader(2, 8).feed(new Uint8Array(9).fill(2)),
    /9 bytes buffered without a whole record \(at most 8\)/);
});

test('a decode-only client reads only the manifest and the decoding graphs', async () => {
  const s = streams.crowd, manifest = (await MotionClient.load(s.bundle, { variant: s.variant })).bundle.manifest;
  assert.ok(Object.hasOwn(manifest.variants[s.variant], 'decoder_step'), 'the lookup, the decoder and its step graph');
  const keep = ['manifest.json', ...DECODING_GRAPHS.map((g) => manifest.variants[s.variant][g].file)];
  const dir = mkdtempSync(join(tmpdir(), 'mogo-wire-'));
  try {
    for (const f of keep) copyFileSync(join(s.bundle, f), join(dir, f));
    const read = [], files = fileLoader(dir);
    const spy = { where: dir, readBytes: (name, most) => { read.push(name); return files.readBytes(name, most); } };
    const c = await MotionClient.load(spy, { variant: s.variant });
    assert.deepEqual(read.sort(), [...keep].sort());
    const got = await run(c, messagesOf(s).slice(0, 7));
    assert.ok(got.joints.size && [...got.joints.values()].every((j) => j.length && j.every(Number.isFinite)));
    await assert.rejects(MotionGenerator.load(dir, { variant: s.variant }), /missing/);
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

test("a broken stream is refused with the Python client's message", async () => {
  const s = streams.crowd, names = [];
  for (const broken of ref.broken) {
    const c = await client(s);
    await assert.rejects((async () => { for (const m of broken.messages) await c.receive(bytes(m)); })(),
      (e) => {
        assert.ok(e instanceof WireError, `${broken.name}: ${e}`);
        assert.equal(e.message, broken.error, broken.name);
        return true;
      });
    names.push(broken.name);
    await c.release();
  }
  for (const name of ['lost token', 'repeated token', 'no HELLO', 'bad magic', 'wrong version', 'wrong decoder id',
    'unknown record type', 'non-UTF-8 text', 'code outside codebook', 'non-finite WARP', 'SYNC state size',
    'SYNC window', 'SYNC no eases', 'SYNC non-finite']) assert.ok(names.includes(name), name);
  report(`token streams: ${names.length} broken streams refused with Python's messages, word for word`);
});

test("planted feet are Python's to the bit, in any chunks, with the same state", () => {
  const p = ref.plant, frameSize = p.joints * 3;
  const input = new Float32Array(bytes(p.input).buffer.slice(0));
  const want = new Float32Array(bytes(p.output).buffer.slice(0));
  const plant = new FootPlant(legsOf(SKELETONS.humanml3d)), out = [];
  let at = 0;
  for (const n of p.chunks) {
    out.push(plant.apply(input.slice(at * frameSize, (at + n) * frameSize), frameSize, p.moved.slice(at, at + n)));
    at += n;
  }
  const got = new Float32Array(input.length);
  out.reduce((o, chunk) => { got.set(chunk, o); return o + chunk.length; }, 0);
  assert.ok(p.changed > p.frames / 2, `the case planted too little (${p.changed} frames changed)`);
  assert.equal(maxAbsDiff(got, want), 0, 'planted joints differ from Python\'s');
  assert.deepEqual(plant.state(), [p.state.pinned, p.state.floats]);
  // and whole at once: the same
  assert.equal(maxAbsDiff(new FootPlant(legsOf(SKELETONS.humanml3d)).apply(input, frameSize, p.moved), want), 0);
  report(`planted feet: ${p.frames} frames (${p.changed} of them changed by the plant) equal to Python's bit for bit, in `
    + `chunks of 1 to 5 frames and whole`);
});
