// Click to walk and the golden controlled streams in the page (bundles with control; page.test.mjs says what the page
// tests cover): a click on the ground sends the streaming character to the point under the click (within 1 cm of the
// camera ray's ground point, computed here) and the stream's tokens are Python's for the same request made before the
// same frame; the golden controlled streams (tests/golden/toy_control.json) in the page's own onnxruntime-web; and on
// MOGO_WEB_BUNDLES with control, the character arrives.

import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';

import { rows } from './browser.mjs';
import { JOINT_TOLERANCE, PY, ROOT, WORK, bundleManifest, open, reference, session, useBrowser, waitState } from './session.mjs';

const WALK = { prompt: 'a person walks forward', seed: 4, click: [0.62, 0.8], after: 40, arriveSeconds: 30 };

useBrowser();

test('click to walk: the click is a walkTo to the ground point under it, and the stream is Python\'s', { timeout: 300_000 }, async () => {
  const name = 'toy-control';
  const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/${name}`);
  assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `the page did not load: ${problems.join('; ')}`);
  const { walk, goal, motion } = await streamAndClick(page, name, (s, w) => s.shown >= w.frame + w.after, WALK.after);
  const want = groundUnder(await page.evaluate(() => window.mogoPage.camera()), goal.click);
  const miss = Math.hypot(walk.goal[0] - want[0], walk.goal[1] - want[1]);
  assert.ok(miss <= 0.01, `the walkTo goal ${walk.goal} is ${miss} m from the ground under the click ${want}`);

  const py = JSON.parse(execFileSync(PY, [join(ROOT, 'web/test/reference.py'), 'control', join(WORK, 'bundles', name),
    motion.variant, String(WALK.seed), String(motion.numFrames), WALK.prompt, String(walk.frame), String(walk.goal[0]),
    String(walk.goal[1])], { maxBuffer: 1 << 28, encoding: 'utf8' }));
  assert.equal(walk.token, py.landed, 'the request landed at another token');
  const got = rows(motion.picked, motion.levels), n = Math.min(got.length, py.tokens.length);
  assert.ok(n >= walk.token + WALK.after / 4, `only ${n} tokens compared (the request landed at token ${walk.token})`);
  assert.deepEqual(got.slice(0, n), py.tokens.slice(0, n), 'the stream\'s tokens differ from Python\'s');
  let err = 0;
  for (let i = 0; i < motion.joints.length; i++) err = Math.max(err, Math.abs(motion.joints[i] - py.joints[i]));
  assert.ok(err <= JOINT_TOLERANCE, `the stream's joints differ from Python's by ${err} m`);
  console.log(`web: ${name}/${motion.variant} click to walk: the click at (${goal.click.map((v) => v.toFixed(0))}) px sent `
    + `walkTo([${walk.goal.map((v) => v.toFixed(3))}]) at token ${walk.token} (frame ${walk.frame}), ${(miss * 1000).toFixed(2)} mm `
    + `from the ground under the click; ${n} tokens identical to Python's for the same request at the same token, `
    + `${motion.numFrames} frames within ${err.toExponential(1)} m`);
  assert.deepEqual(problems, [], 'errors in the page');
  await page.close();
});

for (const [name, bundle] of Object.entries(reference.bundles)) {
  if (!bundleManifest(name).control || !bundleManifest(name).streaming) continue;   // MOGO_WEB_BUNDLES with control
  test(`click to walk on the ${name} bundle: the character arrives within 0.3 m`, { timeout: 600_000 }, async () => {
    const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/${name}`);
    assert.equal(await page.evaluate(() => window.mogoPage.ready), true, `the page did not load: ${problems.join('; ')}`);
    const fps = bundleManifest(name).model.fps;
    const { walk, motion } = await streamAndClick(page, name, (s, w) => s.shown >= w.frame + w.after
      || window.mogoPage.motion().arrivals.length > 0, WALK.arriveSeconds * fps);
    assert.ok(motion.arrivals.length, `${name}: no arrival in ${WALK.arriveSeconds} s of motion`);
    // the runtime says "arrived" from the next frame's pose as it decodes, before the page shows that frame: the
    // root shown must come within the arrival radius by then (the model may walk on after it: README, "Where it goes")
    // "arrived" is read from the pose of the next frame to decode (the first of the next token), so look a token on
    const J3 = motion.joints.length / motion.numFrames, f = Math.min(motion.arrivals[0], motion.numFrames - 1);
    const last = Math.min(f + 2 * bundleManifest(name).model.downsample, motion.numFrames - 1);
    let off = Infinity, at = -1;
    for (let i = walk.frame; i <= last; i++) {
      const d = Math.hypot(motion.joints[i * J3] - walk.goal[0], motion.joints[i * J3 + 2] - walk.goal[1]);
      if (d < off) [off, at] = [d, i];
    }
    assert.ok(off <= 0.3, `${name}: came no closer than ${off} m to the goal`);
    console.log(`web: ${name}/${motion.variant} click to walk: within ${(off * 100).toFixed(0)} cm of the goal at frame ${at} `
      + `(${((at - walk.frame) / fps).toFixed(1)} s after the request), "arrived" said at frame ${f}`);
    assert.deepEqual(problems, [], `${name}: errors in the page`);
    await page.close();
  });
}

/**
 * Stream WALK.prompt with the camera held still, click the ground, play until `until(state, {...walk, after})` holds
 * (evaluated in the page), stop.
 */
async function streamAndClick(page, name, until, after) {
  await page.uncheck('#follow');   // the camera stays where the click was aimed
  await page.fill('#prompt', WALK.prompt);
  await page.fill('#seed', String(WALK.seed));
  await page.click('#stream');
  await waitState(page, (s) => s.busy === 'streaming' && s.shown >= 8);
  const camera = await page.evaluate(() => window.mogoPage.camera());
  const click = [camera.rect.left + WALK.click[0] * camera.rect.width, camera.rect.top + WALK.click[1] * camera.rect.height];
  await page.mouse.click(...click);
  await page.waitForFunction(() => window.mogoPage.motion().walks.length === 1, null, { timeout: 60_000 });
  const walk = (await page.evaluate(() => window.mogoPage.motion())).walks[0];
  assert.deepEqual(await page.evaluate(() => window.mogoPage.camera()), camera, `${name}: the camera moved`);
  await page.waitForFunction(([source, w]) => new Function('s', 'w', `return (${source})(s, w)`)(window.mogoPage.state, w),
    [until.toString(), { ...walk, after }], { timeout: 600_000 });
  await page.click('#stop');
  await waitState(page, (s) => s.busy === null);
  return { walk, goal: { click }, motion: await page.evaluate(() => window.mogoPage.motion()) };
}

/** The ground point [x, z] (y = 0) on the camera ray through client pixel `click`: three.js's conventions, by hand. */
function groundUnder({ position, quaternion: [qx, qy, qz, qw], fov, aspect, rect }, [x, y]) {
  const t = Math.tan((fov * Math.PI) / 360), ndc = [((x - rect.left) / rect.width) * 2 - 1, 1 - ((y - rect.top) / rect.height) * 2];
  const v = [ndc[0] * t * aspect, ndc[1] * t, -1];   // the ray in the camera's frame (it looks down -z)
  // rotated by the camera's quaternion: v + 2w (q x v) + 2 q x (q x v)
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const q = [qx, qy, qz], u = cross(q, v), w = cross(q, u);
  const d = v.map((vi, i) => vi + 2 * qw * u[i] + 2 * w[i]);
  const k = -position[1] / d[1];
  return [position[0] + k * d[0], position[2] + k * d[2]];
}

// The golden controlled streams (tests/golden/toy_control.json) in the browser, read as Node reads them
// (js/test/control_case.mjs), on the page's onnxruntime-web.
test('the browser gives the golden controlled streams', { timeout: 300_000 }, async () => {
  const golden = JSON.parse(readFileSync(join(ROOT, 'tests/golden/toy_control.json'), 'utf8'));
  const manifest = bundleManifest('toy-control');
  for (const [file, sha256] of Object.entries(golden.files)) {
    assert.equal(manifest.files[file]?.sha256, sha256, `${file}: the control toy bundle changed since tests/golden/toy_control.json was written`);
  }
  const { page, problems } = await open(`${session.server.url}web/?bundle=/test-bundles/toy-control`);
  const result = await page.evaluate(async (cases) => {
    const ort = await import('/web/node_modules/onnxruntime-web/dist/ort.wasm.min.mjs');
    ort.env.wasm.wasmPaths = '/web/node_modules/onnxruntime-web/dist/';
    ort.env.wasm.numThreads = 1;
    const { MotionGenerator, urlLoader } = await import('/js/src/index.js');
    const { compareControlCase, runControlCase, samplingOf } = await import('/js/test/control_case.mjs');
    const gens = {}, wrong = [];
    let vectors = 0, exact = 0, worst = 0;
    for (const [i, c] of cases.entries()) {
      gens[c.variant] ??= await MotionGenerator.load(urlLoader('/test-bundles/toy-control/'), { ort, variant: c.variant, threads: 1 });
      const r = compareControlCase(await runControlCase(gens[c.variant], c, samplingOf(c.sampling)), c);
      [vectors, exact, worst] = [vectors + r.vectors, exact + r.exact, Math.max(worst, r.worst)];
      if (!r.same) wrong.push(i);
    }
    return { wrong, vectors, exact, worst };
  }, golden.cases);
  console.log(`web: golden control: ${golden.cases.length - result.wrong.length} of ${golden.cases.length} controlled streams `
    + `identical to tests/golden/toy_control.json in Chromium; control vectors ${result.exact} of ${result.vectors} bit-identical, `
    + `max |difference| ${result.worst.toExponential(1)}`);
  assert.deepEqual(result.wrong, [], `golden controlled streams ${result.wrong.slice(0, 5).join(', ')} differ in the browser`);
  assert.deepEqual(problems, [], 'errors in the page');
  await page.close();
});
