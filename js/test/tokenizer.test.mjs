import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { Tokenizer } from '../src/tokenizer.js';
import { readReference, report } from './reference.mjs';

const units = readReference('units.json');
const load = (file) => Tokenizer.fromText(readFileSync(file, 'utf8'), file);

for (const c of units.tokenizer) {
  test(`tokenizer ids equal Python's tokenizers: ${c.file.split('/').pop()}`, () => {
    const tok = load(c.file);
    const bad = c.strings.flatMap((s, i) => (JSON.stringify(tok.encode(s)) === JSON.stringify(c.ids[i]) ? [] : [i]));
    report(`tokenizer ${c.file.split('/').pop()}: ${c.strings.length - bad.length}/${c.strings.length} strings identical`);
    assert.deepEqual(bad.map((i) => c.strings[i]).slice(0, 5), [], 'strings tokenized differently');
    for (const { texts, input_ids: ids, attention_mask: mask } of c.batches) {
      const { inputIds, attentionMask, dims } = tok.encodeBatch(texts);
      assert.deepEqual(dims, [ids.length, ids[0].length]);
      assert.deepEqual(Array.from(inputIds, Number), ids.flat());
      assert.deepEqual(Array.from(attentionMask, Number), mask.flat());
    }
  });
}

test('every code point is classed as tokenizers classes it (controls, punctuation, accents, CJK)', () => {
  const { file, code_points: cps, ids } = units.code_points;
  const tok = load(file);
  const bad = [];
  cps.forEach((cp, i) => {
    if (JSON.stringify(tok.encode(`a${String.fromCodePoint(cp)}b`)) !== JSON.stringify(ids[i])) bad.push(cp.toString(16));
  });
  report(`tokenizer: ${cps.length - bad.length}/${cps.length} single code points identical`);
  assert.deepEqual(bad.slice(0, 20), []);
});

test('a tokenizer.json the runtime cannot honour is refused with the field named', () => {
  const json = JSON.parse(readFileSync(units.tokenizer[0].file, 'utf8'));
  assert.throws(() => new Tokenizer({ ...json, truncation: null }, 't.json'), /no truncation configured/);
  assert.throws(() => new Tokenizer({ ...json, padding: { ...json.padding, strategy: { Fixed: 128 } } }, 't.json'),
    /padding must be 'longest in batch'/);
  assert.throws(() => new Tokenizer({ ...json, model: { ...json.model, type: 'BPE' } }, 't.json'), /model.type: unsupported model "BPE"/);
  assert.throws(() => new Tokenizer({ ...json, normalizer: { type: 'Precompiled' } }, 't.json'), /normalizer.type/);
});
