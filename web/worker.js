// The generator off the page's main thread: onnxruntime-web (wasm) and the JavaScript runtime (js/src) run here,
// so drawing and the orbit camera never wait for a step. The page (app.js) sends commands and receives frames:
//
//   page -> worker  {type: 'load', bundleUrl, variant, threads, wasmPaths}
//                   {type: 'probe', id, bundleUrl, variant, threads}   does this runtime run that variant?
//                   {type: 'generate', id, text, seed, seconds}        one clip, tokens and all frames at the end
//                   {type: 'stream', id, text, seed, ahead}            frames as they are decoded
//                   {type: 'played', id, frame}                        the page shows `frame`: produce up to frame + ahead
//                   {type: 'setPrompt', id, text}                      the stream follows `text` from its next token
//                   {type: 'walkTo', id, goal: [x, z]}                 the stream's character goes there (control)
//                   {type: 'stop', id}
//   worker -> page  {type: 'status', text} {type: 'loaded', id, ...} {type: 'probed', id, variant}
//                   {type: 'progress', id, step, limit}
//                   {type: 'clip', id, ...} {type: 'frames', id, start, joints, picked, ...} {type: 'switched', id, ...}
//                   {type: 'walking', id, goal, token, frame} {type: 'arrived', id, frame} {type: 'refused', id, message}
//                   {type: 'end', id, frames, busyMs, reason} {type: 'error', id, message, frames?}
//
// `picked` in frames: the token ids (flat, L per token) the stream picked since the last frames message, read from
// its context as it picks them (the page's test holds them to Python's).
//
// A stream answers exactly once when it is over: `end` with reason 'ended' (the model ended the motion) or
// 'stopped' (a stop, or a command that needs the sessions), or `error` with the exception's message; never `end`
// for an exception, so the page cannot show a failure as the model's choice.
//
// A prompt switch or a walkTo is applied between two frames of the stream, never while a step is in flight: the
// stream's setPrompt re-arms the context when its text embedding arrives, and a step already running would overwrite
// that; a walkTo made there lands at the next token, as the same request made between the same frames in Python.

import * as ort from './node_modules/onnxruntime-web/dist/ort.wasm.min.mjs';
import { MotionGenerator, urlLoader } from '../js/src/index.js';

let gen = null;
// Streams by id from their command's arrival until they are over, so a stop (or a prompt) sent while the command
// waits its turn, or while its prompt is encoded, is not lost:
// {id, stream, played, ahead, queued: [texts], goals: [[x, z]], stopped, wake}
const streams = new Map();

// Commands that use the sessions run one after another; the small ones act at once, between two frames of the
// stream. What the user asks for (load, generate, stream) first stops the stream. A probe does not: the page
// probes variants in the background after loading, while the user may already be streaming, and stopping the
// stream there ended every stream started in those seconds after its first frame. A probe waits its turn
// instead (an endless stream holds the sessions until it is stopped).
const TAKES_OVER = new Set(['load', 'generate', 'stream']);
let chain = Promise.resolve();

self.onmessage = (event) => {
  const msg = event.data;
  const fail = (e) => self.postMessage({ type: 'error', id: msg.id, message: describe(e) });
  if (Object.hasOwn(NOW, msg.type)) {
    NOW[msg.type](msg);
  } else if (Object.hasOwn(QUEUED, msg.type)) {
    if (TAKES_OVER.has(msg.type)) for (const me of streams.values()) stop(me);
    if (msg.type === 'stream') {
      streams.set(msg.id, { id: msg.id, stream: null, played: -1, ahead: msg.ahead, queued: [], goals: [], stopped: false,
        wake: null });
    }
    chain = chain.then(() => QUEUED[msg.type](msg)).catch(fail);
  } else {
    fail(new Error(`unknown command ${msg.type}`));
  }
};

const QUEUED = {
  async load({ id, bundleUrl, variant, threads, wasmPaths }) {
    if (gen) await gen.release();
    gen = null;
    ort.env.wasm.wasmPaths = wasmPaths;
    ort.env.wasm.numThreads = threads;
    const loader = urlLoader(bundleUrl, progressFetch);
    gen = await MotionGenerator.load(loader, { variant, threads, ort, providers: ['wasm'] });
    self.postMessage({ type: 'loaded', id, variant, endless: gen.endless, threads });
  },

  /** Whether this runtime runs a variant: load it beside the current one and generate one token. */
  async probe({ id, bundleUrl, variant, threads }) {
    const probe = await MotionGenerator.load(urlLoader(bundleUrl), { variant, threads, ort, providers: ['wasm'] });
    try {
      await probe.generate('a person walks forward', { seconds: probe.dims.downsample / probe.fps, seed: 0 });
    } finally {
      await probe.release();
    }
    self.postMessage({ type: 'probed', id, variant });
  },

  async generate({ id, text, seed, seconds }) {
    const t0 = performance.now();
    const motion = await gen.generate(text, { seed, seconds,
      onProgress: (step, limit) => self.postMessage({ type: 'progress', id, step, limit }) });
    const ms = performance.now() - t0;
    const joints = motion.joints.data, tokens = motion.tokens.data;
    self.postMessage({ type: 'clip', id, text, seed, fps: motion.fps, numFrames: motion.numFrames, ms,
      tokens, levels: motion.tokens.dims[1], joints }, [joints.buffer, tokens.buffer]);
  },

  async stream({ id, text, seed }) {
    const me = streams.get(id);
    try {
      if (!me.stopped) me.stream = await gen.stream(text, { seed });
    } catch (e) {
      streams.delete(id);
      throw e;
    }
    if (me.stopped) {
      streams.delete(id);
      self.postMessage({ type: 'end', id, frames: 0, busyMs: 0, reason: 'stopped' });
      return;
    }
    await produce(me);
  },
};

const NOW = {
  played({ id, frame }) {
    const me = streams.get(id);
    if (me) {
      me.played = Math.max(me.played, frame);
      wake(me);
    }
  },

  setPrompt({ id, text }) {
    const me = streams.get(id);
    if (me) {
      me.queued.push(text);
      wake(me);
    }
  },

  walkTo({ id, goal }) {
    const me = streams.get(id);
    if (me) {
      me.goals.push(goal);
      wake(me);
    }
  },

  stop({ id }) {
    const me = streams.get(id);
    if (me) stop(me);
  },
};

/** Pull frames while the page is less than `ahead` frames from the newest; switch prompts between frames. */
async function produce(me) {
  const J3 = gen.skeleton.parents.length * 3, fps = gen.fps;
  const it = me.stream[Symbol.asyncIterator]();
  let produced = 0, busyMs = 0, sent = 0, arrived = false;   // sent: tokens whose ids went to the page
  const batch = [];
  const flush = () => {
    if (!batch.length) return;
    const joints = new Float32Array(batch.length * J3), picked = pickedSince(me.stream, sent);
    batch.forEach((f, i) => joints.set(f, i * J3));
    sent = me.stream.tokens;
    self.postMessage({ type: 'frames', id: me.id, start: produced - batch.length, joints, count: batch.length,
      tokens: me.stream.tokens, picked, busyMs, fps }, [joints.buffer, picked.buffer]);
    batch.length = 0;
  };
  let reason = 'stopped', failure = null;   // failure: {error}, whatever was thrown
  try {
    while (!me.stopped) {
      while (me.queued.length) {   // the generator is suspended between two frames here: no step in flight
        const text = me.queued.shift();
        try {
          await me.stream.setPrompt(text);
        } catch (e) {   // a prompt the stream refuses (more actions than it plays, a duration out of range): it goes on
          self.postMessage({ type: 'refused', id: me.id, message: describe(e) });
          continue;
        }
        const sw = me.stream.switches[me.stream.switches.length - 1];
        self.postMessage({ type: 'switched', id: me.id, text, token: sw.token, frame: produced });
      }
      while (me.goals.length) {
        const goal = me.goals.shift();
        try {
          me.stream.walkTo(goal);
        } catch (e) {   // a request the stream refuses changes nothing: the stream goes on
          self.postMessage({ type: 'refused', id: me.id, message: describe(e) });
          continue;
        }
        arrived = false;
        self.postMessage({ type: 'walking', id: me.id, goal, token: me.stream.tokens, frame: produced });
      }
      if (me.stream.arrived && !arrived) {
        arrived = true;
        self.postMessage({ type: 'arrived', id: me.id, frame: produced });
      }
      if (produced - me.played > me.ahead) {
        flush();
        await new Promise((resolve) => { me.wake = resolve; });
        continue;
      }
      const t0 = performance.now();
      const { value, done } = await it.next();
      busyMs += performance.now() - t0;
      if (done) {
        reason = 'ended';
        break;
      }
      batch.push(value.joints);
      produced += 1;
      // hand the frames over at each chunk's end (the next call samples tokens), and let messages in
      if (produced === 1 || batch.length >= 4) {
        flush();
        await yieldToEvents();
      }
    }
  } catch (error) {
    failure = { error };
  }
  flush();   // the frames decoded before a failure are still motion
  streams.delete(me.id);
  try {
    await it.return?.();
  } catch (error) {
    failure ??= { error };
  }
  self.postMessage(failure ? { type: 'error', id: me.id, message: describe(failure.error), frames: produced }
    : { type: 'end', id: me.id, frames: produced, busyMs, reason });
}

/** The token ids (flat, L per token) `stream` picked from token `from` on, read from its context's recent tokens. */
function pickedSince(stream, from) {
  const context = stream.loop?.streams[0];
  if (!context) return new Int32Array(0);
  const L = context.policy.dims.numLevels, out = new Int32Array((context.count - from) * L);
  if (context.count - from > context.span) throw new Error(`${context.count - from} tokens picked between two frames messages`);
  for (let t = from; t < context.count; t++) {
    const slot = t % context.span;
    out.set(context.history.subarray(slot * L, (slot + 1) * L), (t - from) * L);
  }
  return out;
}

function stop(me) {
  me.stopped = true;
  wake(me);
}

function wake(me) {
  const w = me.wake;
  me.wake = null;
  w?.();
}

/** Let queued messages (played, setPrompt, stop) run: a task boundary, without setTimeout's clamping. */
function yieldToEvents() {
  return new Promise((resolve) => {
    const channel = new MessageChannel();
    channel.port1.onmessage = () => resolve();
    channel.port2.postMessage(null);
  });
}

/** fetch for urlLoader, reporting each file's download as it goes. */
async function progressFetch(url) {
  const response = await fetch(url);
  const name = decodeURIComponent(new URL(url).pathname.split('/').pop());
  const total = Number(response.headers.get('content-length')) || 0;
  let got = 0, last = 0;
  // the body as it downloads, reported on the way; the loader reads it and stops past the size the manifest gives
  const report = new TransformStream({
    transform(chunk, controller) {
      got += chunk.length;
      if (got - last > (1 << 20) || got === total) {
        last = got;
        self.postMessage({ type: 'status', text: `loading ${name}: ${mb(got)}${total ? ` of ${mb(total)}` : ''}` });
      }
      controller.enqueue(chunk);
    },
    flush() {
      self.postMessage({ type: 'status', text: `checking and opening ${name} (${mb(got)})` });
    },
  });
  return { ok: response.ok, status: response.status, headers: response.headers,
    body: response.body ? response.body.pipeThrough(report) : null };
}

function mb(bytes) {
  return bytes >= 1 << 20 ? `${(bytes / (1 << 20)).toFixed(1)} MB` : `${(bytes / 1024).toFixed(0)} KB`;
}

function describe(e) {
  return e && e.message ? `${e.name && e.name !== 'Error' ? `${e.name}: ` : ''}${e.message}` : String(e);
}
