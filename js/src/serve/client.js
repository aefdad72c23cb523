// A motion server's client (runtime/mogo_runtime/serve/client.py; the protocol: docs/serve.md), for a game or a
// page: add characters, send prompts and control requests, and receive their records; with a bundle, their frames
// too (decoded here, wire/client.js: the lookup and decoder graphs alone).
//
//   const c = await ServerClient.connect('ws://127.0.0.1:8765', token, { bundle: 'bundles/base', variant: 'compact' });
//   const walker = await c.add('a person walks forward', { seed: 1 });
//   await c.request(walker, { goal: [4.0, 2.0] });
//   for (;;) { const [ident, frames] = await c.next(); show(ident, frames.joints); }   // (n, J, 3) flat, metres
//
// `nextSeq` holds the next token expected of each character: `reconnect()` hands it to the server, which sends what
// was missed, so a dropped connection (or a server restarted on its saved state) loses and repeats nothing. A client
// that joins a session afresh (`connect(..., { session })`) names no character; the server sends each as a START and
// a SYNC of where it is now, and the frames go on from there. Requests (`request`, `joints`) are numbered and kept
// in `unapplied` until the server says it carried them out; `reconnect()` sends again those its welcome does not
// count, so one its server got in the tick it died in is not lost. A request while the connection is down throws
// ConnectionClosed (the caller decides what still matters once it reconnects).
//
// The socket is the global WebSocket (browsers, Node 22 and later; Node 20 has it behind --experimental-websocket)
// or the `WebSocket` option. Every message, text or binary, is handled in arrival order, one after another (the
// decoder is asynchronous here, synchronous in Python): so `nextSeq` always counts exactly the tokens whose records
// (or frames) are in the queue `next()` reads, as Python's reader does.

import { MotionClient } from '../wire/client.js';
import { Event, Hello, START, Sync, Tokens, readMessage } from '../wire/format.js';

const CLOSE_SECONDS = 10;   // as websockets' close_timeout: a peer that does not answer a close is left

/** The server refused a request (`fatal`: and closed the connection). */
export class ServerError extends Error {
  name = 'ServerError';

  constructor(message, fatal) {
    super(message);
    this.fatal = fatal;
  }
}

/**
 * The connection closed without the client asking (or could not open): what waits on `next()` or on a reply
 * gets it (Python's reader raises websockets' ConnectionClosedError there).
 */
export class ConnectionClosed extends Error {
  name = 'ConnectionClosed';

  constructor(message, code = null, reason = '') {
    super(message);
    Object.assign(this, { code, reason });
  }
}

/** An unbounded queue of values; `get()` waits for one (asyncio.Queue's put and get). */
class Queue {
  #items = [];
  #waiting = [];

  put(item) {
    const waiter = this.#waiting.shift();
    if (waiter) waiter(item);
    else this.#items.push(item);
  }

  get() {
    return this.#items.length ? Promise.resolve(this.#items.shift()) : new Promise((r) => this.#waiting.push(r));
  }

  /** Those waiting get `item`; what was queued is dropped. */
  drain(item) {
    for (const waiter of this.#waiting.splice(0)) waiter(item);
    this.#items.length = 0;
  }
}

export class ServerClient {
  #replies = new Queue();   // the server's JSON replies and ServerErrors, for add and remove
  #conn = null;             // {ws, ours, live, welcome, closed, failed}: the socket in use
  #turn = Promise.resolve();   // messages handled one after another
  #WebSocket;

  /** `decoder`: a MotionClient (wire/client.js), or null for the records themselves. */
  constructor(url, token, decoder = null, { origin = null, WebSocket = globalThis.WebSocket } = {}) {
    Object.assign(this, { url, token, decoder, origin });
    this.session = null;
    this.welcome = {};          // the server's last welcome (its "server" id: which replica; "synced")
    this.nextSeq = new Map();   // character -> the next token expected
    this.records = new Queue();   // [ident, frames] with a decoder, else records; errors where the stream broke
    this.errors = [];           // every ServerError the server sent
    this.levels = null;
    this.unapplied = new Map();   // request number -> the message, until the server applied it
    this.numbered = 0;            // the last request number used
    this.#WebSocket = WebSocket;
  }

  /**
   * Connect to the server at `url` (ws://...) with its bearer token. With `bundle` (a folder or a loader,
   * bundle/io.js), `next()` gives frames decoded with `variant`'s lookup and decoder, the variant the server runs
   * (`ort`, `providers`, `threads` as MotionClient.load); or pass a loaded MotionClient as `decoder`. `origin`: the
   * Origin header to send, where the WebSocket takes headers (Node's does; a browser sends its page's origin).
   * `session`: one another client had (a page reloaded): its characters come as a START and a SYNC of where they are.
   */
  static async connect(url, token, { bundle = null, variant = 'fp32', origin = null, decoder = null, ort, providers,
    threads, WebSocket, session = null } = {}) {
    const owned = decoder === null && bundle !== null;
    if (owned) decoder = await MotionClient.load(bundle, { variant, ort, providers, threads });
    const client = new ServerClient(url, token, decoder, { origin, WebSocket });
    client.session = session;
    try {
      await client.reconnect();
    } catch (e) {
      if (owned) await decoder.release();   // its native memory: the caller never gets the client to free it
      throw e;
    }
    return client;
  }

  /** Connect (again): a new session the first time, then the same one, from the tokens expected next. -> welcome */
  async reconnect() {
    if (this.#conn !== null) await this.close();
    // replies belong to the connection that got them: a stale error must not fail the next add
    this.#replies.drain(new ConnectionClosed('the connection closed before its reply came'));
    const conn = await this.#open();
    this.#conn = conn;
    const hello = { op: 'hello', token: this.token };
    if (this.session !== null) {
      hello.session = this.session;
      hello.resume = Object.fromEntries([...this.nextSeq].map(([ident, seq]) => [String(ident), seq]));
    }
    conn.ws.send(JSON.stringify(hello));
    let welcome;
    try {
      welcome = await conn.welcome;
      if (welcome?.op !== 'welcome') {
        throw new ServerError(welcome?.message ?? JSON.stringify(welcome), Boolean(welcome?.fatal));
      }
    } catch (e) {
      await this.close();
      throw e;
    }
    this.session = welcome.session;
    this.welcome = welcome;
    this.#applied(welcome.applied);
    this.numbered = Math.max(this.numbered, welcome.applied);   // a session another client numbered before
    // the requests not applied, in order, before any new one (the server skips a number below one it has applied)
    for (const message of this.unapplied.values()) conn.ws.send(message);
    conn.ready = true;
    return welcome;
  }

  #applied(n) {
    for (const k of [...this.unapplied.keys()]) if (k <= n) this.unapplied.delete(k);
  }

  /** A socket to `url`, open, its messages routed: the first (the welcome or an error) to `welcome`. */
  #open() {
    const WS = this.#WebSocket;
    if (typeof WS !== 'function') {
      throw new TypeError('no WebSocket here: browsers and Node 22 or later have one (Node 20: node '
        + '--experimental-websocket), or pass { WebSocket }');
    }
    // undici's WebSocket (Node's) takes a dictionary with headers; a browser's second argument is its protocols
    const ws = this.origin === null ? new WS(this.url) : new WS(this.url, { headers: { origin: this.origin } });
    ws.binaryType = 'arraybuffer';
    const conn = { ws, ours: false, live: false, failed: false, ready: false };
    let welcomed, refused, opened = false, problem = '';
    conn.welcome = new Promise((resolve, reject) => { welcomed = resolve; refused = reject; });
    conn.welcome.catch(() => {});   // awaited by reconnect only once the socket is open
    conn.closed = new Promise((resolve) => {
      ws.addEventListener('close', (e) => {
        resolve();
        const closed = new ConnectionClosed(`the connection to ${this.url} closed (code ${e.code}`
          + `${e.reason ? `: ${e.reason}` : ''})`, e.code, e.reason);
        refused(closed);   // no welcome came: reconnect says so
        if (conn.live && !conn.ours) this.#inTurn(conn, () => { throw closed; });
      });
    });
    let notOpened;   // rejects connect: a refused handshake fires error then close in browsers, error alone in Node 20
    ws.addEventListener('error', (e) => {
      problem = e.message || e.error?.message || '';
      if (!opened) notOpened();
    });
    ws.onmessage = ({ data }) => {
      if (welcomed !== null) {    // the first message: the welcome, or the error that refuses the hello
        const first = welcomed;
        welcomed = null;
        try {
          if (typeof data !== 'string') throw new ServerError('the server sent binary data before its welcome', true);
          const reply = parseReply(data);
          conn.live = reply?.op === 'welcome';   // from here on a close it did not ask for is the stream's end
          first(reply);
        } catch (e) {
          refused(e);
        }
        return;
      }
      this.#inTurn(conn, () => this.#receive(data));
    };
    return new Promise((resolve, reject) => {
      ws.addEventListener('open', () => { opened = true; resolve(conn); });
      notOpened = () => reject(new ConnectionClosed(`could not connect to ${this.url}${problem ? `: ${problem}` : ''}`));
      conn.closed.then(() => { if (!opened) notOpened(); });
    });
  }

  /** Run `work` after what came before it; the first failure ends the connection's stream (Python's reader). */
  #inTurn(conn, work) {
    this.#turn = this.#turn.then(async () => {
      if (!conn.failed) await work();
    }).catch((e) => this.#fail(conn, e));
  }

  /** The connection, or the stream it carried, broke: the caller sees `error` from next() and its next reply. */
  #fail(conn, error) {
    if (conn.failed) return;
    conn.failed = true;
    this.#replies.put(error);
    this.records.put(error);
    if (conn.ws.readyState <= 1) {   // a stream that cannot be read any more is not left queueing at the server
      conn.ours = true;
      conn.ws.onmessage = null;
      conn.ws.close(1000);
    }
  }

  async #receive(data) {
    if (typeof data === 'string') {
      const reply = parseReply(data);
      if (reply?.op === 'applied') {
        this.#applied(reply.n);
      } else if (reply?.op === 'error') {
        const error = new ServerError(reply.message, reply.fatal);
        this.errors.push(error);
        // only what a caller waits for: a refused request() is in `errors`, not the answer to the next add()
        if (reply.fatal || reply.about === 'add' || reply.about === 'remove') this.#replies.put(error);
      } else {
        this.#replies.put(reply);
      }
      return;
    }
    const records = readMessage(data, this.levels);
    for (const r of records) {
      if (r instanceof Hello) this.levels = r.levels;
      else if (r instanceof Tokens) this.nextSeq.set(r.character, r.seq + r.count);
      else if (r instanceof Sync) this.nextSeq.set(r.character, r.seq);   // moved on to where it is now
      else if (r instanceof Event && r.event === START && !this.nextSeq.has(r.character)) {
        this.nextSeq.set(r.character, r.seq);
      }
    }
    if (this.decoder === null) {
      for (const r of records) this.records.put(r);
    } else {
      for (const [ident, frames] of await this.decoder.apply(records)) this.records.put([ident, frames]);
    }
  }

  async #reply(op) {
    const reply = await this.#replies.get();
    if (reply instanceof Error) throw reply;
    if (reply?.op !== op) throw new ServerError(`expected ${op}, got ${JSON.stringify(reply)}`, false);
    return reply;
  }

  #send(message) {
    const ws = this.#conn?.ws;
    if (!ws || ws.readyState !== 1) {
      throw new ConnectionClosed(`not connected to ${this.url}${this.#conn ? '' : ' (closed; reconnect() first)'}`);
    }
    ws.send(message);
  }

  /** -> the new character's id. `seed`: an int in [0, 2**63), a BigInt past 2**53. `seconds`: null, endless. */
  async add(prompt, { seed = 0, seconds = null } = {}) {
    // written by hand: JSON.stringify refuses a BigInt, and a Number past 2**53 would send another seed
    this.#send(`{"op": "add", "prompt": ${JSON.stringify(prompt)}, "seed": ${seedText(seed)}, `
      + `"seconds": ${JSON.stringify(seconds)}}`);
    return (await this.#reply('added')).id;
  }

  /** A prompt and/or a control request: { prompt, goal, path, speed, velocity, facing, root, release }. */
  async request(ident, fields = {}) {
    this.#numbered({ op: 'request', id: ident, ...fields });
  }

  async joints(ident, on = true) {
    this.#numbered({ op: 'joints', id: ident, on });
  }

  /** Send `msg` with the next request number, kept until applied (during a reconnect(), sent by it). */
  #numbered(msg) {
    const conn = this.#conn;
    if (!conn || conn.failed || conn.ws.readyState > 1) {
      throw new ConnectionClosed(`not connected to ${this.url}${conn ? '' : ' (closed; reconnect() first)'}`);
    }
    this.numbered += 1;
    const message = JSON.stringify({ ...msg, n: this.numbered });
    this.unapplied.set(this.numbered, message);
    if (conn.ready) conn.ws.send(message);
  }

  async remove(ident) {
    this.#send(JSON.stringify({ op: 'remove', id: ident }));
    await this.#reply('removed');
  }

  /** The next [ident, frames] with a decoder, else the next record. */
  async next() {
    const item = await this.records.get();
    if (item instanceof Error) throw item;
    return item;
  }

  /** Stop reading and close. Messages not read yet are not counted in `nextSeq`: a reconnect asks for them again. */
  async close() {
    const conn = this.#conn;
    if (conn === null) return;
    this.#conn = null;
    conn.ours = true;
    conn.ws.onmessage = null;
    await this.#turn;   // what was read is decoded and queued first
    if (conn.ws.readyState <= 1) conn.ws.close(1000);
    let timer;
    await Promise.race([conn.closed, new Promise((resolve) => { timer = setTimeout(resolve, CLOSE_SECONDS * 1000); })]);
    clearTimeout(timer);
  }
}

function parseReply(text) {
  try {
    return JSON.parse(text);
  } catch {
    throw new ServerError(`the server sent text that is not JSON: ${text.slice(0, 80)}`, true);
  }
}

function seedText(seed) {
  if (typeof seed === 'bigint' ? seed >= 0n && seed < 2n ** 63n : Number.isSafeInteger(seed) && seed >= 0) {
    return String(seed);
  }
  throw new RangeError(`add: seed must be an int in [0, 2**63) (a BigInt past 2**53), got ${String(seed).slice(0, 40)}`);
}
