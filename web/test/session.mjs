// What the page tests share (page.test.mjs, control.test.mjs): the settings web/test/run.sh passes, the reference
// it wrote, one served repository and one headless Chromium per test file (`useBrowser`), and the page helpers.

import assert from 'node:assert/strict';
import { mkdirSync, readFileSync } from 'node:fs';
import { join } from 'node:path';
import { after, before } from 'node:test';
import { fileURLToPath } from 'node:url';

import { chromium } from 'playwright-core';

import { serve } from './browser.mjs';

export const ROOT = fileURLToPath(new URL('../../', import.meta.url));
export const PY = process.env.PYTHON ?? join(ROOT, '.venv/bin/python');
const REFERENCE = process.env.MOGO_WEB_REFERENCE;
export const OUT = process.env.MOGO_WEB_OUT ?? join(ROOT, 'outputs/web-test');
const CHROMIUM = process.env.CHROMIUM ?? 'chromium';
export const JOINT_TOLERANCE = 1e-4;   // metres: onnxruntime-web's wasm kernels against onnxruntime's native ones
export const WORK = process.env.MOGO_WEB_WORK;

if (!REFERENCE) throw new Error('MOGO_WEB_REFERENCE is not set: run web/test/run.sh (make test-web)');
export const reference = JSON.parse(readFileSync(REFERENCE, 'utf8'));
mkdirSync(OUT, { recursive: true });

/** The served repository and the browser, set by `useBrowser`'s hooks. */
export const session = { server: null, browser: null };

/** Serve the repository (the bundles mounted under /test-bundles/) and launch Chromium for this test file. */
export function useBrowser() {
  before(async () => {
    const mounts = Object.entries(reference.bundles).flatMap(([name, b]) => ['--mount', `/test-bundles/${name}=${b.path}`]);
    for (const made of ['toy-variants', 'toy-failing', 'toy-clips', 'toy-control']) {
      mounts.push('--mount', `/test-bundles/${made}=${join(WORK, 'bundles', made)}`);
    }
    session.server = await serve(PY, ROOT, mounts);
    session.browser = await chromium.launch({
      executablePath: CHROMIUM,
      // software WebGL (SwiftShader): a headless machine has no GPU
      args: ['--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
    });
  });

  after(async () => {
    await session.browser?.close();
    session.server?.process.kill();
  });
}

export function bundleManifest(name) {
  const folder = reference.bundles[name]?.path ?? join(WORK, 'bundles', name);
  return JSON.parse(readFileSync(join(folder, 'manifest.json'), 'utf8'));
}


/** A new page at `url`; with `clock`, the page's timers and animation frames on a clock the test can run ahead. */
export async function open(url, { clock = false } = {}) {
  const page = await session.browser.newPage({ viewport: { width: 1100, height: 700 }, acceptDownloads: true });
  const problems = [];
  page.on('pageerror', (e) => problems.push(`page error: ${e.message}`));
  page.on('console', (m) => { if (m.type() === 'error') problems.push(`console: ${m.text()}`); });
  page.on('crash', () => problems.push('the page crashed'));
  if (clock) await page.clock.install();
  await page.goto(url);
  return { page, problems };
}

export async function selectVariant(page, variant) {
  const current = (await page.evaluate(() => window.mogoPage.state)).variant;
  if (current === variant) return;
  await page.selectOption('#variant', variant);
  await waitState(page, (s, v) => s.variant === v && s.busy === null, variant);
}

export async function generate(page, { text, seed, seconds }) {
  await page.fill('#prompt', text);
  await page.fill('#seed', String(seed));
  await page.fill('#seconds', seconds === null ? '' : String(seconds));
  const shows = (await page.evaluate(() => window.mogoPage.state)).shows;
  await page.click('#generate');
  const state = await waitState(page, (s, n) => s.shows > n && s.busy === null, shows);
  return { motion: await page.evaluate(() => window.mogoPage.motion()), stats: state.stats.clip };
}

/** Wait until `predicate(state, arg)` holds; fail at once with the page's error if one appears. */
export async function waitState(page, predicate, arg) {
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
