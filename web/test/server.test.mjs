// The page in server mode (?server=ws://...&token=...): a real `mogo serve` on the control toy's compact variant
// (started here, stopped however the file ends: js/test/until_eof.py), taking the page's origin only. The page
// fetches the manifest, the lookup and the decoder and nothing else, adds its character with the typed prompt, and
// shows the frames the Python decode-only client makes of those tokens (js/test/make_serve_reference.py); a new
// prompt is a request the server's stream acknowledges; a reloaded page takes its character back; the skeleton is
// on screen and moves.

import assert from 'node:assert/strict';
import { spawn, execFileSync } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, before, test } from 'node:test';

import { skeletonPixels } from './browser.mjs';
import { JOINT_TOLERANCE, OUT, PY, ROOT, WORK, open, session, useBrowser, waitState } from './session.mjs';

const BUNDLE = 'toy-control', VARIANT = 'compact', TOKEN = 'web-test-token-0123456789';
const folder = join(WORK, 'bundles', BUNDLE);
let server = null, ref = null;

useBrowser();

before(() => {   // the reference; the server starts in the test, once useBrowser's hook has served the page
  const dir = mkdtempSync(join(tmpdir(), 'mogo-serve-ref-'));
  try {
    execFileSync(PY, [join(ROOT, 'js/test/make_serve_reference.py'), '--out', dir, '--bundle', folder], { stdio: 'ignore' });
    ref = JSON.parse(readFileSync(join(dir, 'serve.json'), 'utf8'));
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

/** `mogo serve` on a free port, taking `origin` only; resolves once its first stderr line names its URL. */
function startServer(origin) {
  const proc = spawn(PY, [join(ROOT, 'js/test/until_eof.py'), PY, '-m', 'mogo_runtime.cli', 'serve', folder, '--variant',
    VARIANT, '--port', '0', '--status', '0', '--origin', origin],
  { env: { ...process.env, MOGO_SERVE_TOKEN: TOKEN }, stdio: ['pipe', 'inherit', 'pipe'] });
  server = { proc, url: null };
  return new Promise((resolve, reject) => {
    let err = '';
    proc.stderr.on('data', (chunk) => {
      err += chunk;
      const m = err.match(/ on (ws:\/\/\S+)/);
      if (m) resolve(server.url = m[1]);
    });
    proc.on('exit', (code) => reject(new Error(`mogo serve exited with ${code} before listening: ${err}`)));
  });
}

after(async () => {
  if (!server || server.proc.exitCode !== null || server.proc.signalCode !== null) return;   // gone already
  const exited = new Promise((resolve) => server.proc.on('exit', resolve));
  server.proc.stdin.end();   // until_eof.py stops the server
  await exited;
});

test('server mode: the page decodes a mogo serve\'s tokens to the Python client\'s frames', { timeout: 300_000 }, async () => {
  const { prompt, seed } = ref.prompts[0];
  await startServer(new URL(session.server.url).origin);   // the page's origin: the server takes no other
  const query = new URLSearchParams({ bundle: `/test-bundles/${BUNDLE}`, server: server.url, token: TOKEN, variant: VARIANT });
  const { page, problems } = await open(`${session.server.url}web/?${query}`);
  assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `the page did not load: ${problems.join('; ')}`);
  const state = await page.evaluate(() => window.mogoPage.state);
  assert.equal(state.server, server.url);
  assert.deepEqual(state.variants, [VARIANT]);
  assert.ok(await page.isDisabled('#generate'), 'Generate clip: a server streams only');
  const fetched = await page.evaluate(() => performance.getEntriesByType('resource').map((e) => e.name)
    .filter((u) => u.includes('/test-bundles/')).map((u) => u.split('/').pop()).sort());
  const manifest = JSON.parse(readFileSync(join(folder, 'manifest.json'), 'utf8'));
  const graphs = ['lookup', 'decoder', 'decoder_step'].filter((g) => Object.hasOwn(manifest.variants[VARIANT], g))
    .map((g) => manifest.variants[VARIANT][g].file);
  assert.equal(graphs.length, 3, 'the toy has a decoder_step graph: the page decodes with it');
  assert.deepEqual(fetched, ['manifest.json', ...graphs].sort(), 'the page fetched more than the decoder needs');

  await page.fill('#prompt', prompt);
  await page.fill('#seed', String(seed));
  const t0 = Date.now();
  await page.click('#stream');
  const want = ref.joints.frames;
  await waitState(page, (s, n) => s.busy === 'streaming' && s.frames >= n && s.shown >= 30, want);
  const waited = (Date.now() - t0) / 1000;
  const first = await page.locator('#view').screenshot({ path: join(OUT, 'server-1.png') });
  await page.waitForTimeout(400);
  const second = await page.locator('#view').screenshot({ path: join(OUT, 'server-2.png') });
  const motion = await page.evaluate(() => window.mogoPage.motion());
  const J3 = motion.joints.length / motion.numFrames;
  let worst = 0;
  for (let i = 0; i < want * J3; i++) worst = Math.max(worst, Math.abs(motion.joints[i] - ref.joints.data[i]));

  await page.fill('#prompt', 'a person jumps in place');
  await page.click('#set-prompt');
  await page.waitForFunction(() => window.mogoPage.motion().switches.length === 1, null, { timeout: 30_000 });
  // a reload: the page takes its character back from the server (a SYNC of where it is) and shows it going on
  const before = await page.evaluate(() => window.mogoPage.state);
  await page.reload();
  assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `the page did not load again: ${problems.join('; ')}`);
  await waitState(page, (s) => s.busy === 'streaming' && s.frames >= 20);
  const after = await page.evaluate(() => window.mogoPage.state), taken = await page.evaluate(() => window.mogoPage.motion());
  assert.equal(after.session, before.session, 'the same session after the reload');
  assert.deepEqual(taken.texts, ['a person jumps in place'], 'the character taken back follows its last prompt');
  await page.click('#stop');
  await waitState(page, (s) => s.busy === null);
  assert.equal(await page.evaluate(() => sessionStorage.getItem('mogo.server')), null, 'a stopped character is not kept');
  const pixels = await skeletonPixels(page, [first, second]);
  const stats = (await page.evaluate(() => window.mogoPage.state)).stats;
  console.log(`web: server mode (${BUNDLE}/${VARIANT} from mogo serve): fetched ${fetched.join(', ')} only; `
    + `${want} frames (${ref.joints.tokens} tokens) in ${waited.toFixed(1)} s after Stream (first frame `
    + `${stats.stream.firstFrameMs.toFixed(0)} ms), joints max |diff| ${worst.toExponential(1)} m from Python's decode-only `
    + `client; a new prompt acknowledged by the server's stream; after a reload the page took its character back `
    + `(${taken.numFrames} frames from its SYNC on, "${taken.texts[0]}"); skeleton ${pixels.shots.map((s) => s.skeleton)} px, `
    + `moved ${pixels.moved[0]} px`);
  assert.ok(worst <= JOINT_TOLERANCE, `the page's joints differ from Python's by ${worst} m`);
  assert.ok(pixels.shots.every((s) => s.skeleton > 100) && pixels.moved[0] > 0, 'the skeleton is not on screen, or still');
  assert.deepEqual(problems, [], 'errors in the page');
  await page.close();
});
