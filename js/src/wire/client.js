// A decode-only client: tokens in, frames out, with the bundle's decoding graphs alone (lookup, decoder,
// decoder_step; runtime/mogo_runtime/wire/client.py). It reads the manifest and those graphs, nothing else: no step graph,
// no text encoder, no tokenizer (on `base`'s compact variant 0.9 MB of graphs instead of 32 MB).
//
//   const client = await MotionClient.load('bundles/base', { variant: 'compact' });   // the tokens' variant
//   socket.binaryType = 'arraybuffer';
//   socket.onmessage = async ({ data }) => {                                           // token-stream records
//     for (const [ident, frames] of await client.receive(data)) show(ident, frames.joints);   // (n, J, 3) flat
//   };
//
// A character's frames are made as a generator makes them (decoding.js FrameMaker, then the root corrections of a
// steered character replayed from its WARP records), so they are the generating runtime's joints to float32
// rounding; a character joined late starts from the stream's SYNC of it. A game-owned root is not in the stream:
// each machine puts the frames on the capsule its game replicates.

import { Bundle } from '../bundle/folder.js';
import { concat, fileLoader, toHex } from '../bundle/io.js';
import { oneLine, shown } from '../checks.js';
import { legsOf } from '../control/plant.js';
import { RootWarp } from '../control/warp.js';
import { FrameMaker, MAX_CHUNK, checkChunk, decodeDue } from '../decoding.js';
import { MotionDecoder } from '../engine.js';
import {
  END, Event, Hello, PROMPT, RecordReader, START, Sync, Tokens, Warp, WireError, decoderId,
} from './format.js';

export const MAX_CHARACTERS = 100_000;   // characters one client follows at once

/** One character as a client knows it: its prompt, the next token it expects, its frames so far. */
class ClientCharacter {
  constructor(ident, text, frames, nextSeq, warp) {
    Object.assign(this, { ident, text, frames, nextSeq, warp, ended: false });
  }
}

export class MotionClient {
  /**
   * The client of `variant` (the one the tokens were generated with) of the bundle at `source`, a folder or a
   * loader (bundle/io.js). `chunk`: tokens per decode, as a generator's stream's (frames are the same whatever the
   * chunk); `ort`, `providers`, `threads`, `verifyHashes` as MotionGenerator.load.
   */
  static async load(source, { variant = 'fp32', threads = 1, chunk = 1, ort = null, providers, verifyHashes = true } = {}) {
    if (typeof variant !== 'string' || !variant) {
      throw new TypeError(`variant must be a variant name such as 'fp32' or 'compact', got ${shown(variant)}`);
    }
    checkChunk(chunk);
    const loader = typeof source === 'string' ? fileLoader(source) : source;
    const bundle = await Bundle.load(loader, { verifyHashes });
    const runtime = ort ?? (await import('onnxruntime-node'));
    const decoder = await MotionDecoder.open(bundle, variant, { ort: runtime, threads, providers });
    return new MotionClient(bundle, decoder, await decoderId(bundle.manifest, variant), chunk);
  }

  constructor(bundle, decoder, id, chunk = 1) {
    Object.assign(this, { bundle, decoder, id, chunk: checkChunk(chunk) });
    this.dims = bundle.manifest.model;
    this.skeleton = bundle.manifest.skeleton;
    this.legs = legsOf(this.skeleton);
    this.reader = new RecordReader();
    this.characters = new Map();   // ident -> ClientCharacter
    this.hello = null;
    this.busy = Promise.resolve();
  }

  /**
   * Bytes of the stream (whole records or not; Uint8Array or ArrayBuffer) -> Map ident -> the new frames
   * {index, features (n, D), joints (n, J, 3)} of each character they complete.
   */
  receive(data) {
    return this.#inTurn(() => this.#apply(this.reader.feed(data)));
  }

  /** Records (format.js) -> the new frames, as `receive`. */
  apply(records) {
    return this.#inTurn(() => this.#apply(records));
  }

  /**
   * Calls run one after another, in the order they were made: a WebSocket's onmessage does not wait for the last
   * message's frames, and two decodes of one character at once would interleave its window.
   */
  #inTurn(work) {
    const run = this.busy.then(work);
    this.busy = run.catch(() => {});   // a refused message is the caller's to handle; the next one still runs
    return run;
  }

  async #apply(records) {
    const out = new Map();   // ident -> the frames made, in chunks
    const waiting = new Map();   // tokens pushed, frames not made: decoded together at the end
    for (const record of records) {
      if (record instanceof Hello) {
        this.#hello(record);
      } else if (this.hello === null) {
        throw new WireError("a record before the stream's HELLO");
      } else if (record instanceof Tokens) {
        const c = this.#character(record.character);
        if (record.seq !== c.nextSeq) {
          throw new WireError(`character ${c.ident}: token ${record.seq} where ${c.nextSeq} was next `
            + `(${record.seq > c.nextSeq ? 'a token was lost' : 'a token came twice'})`);
        }
        if (record.codes.some((code) => code >= this.dims.codebookSize)) {
          throw new WireError(`character ${c.ident}: a code outside the codebook (${this.dims.codebookSize})`);
        }
        const L = record.levels;
        for (let t = 0; t < record.count; t++) {
          // its earlier tokens' frames first, alone: the maker holds only a window of tokens
          const n = c.frames.due();
          if (n) add(out, c.ident, await this.#frames(c, n));
          c.frames.push(record.codes.subarray(t * L, (t + 1) * L));
        }
        c.nextSeq += record.count;
        waiting.set(c.ident, c);
      } else if (record instanceof Warp) {
        const c = this.#character(record.character);
        await this.#flush(c, out);   // the frames before it were placed without it
        c.warp.plan(record.frame, record.frames, record.pose, record.turn, record.shift);
      } else if (record instanceof Sync) {
        this.#sync(record, out);
      } else if (record instanceof Event) {
        await this.#event(record, out);
      }
    }
    await this.#decode(waiting.values(), out);
    return new Map([...out].map(([ident, chunks]) => [ident, joined(chunks)]));
  }

  /** The frames due of many characters, one decoder call per number of tokens due (client.py `_decode`). */
  async #decode(characters, out) {
    const groups = new Map();
    for (const c of characters) {
      const n = c.frames.due();
      if (n && !c.ended) {
        if (!groups.has(n)) groups.set(n, []);
        groups.get(n).push(c);
      }
    }
    for (const [n, group] of groups) {
      const features = await decodeDue(this.decoder, group.map((c) => c.frames), n);
      const each = features.length / group.length;
      group.forEach((c, b) => {
        const frames = c.frames.framesFrom(features.subarray(b * each, (b + 1) * each));
        frames.joints = c.warp.joints(frames.index, frames.joints, this.skeleton.parents.length * 3);
        add(out, c.ident, frames);
      });
    }
  }

  #hello(hello) {
    const d = this.dims;
    if (hello.levels !== d.numLevels || hello.codebookSize !== d.codebookSize || hello.downsample !== d.downsample) {
      throw new WireError(`the stream's tokens are ${hello.levels} levels of ${hello.codebookSize} codes, `
        + `${hello.downsample} frames each; this bundle's are ${d.numLevels} of ${d.codebookSize}, ${d.downsample}`);
    }
    if (toHex(hello.decoderId) !== toHex(this.id)) {
      throw new WireError(`the stream was generated for decoder ${toHex(hello.decoderId)}, this client has `
        + `${toHex(this.id)} (${this.decoder.variant} of ${oneLine(this.bundle.where)}): open the bundle and `
        + 'variant the server runs');
    }
    this.hello = hello;
  }

  async #event(event, out) {
    if (event.event === START) {
      const old = this.characters.get(event.character);
      if (old !== undefined && !old.ended) throw new WireError(`character ${event.character} started twice`);
      if (this.characters.size >= MAX_CHARACTERS) throw new WireError(`more than ${MAX_CHARACTERS} characters in one stream`);
      const maker = new FrameMaker(this.dims, this.skeleton, this.chunk, this.decoder.decoderState);
      // frame numbers as the generator's (WARP records name frames); a character that started before the client
      // joined decodes from an empty window, at the origin, unless a SYNC of it follows
      maker.frames = event.seq * this.dims.downsample;
      this.characters.set(event.character, new ClientCharacter(event.character, event.text, maker, event.seq,
        new RootWarp(this.legs)));
      return;
    }
    const c = this.#character(event.character);
    if (event.event === PROMPT) {
      c.text = event.text;
    } else if (event.event === END) {
      await this.#flush(c, out);
      c.ended = true;
      this.characters.delete(c.ident);
    }
  }

  /** The character's decoder side from the generator's (client.py `_sync`): what it had here is dropped. */
  #sync(sync, out) {
    const c = this.#character(sync.character), d = this.dims, L = d.numLevels;
    if (out.has(c.ident)) throw new WireError(`character ${c.ident}: a SYNC after its frames in the same message`);
    const rows = Math.min(sync.seq, d.receptiveField + sync.pending);
    if (sync.pending > MAX_CHUNK || sync.rows !== rows) {
      throw new WireError(`character ${c.ident}: a SYNC at token ${sync.seq} holds ${sync.rows} window tokens `
        + `(${sync.pending} pending); ${rows} expected, at most ${MAX_CHUNK} pending`);
    }
    if (sync.window.some((code) => code >= d.codebookSize)) {
      throw new WireError(`character ${c.ident}: a code outside the codebook (${d.codebookSize})`);
    }
    const shapes = this.decoder.decoderState ?? [], size = shapes.reduce((a, [reach, ch]) => a + reach * ch, 0);
    if (sync.decoderState.length !== size) {
      throw new WireError(`character ${c.ident}: a SYNC of ${sync.decoderState.length} decoder state values; this `
        + `decoder's state has ${size}`);
    }
    const maker = new FrameMaker(d, this.skeleton, Math.max(this.chunk, sync.pending), this.decoder.decoderState);
    maker.chunk = this.chunk;   // the window holds the pending tokens, the chunk stays the client's
    maker.tokens.set(sync.window, maker.tokens.length - rows * L);
    Object.assign(maker, { count: sync.seq, pending: sync.pending, frames: (sync.seq - sync.pending) * d.downsample });
    if (maker.state) {
      let at = 0;
      maker.state = shapes.map(([reach, ch]) => sync.decoderState.slice(at, (at += reach * ch)));
    }
    const { root, lock } = maker.joints;
    [root.angle, root.x, root.z] = sync.root.slice(0, 3);
    root.previous = sync.root.slice(3, 6);
    [lock.x, lock.z] = sync.root.slice(6, 8);
    lock.previous = sync.toes === null ? null : { toe: sync.toes.map((t) => [...t]), contact: [...sync.contacts] };
    Object.assign(c, { frames: maker, nextSeq: sync.seq, warp: new RootWarp(this.legs) });
    c.warp.eases = sync.eases.map((e) => ({ ...e }));
    c.warp.active = sync.warped;
    c.warp.plant.load(sync.pinned, sync.plant);
  }

  #character(ident) {
    const c = this.characters.get(ident);
    if (c === undefined) throw new WireError(`character ${ident}: records before its START (or after its END)`);
    return c;
  }

  async #flush(c, out) {
    const n = c.frames.due(true);
    if (n) add(out, c.ident, await this.#frames(c, n));
  }

  async #frames(c, n) {
    const frames = c.frames.framesFrom(await decodeDue(this.decoder, [c.frames], n));
    frames.joints = c.warp.joints(frames.index, frames.joints, this.skeleton.parents.length * 3);
    return frames;
  }

  /** Free the decoder's native memory (the client cannot be used afterwards). */
  async release() { await this.decoder.release(); }
}

function add(out, ident, frames) {
  if (!out.has(ident)) out.set(ident, []);
  out.get(ident).push(frames);
}

function joined(chunks) {
  if (chunks.length === 1) return chunks[0];
  const all = (key) => concat(chunks.map((f) => f[key]));
  return { index: chunks[0].index, features: all('features'), joints: all('joints') };
}
