import test from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { BundleError } from '../src/bundle/sections.js';
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
  assert.throws(() => new Tokenizer({ ...json, padding: { ...json.padding, pad_to_multiple_of: 1e9 } }, 't.json'),
    /padding.pad_to_multiple_of: expected an integer in \[1, 256\], got 1000000000/);
  assert.throws(() => Tokenizer.fromText(new Uint8Array([0x7b, 0xff, 0x7d]), 't.json'), /t\.json: not a tokenizer\.json/);
});

test('normalizers, pre-tokenizers and models: exactly the ones Python reads (text.py TOKENIZER_PARTS)', () => {
  const json = JSON.parse(readFileSync(units.tokenizer[0].file, 'utf8')), python = units.tokenizer_parts;
  // every type the tokenizers library has for each part, and nonsense
  const known = {
    normalizer: ['BertNormalizer', 'Strip', 'StripAccents', 'NFC', 'NFD', 'NFKC', 'NFKD', 'Sequence', 'Lowercase', 'Nmt',
      'Precompiled', 'Replace', 'Prepend', 'ByteLevel', 'x', 7, null],
    pre_tokenizer: ['BertPreTokenizer', 'ByteLevel', 'Delimiter', 'Metaspace', 'Whitespace', 'Sequence', 'Split',
      'Punctuation', 'WhitespaceSplit', 'Digits', 'UnicodeScripts', 'FixedLength', 'x', 7, null],
    model: ['BPE', 'WordPiece', 'WordLevel', 'Unigram', 'x', 7, null],
  };
  const list = { normalizer: 'normalizers', pre_tokenizer: 'pretokenizers' };
  for (const [part, types] of Object.entries(known)) {
    for (const type of new Set([...types, ...python[part]])) {
      const spec = { ...(part === 'model' ? json.model : {}), type, ...(type === 'Sequence' ? { [list[part]]: [] } : {}) };
      const make = () => new Tokenizer({ ...json, [part]: spec }, 'bundle/tokenizer.json');
      if (python[part].includes(type)) assert.ok(make(), `${part} ${type}`);
      else {
        assert.throws(make, (e) => e instanceof BundleError && e.message === `bundle/tokenizer.json: ${part} `
          + `${JSON.stringify(type) ?? 'undefined'} is not one this runtime reads (it reads ${python[part].join(', ')})`, `${part} ${type}`);
      }
    }
  }
});

test('a tokenizer that could explode is refused, inside a Sequence too, as Python refuses it', () => {
  const json = JSON.parse(readFileSync(units.tokenizer[0].file, 'utf8'));
  for (const [normalizer, named] of [
    [{ type: 'Replace', pattern: { String: 'a' }, content: 'a'.repeat(200_000) }, '"Replace"'],
    [{ type: 'Sequence', normalizers: [{ type: 'Lowercase' }, { type: 'Prepend', prepend: 'x'.repeat(100_000) }] }, '"Prepend"'],
    [{ type: 'Sequence', normalizers: [{ type: 'Sequence', normalizers: [{ type: 'Replace' }] }] }, '"Replace"'],
    [{ type: 'Sequence', normalizers: 'Lowercase' }, 'undefined'],
    [{ type: 'Sequence' }, 'undefined'],
  ]) {
    assert.throws(() => new Tokenizer({ ...json, normalizer }, 't.json'),
      (e) => e instanceof BundleError && e.message.startsWith(`t.json: normalizer ${named} is not one this runtime reads`));
  }
  assert.throws(() => new Tokenizer({ ...json, pre_tokenizer: { type: 'Sequence', pretokenizers: [{ type: 'Split' }] } }, 't.json'),
    /t\.json: pre_tokenizer "Split" is not one this runtime reads/);
});
