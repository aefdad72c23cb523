// The web page in a real headless Chromium (Debian's, driven by playwright-core), served by web/serve.py:
//   - for each bundle and variant, 3 clips generated through the page's controls have exactly the tokens the Python
//     runtime gives for the same prompts, seeds and sampling (web/test/reference.py);
//   - a stream whose prompt is changed mid-stream through the page gives the motion of Python's timeline that
//     switches at the same token; the screenshots show the skeleton (pixels of its colours) and it moves;
//   - the page's BVH and JSON downloads equal what runtime/mogo_runtime writes for the same joints.
// Run by web/test/run.sh (make test-web), which builds the bundles and the reference; prints `web:` lines.

import assert from 'node:assert/strict';
import { execFileSync, spawn } from 'node:child_process';
import { mkdirSync, readFileSync } from 'node:fs';
import { join } from 'node:path';
import { after, before, test } from 'node:test';
import { fileURLToPath } from 'node:url';

import { chromium } from 'playwright-core';

import { compareBvh } from './compare.mjs';

const ROOT = fileURLToPath(new URL('../../', import.meta.url));
const PY = process.env.PYTHON ?? join(ROOT, '.venv/bin/python');
const REFERENCE = process.env.MOGO_WEB_REFERENCE;
const OUT = process.env.MOGO_WEB_OUT ?? join(ROOT, 'outputs/web-test');
const CHROMIUM = process.env.CHROMIUM ?? 'chromium';
const JOINT_TOLERANCE = 1e-4;   // metres: onnxruntime-web's wasm kernels against onnxruntime's native ones
const STREAM = { first: 'a person walks forward', then: 'a person jumps twice', seed: 5 };

if (!REFERENCE) throw new Error('MOGO_WEB_REFERENCE is not set: run web/test/run.sh (make test-web)');
const reference = JSON.parse(readFileSync(REFERENCE, 'utf8'));
mkdirSync(OUT, { recursive: true });

let server, browser;

before(async () => {
  const mounts = Object.entries(reference.bundles).flatMap(([name, b]) => ['--mount', `/test-bundles/${name}=${b.path}`]);
  mounts.push('--mount', `/test-bundles/toy-variants=${join(process.env.MOGO_WEB_WORK, 'bundles/toy-variants')}`);
  server = await serve(mounts);
  browser = await chromium.launch({
    executablePath: CHROMIUM,
    // software WebGL (SwiftShader): a headless machine has no GPU
    args: ['--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
  });
});

after(async () => {
  await browser?.close();
  server?.process.kill();
});

for (const [name, bundle] of Object.entries(reference.bundles)) {
  test(`the page on the ${name} bundle: Python's tokens, a stream that changes prompt, the skeleton on screen, files`,
    { timeout: 600_000 }, async () => {
      const { page, problems } = await open(`${server.url}web/?bundle=/test-bundles/${name}`);
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
  const { page, problems } = await open(`${server.url}web/?bundle=/test-bundles/toy-variants`);
  assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `the page did not load: ${problems.join('; ')}`);
  const state = await page.evaluate(() => window.mogoPage.state);
  assert.deepEqual(state.variants, ['fp32', 'int8', 'portable']);
  const note = await page.textContent('#variant-note');
  assert.match(note, /^not offered: broken \(.*broken\.onnx.*\)$/);
  await selectVariant(page, 'portable');
  const { motion } = await generate(page, reference.clips[0]);
  assert.deepEqual(rows(motion.tokens, motion.levels), reference.bundles.toy.tokens.fp32[0], 'portable = the fp32 graphs');
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

// ---- helpers ----------------------------------------------------------------------------------------------

/** web/serve.py on a free port; resolves once it prints its URL. */
function serve(mounts) {
  return new Promise((resolve, reject) => {
    const proc = spawn(PY, [join(ROOT, 'web/serve.py'), '--port', '0', '--page', '', ...mounts], { stdio: ['ignore', 'pipe', 'inherit'] });
    let out = '';
    proc.stdout.on('data', (chunk) => {
      out += chunk;
      const m = out.match(/(http:\/\/\S+)/);
      if (m) resolve({ process: proc, url: m[1].endsWith('/') ? m[1] : `${m[1]}/` });
    });
    proc.on('exit', (code) => reject(new Error(`web/serve.py exited with ${code}: ${out}`)));
  });
}

async function open(url) {
  const page = await browser.newPage({ viewport: { width: 1100, height: 700 }, acceptDownloads: true });
  const problems = [];
  page.on('pageerror', (e) => problems.push(`page error: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error') problems.push(`console: ${m.text()}`); });
  page.on('crash', () => problems.push('the page crashed'));
  await page.goto(url);
  return { page, problems };
}

async function selectVariant(page, variant) {
  const current = (await page.evaluate(() => window.mogoPage.state)).variant;
  if (current === variant) return;
  await page.selectOption('#variant', variant);
  await waitState(page, (s, v) => s.variant === v && s.busy === null, variant);
}

async function generate(page, { text, seed, seconds }) {
  await page.fill('#prompt', text);
  await page.fill('#seed', String(seed));
  await page.fill('#seconds', seconds === null ? '' : String(seconds));
  const shows = (await page.evaluate(() => window.mogoPage.state)).shows;
  await page.click('#generate');
  const state = await waitState(page, (s, n) => s.shows > n && s.busy === null, shows);
  return { motion: await page.evaluate(() => window.mogoPage.motion()), stats: state.stats.clip };
}

/** Wait until `predicate(state, arg)` holds; fail at once with the page's error if one appears. */
async function waitState(page, predicate, arg) {
  const errors = (await page.evaluate(() => window.mogoPage.state)).errors.length;
  const handle = await page.waitForFunction(([source, a, e]) => {
    const s = window.mogoPage.state;
    // eslint-disable-next-line no-new-func
    return s.errors.length > e || new Function('s', 'a', `return (${source})(s, a)`)(s, a) ? s : null;
  }, [predicate.toString(), arg, errors], { timeout: 300_000 });
  const state = await handle.jsonValue();
  assert.ok(state.errors.length === errors, `the page reports: ${state.errors.slice(errors).join('; ')}`);
  return state;
}

async function downloaded(page, button) {
  const [download] = await Promise.all([page.waitForEvent('download'), page.click(button)]);
  const path = await download.path();
  return readFileSync(path, 'utf8');
}

/**
 * Pixels of the skeleton's colours in PNG screenshots, decoded by the browser: the only saturated colours on
 * screen are its left (blue), right (orange) and centre (yellow) parts. `moved[i]`: pixels that are skeleton in
 * one of shots i, i + 1 and not in the other.
 */
async function skeletonPixels(page, pngs) {
  return page.evaluate(async (list) => {
    const masks = [], shots = [];
    let width = 0, height = 0;
    for (const b64 of list) {
      const img = new Image();
      img.src = `data:image/png;base64,${b64}`;
      await img.decode();
      ({ width, height } = img);
      const canvas = new OffscreenCanvas(width, height);
      const ctx = canvas.getContext('2d');
      ctx.drawImage(img, 0, 0);
      const d = ctx.getImageData(0, 0, width, height).data;
      const mask = new Uint8Array(width * height);
      const count = { skeleton: 0, left: 0, right: 0, centre: 0 };
      for (let i = 0; i < mask.length; i++) {
        const r = d[4 * i] / 255, g = d[4 * i + 1] / 255, b = d[4 * i + 2] / 255;
        const max = Math.max(r, g, b), min = Math.min(r, g, b);
        if (max < 0.3 || (max - min) / max < 0.45) continue;   // dark or grey: background, grid, panel
        let hue = max === r ? ((g - b) / (max - min)) * 60 : max === g ? (2 + (b - r) / (max - min)) * 60 : (4 + (r - g) / (max - min)) * 60;
        if (hue < 0) hue += 360;
        const side = hue >= 190 && hue <= 225 ? 'left' : hue >= 12 && hue < 36 ? 'right' : hue >= 36 && hue <= 60 ? 'centre' : null;
        if (!side) continue;
        mask[i] = 1;
        count.skeleton += 1;
        count[side] += 1;
      }
      masks.push(mask);
      shots.push(count);
    }
    const moved = [];
    for (let k = 1; k < masks.length; k++) {
      let n = 0;
      for (let i = 0; i < masks[k].length; i++) n += masks[k][i] !== masks[k - 1][i];
      moved.push(n);
    }
    return { width, height, shots, moved };
  }, pngs.map((b) => b.toString('base64')));
}

/** How many leading rows two token lists share. */
function sharedPrefix(a, b) {
  let n = 0;
  while (n < a.length && n < b.length && a[n].join() === b[n].join()) n += 1;
  return n;
}

/** Flat tokens -> rows of `levels`. */
function rows(flat, levels) {
  return Array.from({ length: flat.length / levels }, (_, t) => flat.slice(t * levels, (t + 1) * levels));
}

// The golden tokens (tests/golden/toy.json) in the browser: the JavaScript runtime on onnxruntime-web (wasm) in
// the page's own context, every golden case on the toy bundle, exactly the stored tokens.
test('the browser gives the golden tokens', { timeout: 300_000 }, async () => {
  assert.ok(reference.bundles.toy, 'the toy bundle is served');
  const golden = JSON.parse(readFileSync(join(ROOT, 'tests/golden/toy.json'), 'utf8'));
  const manifest = JSON.parse(readFileSync(join(reference.bundles.toy.path, 'manifest.json'), 'utf8'));
  for (const [file, sha256] of Object.entries(golden.files)) {
    assert.equal(manifest.files[file]?.sha256, sha256, `${file}: the toy bundle changed since tests/golden/toy.json was written`);
  }
  const { page, problems } = await open(`${server.url}web/?bundle=/test-bundles/toy`);
  const result = await page.evaluate(async (cases) => {
    const ort = await import('/web/node_modules/onnxruntime-web/dist/ort.wasm.min.mjs');
    ort.env.wasm.wasmPaths = '/web/node_modules/onnxruntime-web/dist/';
    ort.env.wasm.numThreads = 1;
    const { MotionGenerator, urlLoader } = await import('/js/src/index.js');
    const gens = {};
    const wrong = [];
    let steps = 0;
    for (const [i, c] of cases.entries()) {
      gens[c.variant] ??= await MotionGenerator.load(urlLoader('/test-bundles/toy/'), { ort, variant: c.variant, threads: 1 });
      const gen = gens[c.variant];
      const s = c.sampling;
      const sampling = { temperature: s.temperature, topK: s.top_k ?? null, topP: s.top_p ?? null, guidance: s.guidance ?? 1 };
      const out = await gen.generate(c.text, { seconds: c.seconds ?? null, seed: BigInt(c.seed), sampling });
      const L = gen.dims.numLevels;
      const got = (Array.isArray(out) ? out : [out]).map((m) => Array.from(
        { length: m.tokens.data.length / L }, (_, t) => Array.from(m.tokens.data.slice(t * L, (t + 1) * L))));
      steps += c.tokens.reduce((n, t) => n + t.length, 0);
      if (JSON.stringify(got) !== JSON.stringify(c.tokens)) wrong.push(i);
    }
    return { wrong, steps };
  }, golden.cases);
  console.log(`web: golden: ${golden.cases.length - result.wrong.length} of ${golden.cases.length} cases (${result.steps} time steps) identical to tests/golden/toy.json in Chromium`);
  assert.deepEqual(result.wrong, [], `golden cases ${result.wrong.slice(0, 5).join(', ')} differ in the browser`);
  assert.deepEqual(problems, [], 'errors in the page');
  await page.close();
});
