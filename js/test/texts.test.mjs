// Prompt checks, as the Python runtime's text.check_texts: length in characters (code points, not UTF-16
// units), blank prompts and lone surrogates refused with the same messages.

import test from 'node:test';
import assert from 'node:assert/strict';
import { MAX_PROMPT_CHARS, checkTexts } from '../src/generator.js';

const refused = (texts, pattern) => assert.throws(() => checkTexts(texts), (e) => e instanceof RangeError && pattern.test(e.message));

test('prompts are at most 10,000 characters, counted as Python counts them', () => {
  assert.equal(MAX_PROMPT_CHARS, 10_000);
  assert.deepEqual(checkTexts(['a'.repeat(10_000)]), ['a'.repeat(10_000)]);
  refused(['walk', 'a'.repeat(10_001)], /^prompt 1 has 10,001 characters; a prompt may have at most 10,000/);
  const emoji = '🙂'.repeat(10_000);                     // 20,000 UTF-16 units, 10,000 characters
  assert.equal(checkTexts([emoji])[0].length, 20_000);
  refused([`${emoji}🙂`], /^prompt 0 has 10,001 characters/);
});

test('lone surrogates and blank prompts are refused; surrogate pairs are text', () => {
  refused(['ab\ud800c'], /^prompt 0 is not valid Unicode text: character 2 is a lone surrogate/);
  refused(['🙂\udc00'], /character 1 is a lone surrogate/);
  refused(['  \n'], /^prompt 0 is empty or whitespace only/);
  assert.deepEqual(checkTexts(['a person waves 👋']), ['a person waves 👋']);
});
