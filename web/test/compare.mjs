// Comparing what the page writes with what the Python runtime writes.

import assert from 'node:assert/strict';

const LAST_DIGIT = 1.01e-6;   // BVH numbers are printed with 6 decimals: allow one unit in the last place

/**
 * Same BVH text up to the last printed digit: every line has the same words, every number is within one unit of
 * the last decimal (the JavaScript writer fits rotations by Horn's method, Python by an SVD). Returns counts.
 */
export function compareBvh(js, py, what) {
  const a = js.split('\n'), b = py.split('\n');
  assert.equal(a.length, b.length, `${what}: ${a.length} lines, Python wrote ${b.length}`);
  let identical = 0, values = 0, sameValues = 0, maxDiff = 0;
  a.forEach((line, i) => {
    if (line === b[i]) identical += 1;
    const x = line.split(/(\s+)/), y = b[i].split(/(\s+)/);
    assert.equal(x.length, y.length, `${what}: line ${i + 1} differs: ${line.slice(0, 80)} | ${b[i].slice(0, 80)}`);
    x.forEach((word, k) => {
      const isNumber = /^-?\d+\.\d+$/.test(word);
      if (!isNumber) {
        assert.equal(word, y[k], `${what}: line ${i + 1}, word ${k}`);
        return;
      }
      values += 1;
      if (word === y[k]) sameValues += 1;
      const d = Math.abs(Number(word) - Number(y[k]));
      maxDiff = Math.max(maxDiff, d);
      assert.ok(d <= LAST_DIGIT, `${what}: line ${i + 1}: ${word} vs Python's ${y[k]}`);
    });
  });
  return { lines: a.length, identical, values, sameValues, maxDiff };
}
