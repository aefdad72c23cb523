// The page: pick a bundle variant, type a prompt, watch the skeleton move as frames stream in, change the prompt
// mid-stream, send the character where you click on the ground (bundles with control: walk.js), download BVH / JSON.
// Generation runs in worker.js; what is on screen (the motion, kept for the downloads in files.js, the status line)
// is screen.js's.
//
// URL parameters: bundle (a folder relative to the repository root, or an absolute URL; default bundles/base),
// variant (default compact where offered, else int8, else fp32), threads (onnxruntime-web threads; more than 1 only where the
// page is cross-origin isolated), prompt, seed.
//
// Server mode, `?server=ws://host:port&token=T` (remote.js): a `mogo serve` generates and the page decodes its
// tokens with the bundle's lookup and decoder alone (variant: the server's, default compact). No worker, no step
// graph, no text encoder: Stream adds the page's character, Set prompt and clicks are requests to the server.
//
// window.mogoPage is what the browser test reads (web/test/page.test.mjs): the motion on screen with its tokens (a
// stream's as they are picked), its walkTo requests, the camera, and the timings.

import { Bundle, WEIGHT_INT8, urlLoader } from '../js/src/index.js';
import { bvhText, download, fileStem, jsonText } from './files.js';
import { $, fail, openViewer, page, receiveFrames, setBusy, show, showStream, status, streamOver, view } from './screen.js';
import { cameraState } from './walk.js';

const AHEAD_SECONDS = 1;   // how far a stream is decoded ahead of what is shown: a new prompt shows within this
// Variants this runtime is known to run (its tests cover them, js/test and web/test): fp32, int8 made by dynamic
// quantization (run one row per call, runtime/mogo_runtime/engine.py), and compact (int8-stored weights, float32
// arithmetic: the tokens of the Python runtime, and the smallest download, so the page's default). Any other
// variant (e.g. `portable`, whose step graph has a fixed-size cache and a `position` input) is offered only once
// the worker has loaded it and generated a token with it here; otherwise the page names it and says why.
const KNOWN_VARIANTS = new Set(['fp32', 'int8', 'compact']);
const KNOWN_QUANTIZATION = new Set(['onnxruntime.quantize_dynamic', 'dynamic', WEIGHT_INT8]);
const DEFAULT_VARIANTS = ['compact', 'int8'];   // the first offered is loaded, else the first variant offered

const params = new URLSearchParams(location.search);
const root = new URL('../', import.meta.url);
const bundleParam = params.get('bundle') || 'bundles/base';
const bundleUrl = new URL(bundleParam.endsWith('/') ? bundleParam : `${bundleParam}/`, root).href;
const isolated = globalThis.crossOriginIsolated === true;
const threadsAsked = Math.max(1, Number.parseInt(params.get('threads') || '1', 10) || 1);
const threads = isolated ? Math.min(threadsAsked, navigator.hardwareConcurrency || 1) : 1;
const serverUrl = params.get('server');   // server mode
let remote = null;                        // server mode's Remote (remote.js), once connected

page.server = serverUrl !== null;
const worker = serverUrl ? null : new Worker(new URL('./worker.js', import.meta.url), { type: 'module' });
const waiting = new Map();   // message id -> {resolve, reject}, for generate and load

window.mogoPage = {
  ready: null,
  get state() {
    return { variant: page.variant, busy: page.busy, endless: page.endless, errors: page.errors.slice(),
      variants: [...$('variant').options].map((o) => o.value), frames: page.motion?.frames.length ?? 0,
      shown: view.viewer?.player.index ?? -1, shows: page.shows, stats: { ...page.stats }, renderFps: page.renderFps, threads, isolated,
      server: serverUrl, session: remote?.client.session ?? null };
  },
  /** The motion on screen: tokens (clips), the joints of every frame (flat, as the runtime gave them). */
  motion() {
    const m = page.motion;
    if (!m) return null;
    return { kind: m.kind, texts: m.texts, seed: String(m.seed), variant: m.variant, fps: m.fps,
      tokens: m.tokens ? Array.from(m.tokens) : null, levels: m.levels, switches: m.switches, picked: m.picked,
      walks: m.walks, arrivals: m.arrivals, joints: m.frames.flatMap((f) => Array.from(f)), numFrames: m.frames.length };
  },
  camera: () => cameraState(view.viewer),
};

// ---- loading --------------------------------------------------------------------------------------------

async function loadBundle() {
  setBusy('loading');
  status(`reading ${bundleUrl}manifest.json`);
  let bundle;
  try {
    bundle = await Bundle.load(urlLoader(bundleUrl), { verifyHashes: false });
  } catch (e) {
    throw new Error(`${e.message}\n\nPick a bundle with ?bundle=FOLDER (relative to the repository root); `
      + '`make demo` builds bundles/base.');
  }
  const m = bundle.manifest;
  page.manifest = m;
  page.endless = m.streaming !== null;
  const perToken = m.model.downsample / m.model.fps;
  $('bundle-info').textContent = `${bundleUrl.replace(root.href, '')}: ${m.skeleton.name} skeleton, ${m.model.numLevels}`
    + ` levels x ${m.model.codebookSize} codes, ${m.model.fps} fps, ${perToken} s per token, `
    + `${page.endless ? 'endless streams (prompt changes mid-stream)' : `clips up to ${m.model.maxSeconds} s`}; `
    + `${m.control && page.endless ? 'control (click the ground while streaming: the character walks there); ' : ''}`
    + `sampling ${describeSampling(m.samplingDefaults)}`;
  $('stream').textContent = page.endless ? 'Stream (endless)' : 'Stream';

  const known = Object.keys(m.variants).filter((v) => isKnown(m, v));
  const others = Object.keys(m.variants).filter((v) => !known.includes(v));
  const wanted = params.get('variant');
  const offered = wanted && others.includes(wanted) ? [...known, wanted] : known;   // asked for by name: tried
  $('variant').replaceChildren(...offered.map((v) => new Option(v, v)));

  openViewer(m.skeleton, m.control && page.endless ? walkTo : null);
  requestAnimationFrame(draw);
  const variant = offered.includes(wanted) ? wanted : DEFAULT_VARIANTS.find((v) => offered.includes(v)) ?? offered[0];
  await loadVariant(variant);
  await probeVariants(others.filter((v) => !offered.includes(v)));
}

/** Server mode: the decoder and the connection instead of the generator (remote.js). */
async function connectServer() {
  setBusy('loading');
  const variant = params.get('variant') || 'compact';
  const { Remote } = await import('./remote.js');   // onnxruntime-web on this thread: only in server mode
  const t0 = performance.now();
  remote = await Remote.connect({ url: serverUrl, token: params.get('token') ?? '', bundleUrl, variant, onStatus: status });
  const m = remote.decoder.bundle.manifest;
  page.manifest = m;
  page.endless = true;   // a server's characters go on until removed (or their seconds end)
  page.variant = variant;
  page.mode = 'stream';  // what Enter does when no stream runs: a server makes no clips
  page.stats.loadMs = performance.now() - t0;
  $('bundle-info').textContent = `server ${serverUrl} (session ${remote.client.session}): its tokens decoded here with `
    + `the ${variant} lookup and decoder of ${bundleUrl.replace(root.href, '')} (${m.skeleton.name} skeleton, ${m.model.fps} fps)`
    + `${m.control ? '; control (click the ground while streaming: the character walks there)' : ''}`;
  $('stream').textContent = 'Stream (from the server)';
  $('variant').replaceChildren(new Option(variant, variant));
  openViewer(m.skeleton, m.control ? walkTo : null);
  requestAnimationFrame(draw);
  setBusy(null);
  if (remote.kept) remote.takeBack();   // a reloaded page: its character, before the frames of its SYNC come
  else status(`connected to ${serverUrl} in ${(page.stats.loadMs / 1000).toFixed(1)} s: type a prompt and press Stream`);
  remote.pump();
}

function isKnown(manifest, variant) {
  return KNOWN_VARIANTS.has(variant)
    && Object.values(manifest.variants[variant]).every((g) => !g.quantization || KNOWN_QUANTIZATION.has(g.quantization.method));
}

/** Offer each variant of unknown make that loads and generates a token here; name the others with the reason. */
async function probeVariants(variants) {
  const notOffered = [];
  const note = (extra) => { $('variant-note').textContent = [extra, notOffered.length ? `not offered: ${notOffered.join('; ')}` : ''].filter(Boolean).join(' '); };
  for (const v of variants) {
    note(`checking whether this runtime runs the ${v} variant${page.stream ? ' (once the stream is stopped)' : ''}...`);
    try {
      await ask({ type: 'probe', bundleUrl, variant: v, threads });
      $('variant').append(new Option(v, v));
    } catch (e) {
      notOffered.push(`${v} (${e.message})`);
    }
  }
  note('');
}

async function loadVariant(variant) {
  stopStream();
  setBusy('loading');
  $('variant').value = variant;
  const t0 = performance.now();
  const wasmPaths = new URL('./node_modules/onnxruntime-web/dist/', import.meta.url).href;
  try {
    await ask({ type: 'load', bundleUrl, variant, threads, wasmPaths });
  } catch (e) {
    page.variant = null;
    setBusy(null);
    throw e;
  }
  page.variant = variant;
  page.stats.loadMs = performance.now() - t0;
  status(`${variant} loaded in ${(page.stats.loadMs / 1000).toFixed(1)} s (onnxruntime-web wasm, ${threads} thread`
    + `${threads > 1 ? 's' : ''}${threadsAsked > threads ? `; ${threadsAsked} asked, the page is not cross-origin isolated` : ''})`);
  setBusy(null);
}

/** Send a command that answers once (load, generate): resolves with the answer, rejects on an error. */
function ask(msg) {
  const id = ++page.runId;
  return new Promise((resolve, reject) => {
    waiting.set(id, { resolve, reject });
    worker.postMessage({ ...msg, id });
  });
}

// ---- generating -----------------------------------------------------------------------------------------

function readInputs() {
  const text = $('prompt').value;
  if (!text.trim()) throw new Error("type a prompt first, e.g. 'a person walks forward and then jumps'");
  const seedText = $('seed').value.trim() || '0';
  if (!/^\d+$/.test(seedText)) throw new Error(`the seed must be a whole number >= 0, got ${JSON.stringify(seedText)}`);
  const seed = BigInt(seedText);
  const secondsText = $('seconds').value.trim();
  const seconds = secondsText ? Number(secondsText) : null;
  if (seconds !== null && !(seconds > 0)) throw new Error(`seconds must be a positive number, or empty (the model decides)`);
  return { text, seed, seconds };
}

async function generateClip() {
  const { text, seed, seconds } = readInputs();
  page.mode = 'clip';
  stopStream();
  setBusy('generating');
  status(`generating "${text}" (seed ${seed})...`);
  const t0 = performance.now();
  try {
    const clip = await ask({ type: 'generate', text, seed, seconds });
    const J3 = page.manifest.skeleton.parents.length * 3;
    const frames = Array.from({ length: clip.numFrames }, (_, i) => clip.joints.subarray(i * J3, (i + 1) * J3));
    show({ kind: 'clip', texts: [text], seed, variant: page.variant, fps: clip.fps, tokens: clip.tokens,
      levels: clip.levels, switches: [], frames }, false);
    const ms = performance.now() - t0;
    page.stats.clip = { ms, frames: clip.numFrames, seconds: clip.numFrames / clip.fps, workerMs: clip.ms,
      tokens: clip.tokens.length / clip.levels };
    status(`"${text}": ${page.stats.clip.seconds.toFixed(1)} s of motion (${page.stats.clip.tokens} tokens) in `
      + `${(ms / 1000).toFixed(2)} s, ${(clip.numFrames / (ms / 1000)).toFixed(0)} frames/s`);
  } finally {
    setBusy(null);
  }
}

function startStream() {
  const { text, seed, seconds } = readInputs();
  page.mode = 'stream';
  stopStream();
  if (remote) return remote.start(text, { seed, seconds });
  const id = ++page.runId;
  showStream(text, seed, id);
  setBusy('streaming');
  status(`streaming "${text}" (seed ${seed})${page.endless ? ': type a new prompt and press Enter or "Set prompt"' : ''}`);
  worker.postMessage({ type: 'stream', id, text, seed, ahead: Math.round(AHEAD_SECONDS * page.manifest.model.fps) });
}

function setPrompt() {
  const text = $('prompt').value;
  if (!page.stream || !text.trim()) return;
  if (remote) remote.setPrompt(text).catch(fail);
  else worker.postMessage({ type: 'setPrompt', id: page.stream.id, text });
  status(`switching to "${text}" at the next token`);
}

/** Send the streaming character to `goal` [x, z] (from its next token), and mark the spot. */
function walkTo(goal) {
  if (!page.stream) {
    status('press Stream first: a click on the ground sends the streaming character there');
    return;
  }
  if (remote) remote.walkTo(goal).catch(fail);
  else worker.postMessage({ type: 'walkTo', id: page.stream.id, goal });
  view.marker.show(goal);
  status(`walking to (${goal[0].toFixed(2)}, ${goal[1].toFixed(2)}) from the next token`);
}

function stopStream() {
  if (!page.stream) return;
  if (remote) remote.stop().catch(fail);
  else worker.postMessage({ type: 'stop', id: page.stream.id });
  streamOver();
}

const onWorkerError = (event) => {   // the worker's script did not load or threw outside a command
  const e = new Error(`the generator's worker failed: ${event.message || 'its script could not be loaded'}`);
  for (const { reject } of waiting.values()) reject(e);
  waiting.clear();
  fail(e);
};

const onWorkerMessage = ({ data: msg }) => {
  const pending = waiting.get(msg.id);
  switch (msg.type) {
    case 'status':
      status(msg.text);
      break;
    case 'progress':
      $('progress').value = msg.step / msg.limit;
      break;
    case 'loaded':
    case 'probed':
    case 'clip':
      waiting.delete(msg.id);
      pending?.resolve(msg);
      break;
    case 'frames':
      if (page.stream?.id !== msg.id) break;
      page.motion.picked.push(...msg.picked);
      receiveFrames(msg.joints, msg.count, { first: msg.start === 0, tokens: msg.tokens, busyMs: msg.busyMs });
      break;
    case 'switched':
      if (page.stream?.id === msg.id) {
        page.motion.switches.push({ token: msg.token, text: msg.text, frame: msg.frame });
        page.motion.texts.push(msg.text);
        status(`now following "${msg.text}" (from token ${msg.token}, frame ${msg.frame})`);
      }
      break;
    case 'walking':
      if (page.stream?.id === msg.id) page.motion.walks.push({ goal: msg.goal, token: msg.token, frame: msg.frame });
      break;
    case 'arrived':
      if (page.stream?.id === msg.id) {
        page.motion.arrivals.push(msg.frame);
        status(`arrived (frame ${msg.frame}): the character stands there doing the prompt`);
      }
      break;
    case 'refused':
      fail(new Error(`the stream refused the request: ${msg.message}`));
      break;
    case 'end':
      if (page.stream?.id !== msg.id) break;   // a stream the page stopped itself
      streamOver();
      if (msg.reason === 'ended') status(`the stream ended after ${msg.frames} frames (the model ended the clip)`);
      else fail(new Error(`the stream stopped after ${msg.frames} frames without being asked to (worker: ${msg.reason})`));
      break;
    case 'error':
      waiting.delete(msg.id);
      if (pending) {
        pending.reject(new Error(msg.message));
      } else if (page.stream?.id === msg.id) {   // the running stream failed: it is over, and not as the model's end
        streamOver();
        fail(new Error(`the stream failed ${msg.frames ? `after ${msg.frames} frames` : 'before its first frame'}: ${msg.message}`));
      } else {
        fail(new Error(msg.message));
      }
      break;
    default:
      break;
  }
};

if (worker) {
  worker.onerror = onWorkerError;
  worker.onmessage = onWorkerMessage;
}

// ---- drawing --------------------------------------------------------------------------------------------

let lastTime = null, frameCount = 0, fpsSince = null, lastPlayed = -1;

function draw(now) {
  const dt = lastTime === null ? 0 : Math.min((now - lastTime) / 1000, 0.25);
  lastTime = now;
  view.viewer.follow = $('follow').checked;
  view.viewer.player.loop = $('loop').checked;
  view.viewer.frame(dt);
  const p = view.viewer.player;
  if (worker && page.stream && p.index !== lastPlayed) {   // tells the worker how far to decode ahead
    lastPlayed = p.index;
    worker.postMessage({ type: 'played', id: page.stream.id, frame: p.index });
  }
  if (remote?.ended && page.stream) {
    streamOver();
    status(`the character's seconds are over: the server ended its stream after ${page.motion.frames.length} frames`);
  }
  frameCount += 1;
  if (fpsSince === null) fpsSince = now;
  if (now - fpsSince >= 1000) {
    page.renderFps = (frameCount * 1000) / (now - fpsSince);
    frameCount = 0;
    fpsSince = now;
  }
  updateReadout();
  requestAnimationFrame(draw);
}

function updateReadout() {
  const p = view.viewer.player, m = page.motion;
  $('time').textContent = m ? `${(p.index / p.fps).toFixed(2)} s / ${(p.frames.length / p.fps).toFixed(2)} s`
    + ` (frame ${p.index + 1} of ${p.frames.length})` : '';
  const s = page.stats.stream, lines = [];
  if (s) {
    lines.push(`first frame ${s.firstFrameMs.toFixed(0)} ms`, `decoded ${s.generatedFps.toFixed(0)} frames/s `
      + `(${(s.generatedFps / p.fps).toFixed(1)}x real time)`, `${s.tokens} tokens`);
  }
  lines.push(`drawing ${page.renderFps.toFixed(0)} fps`);
  $('stats').textContent = lines.join(' · ');
}

// ---- controls -------------------------------------------------------------------------------------------

const guard = (fn) => async () => {
  try {
    await fn();
  } catch (e) {
    fail(e);
  }
  setBusy(page.busy);
};

function describeSampling(s) {
  const parts = [s.temperature === 0 ? 'greedy' : `temperature ${s.temperature}`];
  if (s.topK) parts.push(`top_k ${s.topK}`);
  if (s.topP !== null && s.topP !== undefined) parts.push(`top_p ${s.topP}`);
  if (s.guidance !== 1) parts.push(`guidance ${s.guidance}`);
  return parts.join(', ');
}

$('generate').onclick = guard(generateClip);
$('stream').onclick = guard(startStream);
$('set-prompt').onclick = guard(setPrompt);
$('stop').onclick = guard(stopStream);
$('variant').onchange = guard(() => loadVariant($('variant').value));
$('play').onclick = () => {
  if (!view.viewer) return;
  view.viewer.player.playing = !view.viewer.player.playing;
  $('play').textContent = view.viewer.player.playing ? 'Pause' : 'Play';
};
$('download-bvh').onclick = guard(() => download(bvhText(page.motion, page.manifest.skeleton),
  `${fileStem(page.motion)}.bvh`, 'text/plain'));
$('download-json').onclick = guard(() => download(jsonText(page.motion, page.manifest.skeleton, bundleParam),
  `${fileStem(page.motion)}.json`, 'application/json'));
// Enter: the running stream's new prompt (endless bundles); with none running, what the last button pressed did, so
// a stream that ended or failed is not silently followed by a clip
$('prompt').addEventListener('keydown', (e) => {
  if (e.key !== 'Enter') return;
  e.preventDefault();
  if (page.busy === 'streaming' && page.endless) guard(setPrompt)();
  else if (!page.busy) guard(page.mode === 'stream' ? startStream : generateClip)();
});

if (params.get('prompt')) $('prompt').value = params.get('prompt');
if (params.get('seed')) $('seed').value = params.get('seed');
setBusy('loading');
window.mogoPage.ready = (serverUrl ? connectServer() : loadBundle()).then(() => true, (e) => {
  fail(e);
  setBusy(null);
  return false;
});
