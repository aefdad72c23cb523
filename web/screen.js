// What is on screen, shared by the page's two modes: the motion shown (a clip whole, or a stream whose frames are
// pushed as they arrive) in the viewer, the status line, and which controls are enabled. app.js drives it with the
// generator in worker.js; remote.js (server mode) with a `mogo serve`'s tokens, decoded on the page's thread.

import { SkeletonViewer } from './viewer.js';
import { GoalMarker, onGroundClick } from './walk.js';

export const $ = (id) => document.getElementById(id);

export const page = {
  server: false,       // server mode: the page decodes, it does not generate
  manifest: null,
  variant: null,
  endless: false,
  busy: null,          // 'loading' | 'generating' | 'streaming' | null
  mode: 'clip',        // the last of Generate clip / Stream pressed: what Enter does when no stream runs
  motion: null,        // on screen: {kind, texts, seed, variant, fps, tokens, levels, switches, frames[], picked[],
                       // walks: [{goal, token, frame}], arrivals: [frame]}
  stream: null,        // the stream running: {id, t0, firstMs, busyMs, tokens}
  runId: 0,
  shows: 0,            // motions put on screen so far
  stats: {},
  errors: [],
  renderFps: 0,
};

export const view = { viewer: null, marker: null };

/** The viewer for `skeleton`; a click on the ground calls onGround([x, z]) when given (bundles with control). */
export function openViewer(skeleton, onGround) {
  view.viewer = new SkeletonViewer($('view'), skeleton);
  view.marker = new GoalMarker(view.viewer.scene);
  if (onGround) onGroundClick(view.viewer, onGround);
}

/** Put a motion on screen (a clip whole, or a stream that frames will be pushed to). */
export function show(motion, live) {
  page.motion = motion;
  page.shows += 1;
  view.marker.hide();
  view.viewer.player.start({ fps: motion.fps, live });
  for (const f of motion.frames) view.viewer.player.push(f);
  view.viewer.player.playing = true;
  $('play').textContent = 'Pause';
}

/** A stream of `text` starts on screen, empty until its frames come: -> page.stream. */
export function showStream(text, seed, id) {
  show({ kind: 'stream', texts: [text], seed, variant: page.variant, fps: page.manifest.model.fps, tokens: null,
    levels: page.manifest.model.numLevels, switches: [], frames: [], picked: [], walks: [], arrivals: [] }, true);
  page.stream = { id, t0: performance.now(), firstMs: null, busyMs: 0, tokens: 0 };
  page.stats.stream = null;
  return page.stream;
}

/**
 * `count` frames of the running stream (joints flat), the first of them its frame 0 when `first`; `tokens` picked so
 * far; busyMs: the generator's time so far (null: since the first frame, for a server that sends in real time).
 */
export function receiveFrames(joints, count, { first, tokens, busyMs = null }) {
  const s = page.stream, player = view.viewer.player, J3 = page.manifest.skeleton.parents.length * 3;
  const now = performance.now();
  if (s.firstMs === null) s.firstMs = now - s.t0;
  for (let i = 0; i < count; i++) {
    const f = joints.subarray(i * J3, (i + 1) * J3);
    page.motion.frames.push(f);
    player.push(f);
  }
  if (first) setBusy(page.busy);   // the downloads have something to write now
  s.tokens = tokens;
  s.busyMs = busyMs ?? now - s.t0 - s.firstMs;
  const frames = page.motion.frames.length;
  page.stats.stream = { firstFrameMs: s.firstMs, frames, tokens: s.tokens, busyMs: s.busyMs,
    generatedFps: s.busyMs > 0 ? frames / (s.busyMs / 1000) : 0, stalls: player.stalls };
}

/** The stream is not running any more (stopped, ended or failed): what was received plays as a clip. */
export function streamOver() {
  page.stream = null;
  view.viewer.player.live = false;
  if (page.busy === 'streaming') setBusy(null);
}

export function setBusy(what) {
  page.busy = what;
  const loaded = page.variant !== null && what !== 'loading';
  $('generate').disabled = !loaded || what === 'generating' || page.server;   // a server streams only
  $('stream').disabled = !loaded || what === 'generating';
  $('set-prompt').disabled = what !== 'streaming' || !page.endless;
  $('stop').disabled = what !== 'streaming';
  $('variant').disabled = what === 'loading' || what === 'generating' || page.server;
  const hasMotion = () => page.motion && page.motion.frames.length > 0;
  $('download-bvh').disabled = !hasMotion();
  $('download-json').disabled = !hasMotion();
  $('progress').hidden = what !== 'generating';
  if (what === 'generating') $('progress').value = 0;
  document.body.dataset.busy = what ?? '';
}

export function status(text) {
  $('status').textContent = text;
  $('status').classList.remove('error');
}

export function fail(e) {
  console.error(e);
  page.errors.push(e.message);
  $('status').textContent = e.message;
  $('status').classList.add('error');
}
