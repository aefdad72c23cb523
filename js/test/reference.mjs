// The Python runtime's answers for the tests, written by test/make_reference.py (test/run.sh runs it).

import { readFileSync, readdirSync } from 'node:fs';
import { join } from 'node:path';

/** The reference folder: $MOGO_JS_REFERENCE. A missing one fails the tests (they compare, never skip). */
export function referenceDir() {
  const dir = process.env.MOGO_JS_REFERENCE;
  if (!dir) {
    throw new Error('MOGO_JS_REFERENCE is not set: run js/test/run.sh (it builds the toy bundle and writes the '
      + 'Python reference with js/test/make_reference.py)');
  }
  return dir;
}

export function readReference(name) {
  return JSON.parse(readFileSync(join(referenceDir(), name), 'utf8'));
}

/** Every bundle reference (bundle-<name>.json) in the folder, its variants read from variant-<name>-<v>.json. */
export function bundleReferences() {
  return readdirSync(referenceDir()).filter((f) => /^bundle-.*\.json$/.test(f)).sort().map((f) => {
    const ref = readReference(f);
    const variants = {};
    for (const v of ref.variants) variants[v] = readReference(`variant-${ref.name}-${v}.json`);
    return { ...ref, variants };
  });
}

/** Largest absolute difference of two equally long numeric arrays (null in JSON = -inf, compared as equal). */
export function maxAbsDiff(got, want) {
  if (got.length !== want.length) throw new Error(`length ${got.length}, expected ${want.length}`);
  let worst = 0;
  for (let i = 0; i < want.length; i++) {
    const w = want[i] === null ? -Infinity : want[i];
    if (w === got[i]) continue;
    const d = Math.abs(got[i] - w);
    worst = Number.isNaN(d) ? Infinity : Math.max(worst, d);
  }
  return worst;
}

/** A line of the parity report, printed so that CI logs carry the measured numbers. */
export function report(line) {
  console.log(`parity: ${line}`);
}
