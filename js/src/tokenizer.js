// The bundle's tokenizer.json (HuggingFace `tokenizers`), re-implemented for the pieces mogo bundles use.
//
// A prompt must reach the text encoder as the same ids Python's `tokenizers` gives, so each step follows
// tokenizers' Rust code: added tokens ([CLS], [SEP], ... typed in the text) are split out first, the rest is
// normalised (BertNormalizer: clean text, space around CJK ideographs, NFD + drop non-spacing marks,
// per-character lowercase), pre-tokenised (BERT: split on whitespace, isolate punctuation), cut into
// WordPiece sub-words (greedy longest match, `##` continuation, [UNK] for a word with no split or longer
// than max_input_chars_per_word), cut to max_length minus the template's special tokens, wrapped in the
// template ([CLS] A [SEP]) and padded on the right to the longest prompt of the batch
// (runtime/mogo_runtime/text.py: TokenizerSettings, tokenize). Anything else the file may hold is refused
// with the field named, rather than tokenised differently. test/tokenizer.test.mjs compares with Python on
// over a thousand strings.

import { BundleError } from './bundle/sections.js';
import { oneLine, shown } from './checks.js';
import * as tables from './unicode-tables.js';

const WHITESPACE = /\p{White_Space}/u;   // Rust's char::is_whitespace
const WHITESPACE_RUNS = /\p{White_Space}+/u;
// tokenizers' own character classes (its Unicode tables are older than the engine's; see unicode-tables.js)
const OTHER = charClass(tables.OTHER);
const PUNCTUATION = new RegExp(`(${charClass(tables.PUNCTUATION).source})`, 'u');   // split() keeps each one
const NONSPACING_MARK = charClass(tables.NONSPACING_MARK);
// the regex crate's Unicode \w, for the Whitespace pre-tokenizer's `\w+|[^\w\s]+`
const WORD = '\\p{Alphabetic}\\p{M}\\p{Nd}\\p{Pc}\\p{Join_Control}';
const WHITESPACE_PRETOKENS = new RegExp(`[${WORD}]+|[^${WORD}\\p{White_Space}]+`, 'gu');
const CJK = charClass('4e00-9fff 3400-4dbf 20000-2a6df 2a700-2b73f 2b740-2b81f 2b920-2ceaf f900-faff 2f800-2fa1f');

/** A tokenizer.json this runtime cannot read exactly as Python's `tokenizers` does; the bundle's file is wrong. */
export class TokenizerError extends BundleError {
  name = 'TokenizerError';
}

// The parts both runtimes implement, as runtime/mogo_runtime/text.py TOKENIZER_PARTS: others are refused before any
// prompt is read (a Replace normalizer that expands a character 200,000-fold aborted Python on a long prompt).
const PARTS = {
  normalizer: ['BertNormalizer', 'Lowercase', 'StripAccents', 'NFC', 'NFD', 'NFKC', 'NFKD', 'Sequence'],
  pre_tokenizer: ['BertPreTokenizer', 'Whitespace', 'WhitespaceSplit', 'Sequence'],
  model: ['WordPiece', 'WordLevel'],
};

export class Tokenizer {
  /**
   * @param {object} json the parsed tokenizer.json
   * @param {string} [source] the file, for error messages
   */
  constructor(json, source = 'tokenizer.json') {
    const fail = (field, message) => {
      throw new TokenizerError(`${source}: ${field}: ${message}`);
    };
    if (json === null || typeof json !== 'object' || Array.isArray(json)) fail('(top level)', 'expected a JSON object');
    checkParts(json, source);
    this.source = source;
    this.normalize = makeNormalizer(json.normalizer ?? null);
    this.preTokenize = makePreTokenizer(json.pre_tokenizer ?? null);
    this.model = makeModel(json.model, fail);
    this.addedTokens = parseAddedTokens(json.added_tokens ?? [], fail);
    this.template = makeTemplate(json.post_processor ?? null, fail);
    Object.assign(this, parseSettings(json, source, this));
  }

  /** A Tokenizer from a tokenizer.json file's text, or its bytes (UTF-8). */
  static fromText(text, source) {
    let json;
    try {
      json = JSON.parse(typeof text === 'string' ? text : new TextDecoder('utf-8', { fatal: true }).decode(text));
    } catch (e) {
      throw new TokenizerError(`${source}: not a tokenizer.json (${oneLine(e.message, 200)})`);
    }
    return new Tokenizer(json, source);
  }

  /** One prompt -> ids, truncated and wrapped in the template (no padding). */
  encode(text) {
    const ids = [];
    for (const piece of splitAddedTokens(text, this.addedTokens.filter((t) => !t.normalized))) {
      if (piece.id !== undefined) {
        ids.push(piece.id);
        continue;
      }
      const normalized = this.normalize(piece.text);
      for (const inner of splitAddedTokens(normalized, this.addedTokens.filter((t) => t.normalized))) {
        if (inner.id !== undefined) ids.push(inner.id);
        else for (const word of this.preTokenize(inner.text)) ids.push(...this.model.tokenize(word));
      }
    }
    return this.template(ids.slice(0, Math.max(0, this.maxLength - this.template.added)));
  }

  /**
   * Prompts -> input_ids and attention_mask, both (N, S) int64 as BigInt64Array, S = the longest prompt
   * (rounded up to pad_to_multiple_of when the file sets it), padded on the right.
   */
  encodeBatch(texts) {
    const rows = texts.map((t) => this.encode(t));
    let S = Math.max(...rows.map((r) => r.length));
    if (this.padMultiple) S = Math.ceil(S / this.padMultiple) * this.padMultiple;
    const inputIds = new BigInt64Array(rows.length * S).fill(BigInt(this.padId));
    const attentionMask = new BigInt64Array(rows.length * S);
    rows.forEach((ids, n) => {
      ids.forEach((id, s) => {
        inputIds[n * S + s] = BigInt(id);
        attentionMask[n * S + s] = 1n;
      });
    });
    return { inputIds, attentionMask, dims: [rows.length, S] };
  }
}

/** TokenizerSettings.from_tokenizer: truncation on the right, padding to the longest of the batch. */
function parseSettings(json, source, tok) {
  const trunc = json.truncation ?? null, pad = json.padding ?? null;
  if (trunc === null) {
    throw new TokenizerError(`${source}: no truncation configured; long prompts would exceed the encoder's positions. `
      + 'Re-export the text encoder (it writes truncation into tokenizer.json)');
  }
  if (pad === null || pad.strategy !== 'BatchLongest') {
    throw new TokenizerError(`${source}: padding must be 'longest in batch', found ${shown(pad, 200)}; re-export the text encoder`);
  }
  if ((trunc.direction ?? 'Right') !== 'Right' || (pad.direction ?? 'Right') !== 'Right') {
    throw new TokenizerError(`${source}: truncation and padding must both be on the right, found `
      + `${shown(trunc, 200)} / ${shown(pad, 200)}`);
  }
  if (!Number.isInteger(trunc.max_length) || trunc.max_length < tok.template.added) {
    throw new TokenizerError(`${source}: truncation.max_length: expected an integer >= ${tok.template.added}, got ${shown(trunc.max_length)}`);
  }
  if (!Number.isInteger(pad.pad_id)) throw new TokenizerError(`${source}: padding.pad_id: expected an integer`);
  const padMultiple = pad.pad_to_multiple_of ?? null;   // more than max_length would pad every batch past it
  if (padMultiple !== null && !(Number.isInteger(padMultiple) && padMultiple >= 1 && padMultiple <= trunc.max_length)) {
    throw new TokenizerError(`${source}: padding.pad_to_multiple_of: expected an integer in [1, ${trunc.max_length}], `
      + `got ${shown(padMultiple)}`);
  }
  return { maxLength: trunc.max_length, padId: pad.pad_id, padMultiple };
}

/** Each normalizer, pre-tokenizer and model in the file (Sequences walked) is one of PARTS (text.py load_tokenizer). */
function checkParts(json, source) {
  const parts = Object.keys(PARTS).map((key) => [key, json[key] ?? null]);
  while (parts.length) {
    const [key, part] = parts.pop();
    if (part === null && key !== 'model') continue;
    if (!PARTS[key].includes(part?.type)) {
      throw new TokenizerError(`${source}: ${key} ${shown(part?.type)} is not one this runtime reads (it reads `
        + `${[...PARTS[key]].sort().join(', ')})`);
    }
    if (part.type === 'Sequence') {
      const inner = part[key === 'normalizer' ? 'normalizers' : 'pretokenizers'];
      parts.push(...(Array.isArray(inner) ? inner.map((p) => [key, p ?? null]) : [[key, false]]));
    }
  }
}

/** A one-character class, from a table of space-separated hex code points and ranges. */
function charClass(table) {
  return new RegExp(`[${table.split(' ').map((r) => r.split('-').map((h) => `\\u{${h}}`).join('-')).join('')}]`, 'u');
}

// ---- added tokens -------------------------------------------------------------------------------------

function parseAddedTokens(list, fail) {
  if (!Array.isArray(list)) fail('added_tokens', 'expected a list');
  return list.map((t, i) => {
    if (typeof t?.content !== 'string' || !t.content || !Number.isInteger(t.id)) {
      fail(`added_tokens[${i}]`, 'expected {id, content}');
    }
    for (const flag of ['single_word', 'lstrip', 'rstrip']) {
      if (t[flag]) fail(`added_tokens[${i}].${flag}`, 'is true; this tokenizer supports plain added tokens only');
    }
    return { content: t.content, id: t.id, normalized: Boolean(t.normalized) };
  });
}

/** Split `text` around occurrences of the tokens (leftmost, then longest): [{text} | {id}] pieces. */
function splitAddedTokens(text, tokens) {
  if (!tokens.length) return [{ text }];
  const pieces = [];
  let last = 0, at = 0;
  while (at < text.length) {
    let match = null;
    for (const t of tokens) {
      if (text.startsWith(t.content, at) && (!match || t.content.length > match.content.length)) match = t;
    }
    if (!match) {
      at++;
      continue;
    }
    if (at > last) pieces.push({ text: text.slice(last, at) });
    pieces.push({ id: match.id });
    at = last = at + match.content.length;
  }
  if (last < text.length) pieces.push({ text: text.slice(last) });
  return pieces;
}

// ---- normalizers --------------------------------------------------------------------------------------

function makeNormalizer(spec) {
  if (spec === null) return (s) => s;
  switch (spec.type) {
    case 'BertNormalizer': {
      const lowercase = spec.lowercase ?? true;
      const steps = [];
      if (spec.clean_text ?? true) steps.push(cleanText);
      if (spec.handle_chinese_chars ?? true) steps.push(spaceChineseChars);
      if (spec.strip_accents ?? lowercase) steps.push((s) => stripAccents(s.normalize('NFD')));   // null: as lowercase
      if (lowercase) steps.push(lowercaseChars);
      return (s) => steps.reduce((acc, step) => step(acc), s);
    }
    case 'Lowercase': return lowercaseChars;
    case 'StripAccents': return (s) => s.replace(/\p{M}/gu, '');   // every combining mark, unlike BERT's
    case 'NFD': case 'NFC': case 'NFKD': case 'NFKC': return (s) => s.normalize(spec.type);
    default: {   // a Sequence (checkParts let no other type through)
      const parts = spec.normalizers.map((n) => makeNormalizer(n ?? null));
      return (s) => parts.reduce((acc, n) => n(acc), s);
    }
  }
}

/** `s` with each character (code point) replaced by f(character). */
const mapChars = (s, f) => Array.from(s, f).join('');

const cleanText = (s) => mapChars(s, (c) => {
  if (c === '\t' || c === '\n' || c === '\r') return ' ';
  if (c === '\0' || c === '\ufffd' || OTHER.test(c)) return '';
  return WHITESPACE.test(c) ? ' ' : c;
});
const spaceChineseChars = (s) => mapChars(s, (c) => (CJK.test(c) ? ` ${c} ` : c));
const stripAccents = (s) => mapChars(s, (c) => (NONSPACING_MARK.test(c) ? '' : c));
// Rust lowercases character by character (no context: a final capital sigma becomes σ, not ς)
const lowercaseChars = (s) => mapChars(s, (c) => c.toLowerCase());

// ---- pre-tokenizers -----------------------------------------------------------------------------------

function makePreTokenizer(spec) {
  if (spec === null) return (s) => (s ? [s] : []);
  switch (spec.type) {
    case 'BertPreTokenizer': return bertPreTokenize;
    case 'Whitespace': return (s) => s.match(WHITESPACE_PRETOKENS) ?? [];
    case 'WhitespaceSplit': return (s) => splitWhitespace(s);
    default: {   // a Sequence
      const parts = spec.pretokenizers.map((p) => makePreTokenizer(p ?? null));
      return (s) => parts.reduce((words, p) => words.flatMap(p), [s]);
    }
  }
}

const splitWhitespace = (s) => s.split(WHITESPACE_RUNS).filter(Boolean);

/** Split on whitespace (dropped), then isolate every punctuation character. */
const bertPreTokenize = (s) => splitWhitespace(s).flatMap((chunk) => chunk.split(PUNCTUATION).filter(Boolean));

// ---- models -------------------------------------------------------------------------------------------

/** A WordLevel or WordPiece model (checkParts let no other type through). */
function makeModel(spec, fail) {
  if (spec.vocab === null || typeof spec.vocab !== 'object' || Array.isArray(spec.vocab)) {
    return fail('model.vocab', 'expected an object of token -> id');
  }
  const vocab = new Map(Object.entries(spec.vocab));
  const unk = vocab.get(spec.unk_token);
  if (unk === undefined) fail('model.unk_token', `${shown(spec.unk_token)} is not in the vocabulary`);
  if (spec.type === 'WordLevel') return { vocab, tokenize: (word) => [vocab.get(word) ?? unk] };
  const prefix = spec.continuing_subword_prefix ?? '##';
  const maxChars = spec.max_input_chars_per_word ?? 100;
  return { vocab, tokenize: (word) => wordPiece(word, vocab, prefix, maxChars, unk) };
}

/** Greedy longest-match-first sub-words; [UNK] for the whole word when any part has no match. */
function wordPiece(word, vocab, prefix, maxChars, unk) {
  const chars = [...word];   // code points, as Rust's chars()
  if (chars.length > maxChars) return [unk];
  const ids = [];
  let start = 0;
  while (start < chars.length) {
    let end = chars.length, id;
    for (; end > start; end--) {
      const piece = (start > 0 ? prefix : '') + chars.slice(start, end).join('');
      id = vocab.get(piece);
      if (id !== undefined) break;
    }
    if (id === undefined) return [unk];
    ids.push(id);
    start = end;
  }
  return ids;
}

// ---- post-processor -----------------------------------------------------------------------------------

/** The single-sequence template, as a function of the content ids; `.added` = its special tokens. */
function makeTemplate(spec, fail) {
  let before = [], after = [];
  if (spec === null) {
    // no template: the ids as they are
  } else if (spec.type === 'BertProcessing') {
    before = [spec.cls?.[1]];
    after = [spec.sep?.[1]];
  } else if (spec.type === 'TemplateProcessing') {
    const single = spec.single ?? [];
    const seq = single.findIndex((p) => p.Sequence);
    if (seq < 0 || single.filter((p) => p.Sequence).length !== 1) fail('post_processor.single', 'expected one Sequence');
    const ids = (p) => {
      const tok = spec.special_tokens?.[p.SpecialToken?.id];
      if (!tok) fail('post_processor.single', `special token ${shown(p.SpecialToken?.id)} is not in special_tokens`);
      return tok.ids;
    };
    before = single.slice(0, seq).flatMap(ids);
    after = single.slice(seq + 1).flatMap(ids);
  } else {
    fail('post_processor.type', `unsupported post-processor ${shown(spec.type)}`);
  }
  if (![...before, ...after].every(Number.isInteger)) fail('post_processor', 'special token ids must be integers');
  const template = (ids) => [...before, ...ids, ...after];
  template.added = before.length + after.length;
  return template;
}
