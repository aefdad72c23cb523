// Server mode (?server=ws://host:port&token=T): the motion comes from a `mogo serve` (docs/serve.md), which
// generates; this page only decodes. It opens the bundle's lookup and decoder graphs alone (MotionClient: no step
// graph, no text encoder, no tokenizer) on onnxruntime-web, connects with the runtime's ServerClient, and hands
// the page's character's frames to the screen (screen.js) as they are decoded.
//
// Decoding runs on the page's thread: a tick is one token (4 frames on the toy and base), a small decode, so no
// worker is needed. A dropped connection is resumed (reconnect: the server keeps a session's characters 30 s and
// sends what was missed), so nothing on screen is lost or repeated. A reloaded page takes its character back: the
// session and the character are kept in sessionStorage, and the server sends the character as a SYNC of where it
// is now (docs/serve.md), so the page shows it going on from there.

import * as ort from './node_modules/onnxruntime-web/dist/ort.wasm.min.mjs';
import { ConnectionClosed, MotionClient, ServerClient, ServerError, urlLoader } from '../js/src/index.js';
import { fail, page, receiveFrames, setBusy, showStream, status, streamOver } from './screen.js';

const RECONNECT_TRIES = 10, RECONNECT_SECONDS = 2;   // within the server's 30 s linger
const SAVED = 'mogo.server';   // sessionStorage: {url, session, ident, text, seed} of the page's character

/** What the page before a reload kept of its character on the server at `url`, or null. */
function saved(url) {
  try {
    const s = JSON.parse(sessionStorage.getItem(SAVED));
    return s?.url === url && typeof s.session === 'string' && Number.isInteger(s.ident) ? s : null;
  } catch {
    return null;   // not JSON: as if nothing was kept
  }
}

export class Remote {
  /** The decoder of `variant` (the one the server runs) of the bundle at `bundleUrl`, connected to `url`. */
  static async connect({ url, token, bundleUrl, variant, onStatus }) {
    ort.env.wasm.wasmPaths = new URL('./node_modules/onnxruntime-web/dist/', import.meta.url).href;
    ort.env.wasm.numThreads = 1;
    onStatus(`loading the ${variant} lookup and decoder graphs of ${bundleUrl}`);
    const decoder = await MotionClient.load(urlLoader(bundleUrl), { variant, ort, providers: ['wasm'] });
    onStatus(`connecting to ${url}`);
    const kept = saved(url);
    let client = null;
    if (kept !== null) {
      try {
        client = await ServerClient.connect(url, token, { decoder, session: kept.session });
      } catch (e) {
        if (!(e instanceof ServerError)) throw e;
        sessionStorage.removeItem(SAVED);
        onStatus(`the session before the reload is gone (${e.message}): starting a new one`);
      }
    }
    client ??= await ServerClient.connect(url, token, { decoder });
    const remote = new Remote(client, onStatus);
    if (kept !== null && client.session === kept.session && Object.hasOwn(client.welcome.characters, String(kept.ident))) {
      remote.kept = kept;
    }
    return remote;
  }

  constructor(client, onStatus) {
    Object.assign(this, { client, onStatus, ident: null, text: null, kept: null });
    this.removed = new Set();   // characters the page is done with: their last frames are dropped
    this.decoder = client.decoder;
  }

  /**
   * Show the page's character's frames until the connection is given up (then the stream is over, with the error on
   * the status line); a new prompt the server's stream names is marked where the page saw it.
   */
  async pump() {
    for (;;) {
      let item;
      try {
        item = await this.client.next();
      } catch (e) {
        if (!(e instanceof ConnectionClosed) || !(await this.#resume(e))) {
          if (page.stream) streamOver();
          fail(new Error(`the server's stream stopped: ${e.message}`));
          return;
        }
        continue;
      }
      // the page's character: the one it adds may send frames before add's reply has been handed over
      const [ident, frames] = item;
      const s = page.stream;
      if (this.removed.has(ident) || !s || (s.id !== null && s.id !== ident)) continue;
      s.id = ident;
      receiveFrames(frames.joints, frames.joints.length / (page.manifest.skeleton.parents.length * 3),
        { first: page.motion.frames.length === 0, tokens: this.client.nextSeq.get(ident) ?? 0 });
      const text = this.decoder.characters.get(ident)?.text;   // its PROMPT events, as the decoder read them
      if (text !== undefined && text !== this.text) {
        this.text = text;
        this.#switched(text);
      }
    }
  }

  #switched(text) {
    const m = page.motion;
    if (!m || text === m.texts[m.texts.length - 1]) return;
    // the token a PROMPT event names is the decoder's; the frame is where the page saw it (the switch is at or before it)
    m.switches.push({ token: null, text, frame: m.frames.length });
    m.texts.push(text);
    status(`now following "${text}" (from frame ${m.frames.length} on)`);
  }

  /** Reconnect after a drop, a few times; -> whether it worked. */
  async #resume(lost) {
    for (let i = 1; i <= RECONNECT_TRIES; i++) {
      this.onStatus(`${lost.message}; reconnecting (try ${i} of ${RECONNECT_TRIES})`);
      await new Promise((resolve) => setTimeout(resolve, RECONNECT_SECONDS * 1000));
      try {
        await this.client.reconnect();
        this.onStatus(`reconnected to ${this.client.url}: the frames missed meanwhile follow`);
        return true;
      } catch (e) {
        if (!(e instanceof ConnectionClosed)) throw e;   // refused (a fatal ServerError): trying again is no use
      }
    }
    return false;
  }

  /** The character the page had before a reload, on screen again from where it is now (call before `pump`). */
  takeBack() {
    const { ident, text } = this.kept, seed = /^\d+$/.test(this.kept.seed) ? BigInt(this.kept.seed) : 0n;
    showStream(text, seed, ident);
    Object.assign(this, { ident, text, kept: null });
    setBusy('streaming');
    status(`took "${text}" (seed ${seed}) back from the server after the reload: it goes on from where it is now`);
  }

  /** The page's character as a reloaded page finds it (`text`: the prompt it follows, or was just asked to). */
  #keep(text = this.text) {
    if (this.ident === null) sessionStorage.removeItem(SAVED);
    else {
      sessionStorage.setItem(SAVED, JSON.stringify({ url: this.client.url, session: this.client.session,
        ident: this.ident, text, seed: String(page.motion?.seed ?? 0) }));   // a BigInt: as text
    }
  }

  /** The page's one character, added with `text` (the one before it removed), on screen as its frames come. */
  async start(text, { seed, seconds }) {
    await this.stop();
    setBusy('streaming');
    status(`adding "${text}" (seed ${seed}) on the server...`);
    // on screen before add's reply: the character's first frames may come in the same turn as it
    const stream = showStream(text, seed, null);
    try {
      this.ident = await this.client.add(text, { seed, seconds });
    } catch (e) {   // refused (a limit, a blank prompt) or disconnected: no stream
      if (page.stream === stream) streamOver();
      throw e;
    }
    this.text = text;
    this.#keep();
    if (page.stream !== stream) return;   // stopped meanwhile
    stream.id = this.ident;
    status(`streaming "${text}" (seed ${seed}) from the server: type a new prompt and press Enter or "Set prompt"`);
  }

  async setPrompt(text) {
    if (this.ident === null) return;
    await this.client.request(this.ident, { prompt: text });
    this.#keep(text);   // this.text changes when the server's stream names the prompt (pump)
  }

  async walkTo(goal) {
    if (this.ident !== null) await this.client.request(this.ident, { goal });
  }

  async stop() {
    const ident = this.ident, ended = this.ended;
    this.ident = null;
    if (ident === null) return;
    this.#keep();
    this.removed.add(ident);
    if (ended) return;
    try {
      await this.client.remove(ident);
    } catch (e) {   // a refusal (its seconds ended meanwhile) leaves nothing to remove; a lost connection is pump's
      if (!(e instanceof ServerError) || e.fatal) throw e;
    }
  }

  /** Whether the character's stream ended on the server (its `seconds` are over): the decoder saw its END. */
  get ended() {
    return this.ident !== null && this.text !== null && this.client.nextSeq.has(this.ident)
      && !this.decoder.characters.has(this.ident);
  }
}
