// The web page in a real headless Chromium (Debian's, driven by playwright-core), served by web/serve.py:
//   - for each bundle and variant, 3 clips generated through the page's controls have exactly the tokens the Python
//     runtime gives for the same prompts, seeds and sampling (web/test/reference.py);
//   - a stream whose prompt is changed mid-stream through the page gives the motion of Python's timeline that
//     switches at the same token; the screenshots show the skeleton (pixels of its colours) and it moves;
//   - the page's BVH and JSON downloads equal what runtime/mogo_runtime writes for the same joints;
//   - every bundle (toy, toy-variants, MOGO_WEB_BUNDLES) streams as a person streams it: Stream pressed as soon as it
//     is enabled, ENDLESS.seconds of motion shown (the page's clock run ahead), a new prompt with Enter, the status
//     never saying the stream ended; a stream whose worker throws is shown as an error, and only a stream the model
//     ended (toy-clips, no endless streams) says so; click to walk and controlled streams: control.test.mjs.
// Run by web/test/run.sh (make test-web), which builds the bundles and the reference; prints `web:` lines.

import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';

import { downloaded, rows, sharedPrefix, skeletonPixels } from './browser.mjs';
import { compareBvh } from './compare.mjs';
import { JOINT_TOLERANCE, OUT, PY, ROOT, bundleManifest, generate, open, reference, selectVariant, session,
  useBrowser, waitState } from './session.mjs';

const STREAM = { first: 'a person walks forward', then: 'a person jumps twice', seed: 5 };
const ENDLESS = { first: 'a person walks forward', then: 'a person turns left', seed: 3, seconds: 20, switchAt: 10 };

useBrowser();

for (const [name, bundle] of Object.entries(reference.bundles)) {
  test(`the page on the ${name} bundle: Python's tokens, a stream that changes prompt, the skeleton on screen, files`,
    { timeout: 600_000 }, async () => {
      const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/${name}`);
      assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `the page did not load: ${problems.join('; ')}`);
      const state = await page.evaluate(() => window.mogoPage.state);
      assert.deepEqual(state.variants.slice().sort(), bundle.variants.slice().sort(), 'variants offered');

      const exact = [];   // variants whose tokens must equal Python's
      for (const [variant, tokens] of Object.entries(bundle.tokens)) {
        await selectVariant(page, variant);
        const quantized = Object.values(bundle.quantized[variant]).some(Boolean);
        const strict = !quantized || name === 'toy';
        const loadMs = (await page.evaluate(() => window.mogoPage.state)).stats.loadMs;
        let compared = 0, identical = 0;
        const timings = [], prefixes = [];
        for (const [i, clip] of reference.clips.entries()) {
          const { motion, stats } = await generate(page, clip);
          assert.equal(motion.variant, variant);
          const got = rows(motion.tokens, motion.levels), want = tokens[i];
          const prefix = sharedPrefix(got, want);
          compared += want.length * motion.levels;
          identical += prefix * motion.levels;
          prefixes.push(`${prefix} of ${want.length}`);
          timings.push(`${stats.frames} frames in ${stats.ms.toFixed(0)} ms`);
          if (strict) {
            assert.deepEqual(got, want, `${name}/${variant}: tokens of "${clip.text}" seed ${clip.seed}`);
          } else {
            // Dynamic int8 quantizes each activation tensor by its range, so a last-bit difference between
            // onnxruntime-web's wasm kernels and the native ones can move a value into the next quantum: on real
            // models a logit then moves by ~0.1 at some step, and the samples part from there. The first token
            // step still has to agree.
            assert.ok(prefix >= 1, `${name}/${variant}: the first token of "${clip.text}" differs from Python's`);
          }
        }
        if (strict) exact.push(variant);
        console.log(`web: ${name}/${variant}: ${reference.clips.length} prompts, ${identical} of ${compared} token ids identical `
          + `to Python's${strict ? '' : ` (token steps before the first difference: ${prefixes.join(', ')}; quantized graphs, `
          + 'not held to exactness on this bundle)'} (loaded in ${(loadMs / 1000).toFixed(1)} s; clips: ${timings.join(', ')})`);
      }
      await checkFiles(page, `${name}-clip`);

      if (bundle.endless) {
        await selectVariant(page, exact[exact.length - 1]);   // a stream held to Python's motion
        await checkStream(page, name, bundle);
      }
      assert.deepEqual(problems, [], 'errors in the page');
      await page.close();
    });
}

test('variants of a make the page does not know are offered only where they run here', { timeout: 120_000 }, async () => {
  const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/toy-variants`);
  assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `the page did not load: ${problems.join('; ')}`);
  const state = await page.evaluate(() => window.mogoPage.state);
  assert.deepEqual(state.variants, ['fp32', 'int8', 'copy']);
  const note = await page.textContent('#variant-note');
  assert.match(note, /^not offered: broken \(.*broken\.onnx.*\)$/);
  await selectVariant(page, 'copy');
  const { motion } = await generate(page, reference.clips[0]);
  assert.deepEqual(rows(motion.tokens, motion.levels), reference.bundles.toy.tokens.fp32[0], 'copy = the fp32 graphs');
  console.log(`web: toy-variants: offered ${state.variants.join(', ')}; ${note}`);
  assert.deepEqual(problems.filter((p) => !p.includes('broken.onnx')), [], 'errors in the page');
  await page.close();
});

/** Stream, switch the prompt mid-stream, screenshot twice; the motion equals Python's timeline with that switch. */
async function checkStream(page, name, bundle) {
  const variant = (await page.evaluate(() => window.mogoPage.state)).variant;
  const fps = await page.evaluate(() => window.mogoPage.motion().fps);
  await page.fill('#prompt', STREAM.first);
  await page.fill('#seed', String(STREAM.seed));
  const shows = (await page.evaluate(() => window.mogoPage.state)).shows;
  await page.click('#stream');
  await waitState(page, (s, n) => s.shows > n && s.busy === 'streaming' && s.shown >= 30, shows);   // 1.5 s on screen
  const first = await page.locator('#view').screenshot({ path: join(OUT, `${name}-stream-1.png`) });
  await page.waitForTimeout(400);
  const second = await page.locator('#view').screenshot({ path: join(OUT, `${name}-stream-2.png`) });

  await page.fill('#prompt', STREAM.then);
  await page.click('#set-prompt');
  await page.waitForFunction(() => window.mogoPage.motion().switches.length === 1);
  const switched = (await page.evaluate(() => window.mogoPage.motion())).switches[0];
  await waitState(page, (s, f) => s.shown >= f + 30, switched.frame);   // the new prompt on screen for 1.5 s
  const third = await page.locator('#view').screenshot({ path: join(OUT, `${name}-stream-3.png`) });
  await page.screenshot({ path: join(OUT, `${name}-page.png`) });   // the whole page, controls and readouts
  await page.click('#stop');
  await waitState(page, (s) => s.busy === null);
  const state = await page.evaluate(() => window.mogoPage.state);
  const motion = await page.evaluate(() => window.mogoPage.motion());

  const pixels = await skeletonPixels(page, [first, second, third]);
  const area = pixels.width * pixels.height;
  pixels.shots.forEach((p, i) => {
    assert.ok(p.skeleton >= 400 && p.skeleton < area * 0.2, `screenshot ${i + 1}: ${p.skeleton} skeleton pixels of ${area}`);
    for (const side of ['left', 'right', 'centre']) assert.ok(p[side] >= 30, `screenshot ${i + 1}: ${p[side]} ${side} pixels`);
  });
  pixels.moved.forEach((m, i) => assert.ok(m >= 100, `screenshots ${i + 1} and ${i + 2}: only ${m} skeleton pixels changed`));

  // the frames equal Python's: a timeline that switches at the token where the page's switch landed
  assert.equal(motion.switches.length, 1);
  assert.equal(motion.switches[0].text, STREAM.then);
  const tokens = Math.ceil(motion.numFrames / bundle.downsample);
  const want = JSON.parse(execFileSync(PY, [join(ROOT, 'web/test/reference.py'), 'timeline', bundle.path, variant,
    String(STREAM.seed), String(tokens), STREAM.first, String(motion.switches[0].token), STREAM.then],
  { maxBuffer: 1 << 28, encoding: 'utf8' }));
  const n = motion.joints.length;
  assert.ok(want.joints.length >= n, `Python's timeline has ${want.joints.length / 66} frames, the page ${motion.numFrames}`);
  let err = 0;
  for (let i = 0; i < n; i++) err = Math.max(err, Math.abs(motion.joints[i] - want.joints[i]));
  assert.ok(err <= JOINT_TOLERANCE, `${name}: the stream's joints differ from Python's timeline by ${err} m`);
  const s = state.stats.stream;
  console.log(`web: ${name}/${variant} stream: first frame ${s.firstFrameMs.toFixed(0)} ms after Stream was pressed, `
    + `decoded ${s.generatedFps.toFixed(0)} frames/s (${(s.generatedFps / fps).toFixed(1)}x real time; ${s.frames} frames, `
    + `${s.tokens} tokens), drawn at ${state.renderFps.toFixed(0)} fps; prompt switched at token ${motion.switches[0].token}; `
    + `${motion.numFrames} frames within ${err.toExponential(1)} m of Python's timeline`);
  console.log(`web: ${name} screenshots: ${pixels.shots.map((p) => `${p.skeleton} skeleton pixels (left ${p.left}, right ${p.right}, `
    + `centre ${p.centre})`).join('; ')}; ${pixels.moved.join(' and ')} changed between shots; ${join(OUT, `${name}-stream-*.png`)}`);
  await checkFiles(page, `${name}-stream`);
}

/** The BVH and JSON downloads of the motion on screen equal what the Python runtime writes for its joints. */
async function checkFiles(page, what) {
  const motion = await page.evaluate(() => window.mogoPage.motion());
  const bvh = await downloaded(page, '#download-bvh');
  const json = JSON.parse(await downloaded(page, '#download-json'));
  const want = JSON.parse(execFileSync(PY, [join(ROOT, 'web/test/reference.py'), 'files', String(motion.fps)],
    { input: JSON.stringify({ joints: motion.joints, frames: motion.numFrames }), maxBuffer: 1 << 28, encoding: 'utf8' }));
  const r = compareBvh(bvh, want.bvh, `${what} BVH`);
  // the same numbers; JSON.stringify writes Python's -0.0 as 0, so compare after the same trip
  assert.deepEqual(json.frames, JSON.parse(JSON.stringify(want.json_frames)), `${what} JSON frames`);
  assert.equal(json.num_frames, motion.numFrames);
  assert.equal(json.fps, motion.fps);
  assert.equal(String(json.seed), motion.seed);
  assert.deepEqual(json.skeleton.joint_names.length, 22);
  if (motion.tokens) assert.deepEqual(json.tokens, rows(motion.tokens, motion.levels));
  console.log(`web: ${what} files: BVH ${r.identical} of ${r.lines} lines identical to bvh.py's (the rest within `
    + `${r.maxDiff.toExponential(1)}), JSON frames equal Motion.save's (${motion.numFrames} frames)`);
}

// A person opens the page and presses Stream as soon as it is enabled, while the page may still be checking the
// bundle's other variants in the background (streams started then used to end after one frame, shown as the model's
// end). The stream must run until stopped, follow a prompt typed with Enter, and never say it is over. The page's
// clock runs ahead whenever decoded frames wait to be shown, so the motion takes its decoding time, not its length.
// On a bundle of clips (no endless streams) the stream must end as the model ends it, and say so.
for (const name of [...Object.keys(reference.bundles), 'toy-variants']) {
  test(`the ${name} bundle streams through the page's controls: ${ENDLESS.seconds} s of motion, a new prompt with Enter`,
    { timeout: 600_000 }, async () => {
      const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/${name}`, { clock: true });
      const run = await startStreaming(page, name, ENDLESS, { early: true });
      if (bundleManifest(name).streaming) await streamEndlessly(page, run);
      else await checkModelEnds(page, run);
      // the variants not checked yet when Stream was pressed were checked once the stream stopped
      assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `${name}: the page did not finish loading`);
      assert.deepEqual(problems.filter((p) => !p.includes('broken.onnx')), [], `${name}: errors in the page`);
      await page.close();
    });
}

/** ENDLESS.seconds of motion shown, a new prompt typed with Enter at ENDLESS.switchAt, then Stop. */
async function streamEndlessly(page, run) {
  const { name } = run, fps = bundleManifest(name).model.fps;
  const streaming = (s) => {
    assert.deepEqual(s.errors, [], `${name}: errors at frame ${s.shown}`);
    assert.equal(s.busy, 'streaming', `${name}: the stream is not running at frame ${s.shown} of ${s.frames}: "${s.status}"`);
  };
  const before = await play(page, run, (s) => s.shown >= ENDLESS.switchAt * fps, streaming);
  await page.fill('#prompt', ENDLESS.then);
  await page.press('#prompt', 'Enter');
  const last = await play(page, run, (s) => s.shown >= ENDLESS.seconds * fps, streaming);
  const wallS = (Date.now() - run.t0) / 1000;
  const { switches, variant } = await page.evaluate(() => window.mogoPage.motion());
  const statuses = await page.evaluate(() => window.statusLog);
  assert.equal(switches.length, 1, `${name}: the prompt switch was not applied`);
  assert.equal(switches[0].text, ENDLESS.then);
  assert.ok(switches[0].frame >= before.shown, `${name}: switched at frame ${switches[0].frame}, before Enter`);
  assert.ok(statuses.some((t) => t.startsWith(`now following "${ENDLESS.then}"`)), `${name}: no acknowledgement in ${statuses.join(' / ')}`);
  assert.deepEqual(statuses.filter((t) => /ended|stopped|failed/.test(t)), [], `${name}: the status said the stream was over`);
  await page.click('#stop');
  await play(page, run, (s) => s.busy === null);
  const { tokens, generatedFps } = last.stats.stream;
  console.log(`web: ${name}/${variant} endless stream through the page's controls (Stream pressed `
    + `${run.note ? `while the page said ${JSON.stringify(run.note)}` : 'once the page loaded (no variant to check)'}): `
    + `${(last.shown / fps).toFixed(1)} s of motion shown (${last.frames} frames decoded, ${tokens} tokens) in `
    + `${wallS.toFixed(1)} s wall time, first frame ${run.firstAt - run.t0} ms after Stream; Enter at frame ${before.shown} `
    + `switched at token ${switches[0].token} (frame ${switches[0].frame}); the worker decoded ${generatedFps.toFixed(0)} `
    + 'frames/s; the status never said the stream was over');
}

test('a stream whose worker throws is shown as an error with its message, not as an end', { timeout: 120_000 }, async () => {
  // toy-failing's decoder gives NaN for more than one token: the first token's frames come, then the worker throws
  const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/toy-failing`, { clock: true });
  const failure = /^the stream failed after 4 frames: .*decoder\.onnx: the decoder graph produced NaN/;
  const run = await startStreaming(page, 'toy-failing', ENDLESS, { limitMs: 60_000 });
  let s = await play(page, run, (st) => st.busy !== 'streaming');
  assert.equal(s.errors.length, 1, `errors: ${s.errors.join('; ')}`);
  assert.match(s.errors[0], failure);
  assert.equal(s.status, s.errors[0], 'the status line shows the failure');
  assert.equal(await page.getAttribute('#status', 'class'), 'error');
  assert.equal(s.busy, null);
  assert.equal(s.frames, 4, 'the frames decoded before the failure are kept');
  for (const button of ['#stop', '#set-prompt']) assert.ok(await page.isDisabled(button), `${button} is enabled after the failure`);
  const statuses = await page.evaluate(() => window.statusLog);
  assert.deepEqual(statuses.filter((t) => /ended/.test(t)), [], 'the status said the stream ended');

  // Enter after a stream: a stream again (here failing again), not a clip
  await page.fill('#prompt', ENDLESS.then);
  await page.press('#prompt', 'Enter');
  const shows = s.shows;
  s = await play(page, run, (st) => st.shows === shows + 1 && st.busy === null);
  assert.equal((await page.evaluate(() => window.mogoPage.motion())).kind, 'stream', 'Enter after a stream made a clip');
  assert.equal(s.errors.length, 2);
  assert.match(s.errors[1], failure);

  await page.fill('#seconds', '2');   // 10 tokens, decoded at once: a clip fails, and says so
  await page.click('#generate');
  s = await play(page, run, (st) => st.busy === null && (st.errors.length > 2 || st.shows > shows + 1));
  assert.equal(s.errors.length, 3, 'Generate clip did not fail');
  assert.match(s.errors[2], /^(BundleError: )?decoder\.onnx: the decoder graph produced NaN/);
  assert.ok(problems.every((p) => p.includes('produced NaN')), `other errors in the page: ${problems.join('; ')}`);
  console.log(`web: toy-failing: a stream that throws after ${s.frames} frames: "${s.errors[0]}" in the status line (error), `
    + 'the stream not running; Enter streams again; Generate clip fails with the same message');
  await page.close();
});

test('a stream on a bundle without endless streams ends when the model ends it, and says so', { timeout: 120_000 }, async () => {
  const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/toy-clips`, { clock: true });
  await checkModelEnds(page, await startStreaming(page, 'toy-clips', ENDLESS, { limitMs: 60_000 }));
  assert.deepEqual(problems, [], 'errors in the page');
  await page.close();
});

test('Stop pressed while a stream waits for a variant check: nothing streams, the checks finish', { timeout: 120_000 }, async () => {
  const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/toy-variants`, { clock: true });
  const run = await startStreaming(page, 'toy-variants', ENDLESS, { early: true, stop: true });
  assert.match(run.note, /^checking/, 'Stream was pressed while the page checked a variant');
  const ready = await page.evaluate(() => Promise.race([window.mogoPage.ready,
    new Promise((resolve) => { setTimeout(() => resolve('still checking after 60 s'), 60_000); })]));
  assert.equal(ready, true, 'the variant checks did not finish: a stream stopped before it started still holds the worker');
  await page.waitForTimeout(500);   // a stream that started anyway would show frames by now
  const s = await page.evaluate(() => window.mogoPage.state);
  assert.deepEqual([s.busy, s.frames, s.errors], [null, 0, []]);
  assert.deepEqual(s.variants, ['fp32', 'int8', 'copy']);
  assert.deepEqual(problems.filter((p) => !p.includes('broken.onnx')), [], 'errors in the page');
  await page.close();
});

/**
 * Type the prompt and seed, press Stream; every text of the status line from then on goes to window.statusLog.
 * `early`: press it as soon as a person can, in the page itself (a variant check on the toy bundles lasts a fraction
 * of a second, too short to catch from outside): while the page says it checks a variant of unknown make, else
 * once loaded. Otherwise once loaded. `stop`: press Stop right after Stream, in the same task.
 */
async function startStreaming(page, name, { first, seed }, { early = false, stop = false, limitMs = 300_000 } = {}) {
  await page.fill('#prompt', first);
  await page.fill('#seed', String(seed));
  if (!early) assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `${name}: the page did not load`);
  const t0 = Date.now();
  const note = await page.evaluate(([atCheck, thenStop]) => new Promise((resolve) => {
    const button = document.getElementById('stream'), note = document.getElementById('variant-note');
    const status = document.getElementById('status');
    let pressed = false;
    const press = () => {
      if (pressed) return;
      pressed = true;
      observer.disconnect();
      window.statusLog = [];
      new MutationObserver(() => window.statusLog.push(status.textContent))
        .observe(status, { childList: true, characterData: true, subtree: true });
      button.click();
      if (thenStop) document.getElementById('stop').click();
      resolve(note.textContent);
    };
    const check = () => { if (atCheck && !button.disabled && note.textContent.startsWith('checking')) press(); };
    const observer = new MutationObserver(check);
    observer.observe(document.body, { subtree: true, childList: true, characterData: true, attributes: true });
    check();
    window.mogoPage.ready.then(press);
  }), [early, stop]);
  return { name, note, t0, firstAt: null, deadline: t0 + limitMs };
}

/** A stream on a bundle of clips: over when the model ends the motion, said as such, nothing shown as an error. */
async function checkModelEnds(page, run) {
  const s = await play(page, run, (st) => st.busy === null);
  assert.deepEqual(s.errors, [], `${run.name}: errors`);
  assert.match(s.status, new RegExp(`^the stream ended after ${s.frames} frames \\(the model ended the clip\\)$`));
  assert.ok(s.frames > 0);
  console.log(`web: ${run.name} (no endless streams): the stream ended after ${s.frames} frames and the page says the model ended it`);
}

/** Poll the page until `until(state)`, running its clock one animation frame ahead whenever frames wait to be shown. */
async function play(page, run, until, check = () => {}) {
  for (;;) {
    const s = await page.evaluate(() => ({ ...window.mogoPage.state, status: document.getElementById('status').textContent }));
    if (s.frames > 0) run.firstAt ??= Date.now();
    check(s);
    if (until(s)) return s;
    assert.ok(Date.now() < run.deadline, `${run.name}: timed out at frame ${s.shown} of ${s.frames}: "${s.status}"`);
    if (s.frames - 1 > s.shown) await page.clock.fastForward(250);   // the player moves at most 0.25 s per frame drawn
    else await new Promise((resolve) => { setTimeout(resolve, 20); });   // the worker is decoding
  }
}

// The golden tokens (tests/golden/toy.json) in the browser: the JavaScript runtime on onnxruntime-web (wasm) in
// the page's own context, every golden case on the toy bundle (prompts of several actions and streams with prompt
// switches too, read as Node reads them: js/test/golden_case.mjs), exactly the stored tokens.
test('the browser gives the golden tokens', { timeout: 300_000 }, async () => {
  assert.ok(reference.bundles.toy, 'the toy bundle is served');
  const golden = JSON.parse(readFileSync(join(ROOT, 'tests/golden/toy.json'), 'utf8'));
  const manifest = JSON.parse(readFileSync(join(reference.bundles.toy.path, 'manifest.json'), 'utf8'));
  for (const [file, sha256] of Object.entries(golden.files)) {
    assert.equal(manifest.files[file]?.sha256, sha256, `${file}: the toy bundle changed since tests/golden/toy.json was written`);
  }
  const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/toy`);
  const result = await page.evaluate(async (cases) => {
    const ort = await import('/web/node_modules/onnxruntime-web/dist/ort.wasm.min.mjs');
    ort.env.wasm.wasmPaths = '/web/node_modules/onnxruntime-web/dist/';
    ort.env.wasm.numThreads = 1;
    const { MotionGenerator, urlLoader } = await import('/js/src/index.js');
    const { runGoldenCase, sameAsGolden } = await import('/js/test/golden_case.mjs');
    const { samplingOf } = await import('/js/test/control_case.mjs');
    const gens = {};
    const wrong = [];
    let steps = 0;
    for (const [i, c] of cases.entries()) {
      gens[c.variant] ??= await MotionGenerator.load(urlLoader('/test-bundles/toy/'), { ort, variant: c.variant, threads: 1 });
      const got = await runGoldenCase(gens[c.variant], c, samplingOf(c.sampling));
      steps += c.tokens.reduce((n, t) => n + t.length, 0);
      if (!sameAsGolden(got, c)) wrong.push(i);
    }
    return { wrong, steps };
  }, golden.cases);
  console.log(`web: golden: ${golden.cases.length - result.wrong.length} of ${golden.cases.length} cases (${result.steps} time steps) identical to tests/golden/toy.json in Chromium`);
  assert.deepEqual(result.wrong, [], `golden cases ${result.wrong.slice(0, 5).join(', ')} differ in the browser`);
  assert.deepEqual(problems, [], 'errors in the page');
  await page.close();
});
