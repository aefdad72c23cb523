// The same golden-format cases as js/scripts/cases.mjs, run by the JavaScript runtime inside headless Chromium on
// onnxruntime-web (wasm, 1 thread), and what the page costs per variant: the web page opened on the bundle with
// ?variant=V until it has loaded the variant (its own loadMs), and in a page of its own, the runtime loading V and
// streaming a prompt to its first frame.
//   node web/scripts/cases.mjs BUNDLE CASES.json [V1,V2,...]   -> one JSON line {runtime, cases, identical, wrong,
//                                                                 ms, pages: {V: {pageLoadMs, loadMs, firstFrameMs}}}
// Needs web/'s npm packages (`npm ci --ignore-scripts` in web/) and Debian's chromium (CHROMIUM=... to override).
import { execSync } from 'node:child_process';
import { readFileSync } from 'node:fs';
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';
import { serve } from '../test/browser.mjs';

const ROOT = resolve(dirname(fileURLToPath(import.meta.url)), '../..');
const [dir, file, timed = ''] = process.argv.slice(2);
if (!dir || !file) {
  console.error('usage: node web/scripts/cases.mjs BUNDLE CASES.json [variants to time, comma-separated]');
  process.exit(2);
}
const cases = JSON.parse(readFileSync(file, 'utf8')).cases;
const python = process.env.PYTHON ?? join(ROOT, '.venv/bin/python');
const server = await serve(python, ROOT, ['--mount', `/bundle=${resolve(dir)}`]);
const browser = await chromium.launch({ executablePath: process.env.CHROMIUM ?? execSync('command -v chromium').toString().trim() });
try {
  const page = await browser.newPage();
  await page.goto(`${server.url}web/scripts/blank.html`);
  const result = await page.evaluate(async (list) => {
    const ort = await import('/web/node_modules/onnxruntime-web/dist/ort.wasm.min.mjs');
    ort.env.wasm.wasmPaths = '/web/node_modules/onnxruntime-web/dist/';
    ort.env.wasm.numThreads = 1;
    const { MotionGenerator, SamplingConfig, urlLoader } = await import('/js/src/index.js');
    const { samplingOf } = await import('/js/test/control_case.mjs');
    const { runGoldenCase, sameAsGolden } = await import('/js/test/golden_case.mjs');
    const gens = {}, wrong = [];
    const t0 = performance.now();
    for (const [i, c] of list.entries()) {
      gens[c.variant] ??= await MotionGenerator.load(urlLoader('/bundle/'), { ort, variant: c.variant, threads: 1 });
      const got = await runGoldenCase(gens[c.variant], c, new SamplingConfig(samplingOf(c.sampling)));
      if (!sameAsGolden(got, c)) wrong.push(i);
    }
    return { wrong, ms: performance.now() - t0 };
  }, cases);
  await page.close();
  const pages = {};
  for (const variant of timed.split(',').filter(Boolean)) {
    const web = await browser.newPage();
    const t0 = Date.now();
    await web.goto(`${server.url}web/?bundle=/bundle/&variant=${variant}`);
    await web.waitForFunction((v) => window.mogoPage?.ready && window.mogoPage.state.variant === v
      && window.mogoPage.state.busy === null && window.mogoPage.state.stats.loadMs > 0, variant, { timeout: 600_000 });
    const loadMs = await web.evaluate(() => window.mogoPage.state.stats.loadMs);
    const pageLoadMs = Date.now() - t0;
    await web.close();
    const fresh = await browser.newPage();   // a page of its own: nothing cached in the worker
    await fresh.goto(`${server.url}web/scripts/blank.html`);
    const first = await fresh.evaluate(async (v) => {
      const t0 = performance.now();
      const ort = await import('/web/node_modules/onnxruntime-web/dist/ort.wasm.min.mjs');
      ort.env.wasm.wasmPaths = '/web/node_modules/onnxruntime-web/dist/';
      ort.env.wasm.numThreads = 1;
      const { MotionGenerator, urlLoader } = await import('/js/src/index.js');
      const gen = await MotionGenerator.load(urlLoader('/bundle/'), { ort, variant: v, threads: 1 });
      const loaded = performance.now();
      const stream = await gen.stream('a person walks forward', { seed: 1n });
      await stream.next();
      return { runtimeLoadMs: loaded - t0, firstFrameMs: performance.now() - loaded };
    }, variant);
    await fresh.close();
    pages[variant] = { pageLoadMs, loadMs, ...first };
  }
  console.log(JSON.stringify({ runtime: 'chromium', cases: cases.length, identical: cases.length - result.wrong.length,
    wrong: result.wrong, ms: result.ms, pages }));
} finally {
  await browser.close();
  server.process.kill();
}
