// Server mode (?server=ws://host:port&token=T): the motion comes from a `mogo serve` (docs/serve.md), which
// generates; this page only decodes. It opens the bundle's lookup and decoder graphs alone (MotionClient: no step
// graph, no text encoder, no tokenizer) on onnxruntime-web, connects with the runtime's ServerClient, and hands
// each character's frames to the page (app.js) as they are decoded.
//
// Decoding runs on the page's thread: a tick is one token (4 frames on the toy and base), a small decode, so no
// worker is needed. A dropped connection is resumed (reconnect: the server keeps a session's characters 30 s and
// sends what was missed), so nothing on screen is lost or repeated.

import * as ort from './node_modules/onnxruntime-web/dist/ort.wasm.min.mjs';
import { ConnectionClosed, MotionClient, ServerClient, ServerError, urlLoader } from '../js/src/index.js';

const RECONNECT_TRIES = 10, RECONNECT_SECONDS = 2;   // within the server's 30 s linger

export class Remote {
  /** The decoder of `variant` (the one the server runs) of the bundle at `bundleUrl`, connected to `url`. */
  static async connect({ url, token, bundleUrl, variant, onStatus }) {
    ort.env.wasm.wasmPaths = new URL('./node_modules/onnxruntime-web/dist/', import.meta.url).href;
    ort.env.wasm.numThreads = 1;
    onStatus(`loading the ${variant} lookup and decoder graphs of ${bundleUrl}`);
    const decoder = await MotionClient.load(urlLoader(bundleUrl), { variant, ort, providers: ['wasm'] });
    onStatus(`connecting to ${url}`);
    const client = await ServerClient.connect(url, token, { decoder });
    return new Remote(client, onStatus);
  }

  constructor(client, onStatus) {
    Object.assign(this, { client, onStatus, ident: null, text: null });
    this.removed = new Set();   // characters the page is done with: their last frames are dropped
    this.decoder = client.decoder;
  }

  /**
   * Hand frames over until the connection is given up: onFrames(ident, frames), onSwitch(text) when the server's
   * stream says the character follows a new prompt, onEnd(error) once (null: closed by the page).
   */
  async pump({ onFrames, onSwitch, onEnd }) {
    for (;;) {
      let item;
      try {
        item = await this.client.next();
      } catch (e) {
        if (!(e instanceof ConnectionClosed) || !(await this.#resume(e))) {
          onEnd(e);
          return;
        }
        continue;
      }
      // the page's character: the one it adds may send frames before add's reply has been handed over
      const [ident, frames] = item;
      if (this.removed.has(ident)) continue;
      onFrames(ident, frames);
      const text = this.decoder.characters.get(ident)?.text;   // its PROMPT events, as the decoder read them
      if (text !== undefined && text !== this.text) {
        this.text = text;
        onSwitch(text);
      }
    }
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

  /** The page's one character: added with `text` (the one before it removed). */
  async start(text, { seed, seconds }) {
    await this.stop();
    this.ident = await this.client.add(text, { seed, seconds });
    this.text = text;
    return this.ident;
  }

  async setPrompt(text) {
    if (this.ident !== null) await this.client.request(this.ident, { prompt: text });
  }

  async walkTo(goal) {
    if (this.ident !== null) await this.client.request(this.ident, { goal });
  }

  async stop() {
    const ident = this.ident, ended = this.ended;
    this.ident = null;
    if (ident === null) return;
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
