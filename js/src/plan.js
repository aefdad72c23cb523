// A prompt that names several actions, split into the actions it names, in order: `planActions`, as
// runtime/mogo_runtime/plan.py (same rules, same word tables; both are held to tests/golden/plans.json).
//
//   planActions('a person walks forward and then jumps')
//     -> [{ text: 'a person walks forward', seconds: null }, { text: 'a person jumps', seconds: null }]
//   planActions('someone waves for 3 seconds, then sits down')
//     -> [{ text: 'someone waves', seconds: 3 }, { text: 'someone sits down', seconds: null }]
//
// On a bundle trained for endless streams the runtime plays them one after another (endless.js StreamContext): each
// action until the model ends it (END), or for its stated duration ('for 3 seconds'), then the next. A prompt is cut
// at the sequence words of SEQUENCE_WORDS and at sentence ends; commas cut too, but only in a prompt that has a
// sequence word ('walks left, waves, and then sits down'), so 'waves, slowly' stays one action. The first action's
// subject ('a person', 'the man') is given to the later ones that have none, or have a pronoun ('then he jumps').
//
// The regular expressions are Python's, written so that JavaScript matches what Python's `re` matches on str: `\s`
// is Python's whitespace (str.isspace), `\d` any decimal digit (\p{Nd}; float() reads them), `\b` a boundary of
// Python's word characters (letters, numbers, _), and re.I's case folding spelled out letter by letter (Python's re
// matches 'İ' and 'ı' to i, 'ſ' to s, the Kelvin sign to k; JavaScript's /i does not all of these).

import { shown } from './checks.js';

export const MAX_ACTIONS = 8;        // as many actions as the training captions name at most
export const MOST_SECONDS = 600;     // a stated duration, at most (an endless stream's fixed length is at most this too)
export const SEQUENCE_WORDS = ['and then', 'and after that', 'and afterwards', 'and afterward', 'after that', 'afterwards',
  'afterward', 'then', 'followed by', 'and finally', 'finally', 'and next'];
export const SUBJECTS = ['a person', 'the person', 'this person', 'a man', 'the man', 'a woman', 'the woman', 'a human',
  'someone', 'a character', 'the character', 'a guy', 'the guy', 'a girl', 'a boy'];
export const PRONOUNS = ['he', 'she', 'they', 'it'];
export const NUMBER_WORDS = { a: 1, an: 1, one: 1, two: 2, three: 3, four: 4, five: 5, six: 6, seven: 7, eight: 8,
  nine: 9, ten: 10, fifteen: 15, twenty: 20, thirty: 30, 'half a': 0.5 };
export const UNITS = { seconds: 1, second: 1, secs: 1, sec: 1, s: 1, minutes: 60, minute: 60, min: 60 };

const SPACE = '\\t\\n\\v\\f\\r\\x1c-\\x20\\x85\\xa0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000';   // str.isspace
const S = `[${SPACE}]`, NS = `[^${SPACE}]`, D = '\\p{Nd}', W = '[\\p{L}\\p{N}_]';
const FOLD = { i: 'iIİı', s: 'sSſ', k: 'kKK' };                                // re.I, as Python's re folds
const LETTER = '[a-zA-ZİıſK]';                                                 // [a-z] under re.I
const ignoringCase = (word) => [...word].map((c) => (/[a-z]/.test(c) ? `[${FOLD[c] ?? c + c.toUpperCase()}]` : c)).join('');
const escaped = (word) => word.replace(/[.*+?^${}()|[\]\\]/g, '\\$&');
const longestFirst = (words) => [...words].sort((a, b) => b.length - a.length);   // stable, as sorted(key=len, reverse=True)

const SEQUENCE_SOURCE = SEQUENCE_WORDS.map((w) => `(?<!${LETTER})${ignoringCase(escaped(w))}(?!${LETTER})`).join('|');
const SENTENCE_END = `(?:[;!?]|\\.(?!${D}))`;
const SEQUENCE = new RegExp(SEQUENCE_SOURCE, 'u');
const CUT = new RegExp(`${S}*,?${S}*(?:${SEQUENCE_SOURCE})${S}*,?${S}*|${S}*${SENTENCE_END}+${S}*|${S}*(?:->|=>)${S}*`, 'u');
const MAY_SPLIT = new RegExp(`${SENTENCE_END}${S}*${NS}|->|=>|(?<!${W})for${S}`, 'u');
const DURATION = new RegExp(`${S}*,?${S}*(?<!${W})for${S}+(${D}+(?:\\.${D}+)?|`
  + `${longestFirst(Object.keys(NUMBER_WORDS)).map(escaped).join('|')})${S}*(${longestFirst(Object.keys(UNITS)).join('|')})(?!${W})`, 'u');
const SUBJECT = new RegExp(`^(?:${[...SUBJECTS, ...PRONOUNS].map(escaped).join('|')})(?![a-z])`, 'u');
const FIRST = new RegExp(`^${ignoringCase('first')}${S}+`, 'u');
const SPACES = new RegExp(`${S}+`, 'gu');
const STRIP = new RegExp(`^${S}+|${S}+$`, 'gu');
const LEFT = new RegExp(`^${S}+`, 'u');
// Lower case for matching: ASCII letters only, so a match's indices are the same in the text as typed (toLowerCase
// changes some texts' length: 'İ' -> 'i̇'), in every runtime.
const lower = (text) => text.replace(/[A-Z]+/g, (c) => c.toLowerCase());
const stripped = (text, chars = null) => (chars === null ? text.replace(STRIP, '')
  : text.replace(new RegExp(`^[${chars}]+|[${chars}]+$`, 'g'), ''));

/**
 * The actions `text` names, in order: [{text, seconds (null: until the model ends it)}] (one, for a prompt of one
 * action: its text as given). RangeError for more than MAX_ACTIONS actions or a stated duration outside
 * (0, MOST_SECONDS].
 */
export function planActions(text) {
  const low = lower(text), sequenced = SEQUENCE.test(low);
  if (!sequenced && !MAY_SPLIT.test(low)) return [{ text, seconds: null }];   // one action, as typed: untouched
  let pieces = stripped(text).split(CUT);
  if (sequenced) pieces = pieces.flatMap((piece) => piece.split(','));
  const parts = pieces.map((p) => stripped(p.replace(SPACES, ' '), ' ,')).filter(Boolean);
  if (parts.length > MAX_ACTIONS) {
    throw new RangeError(`a prompt names at most ${MAX_ACTIONS} actions, this one ${parts.length}: give the rest with `
      + 'setPrompt, or as a timeline [[prompt, startSeconds], ...]');
  }
  const subject = parts.length ? subjectOf(parts[0]) : null;
  const out = [];
  for (const part of parts) {
    const [p, seconds] = duration(part);
    const own = subjectOf(p);
    const rest = (own ? p.slice(own.length).replace(LEFT, '') : p).replace(FIRST, '');   // 'a person first ...'
    const who = subject && (own === null || PRONOUNS.includes(lower(own))) ? subject : own;
    if (rest) out.push({ text: who ? `${who} ${rest}` : rest, seconds });
  }
  return out.length ? out : [{ text, seconds: null }];
}

// Python cuts `part` at a match's indices in characters (code points): so does this.
const chars = (text) => [...text];

function subjectOf(part) {
  const m = SUBJECT.exec(lower(part));
  return m ? chars(part).slice(0, chars(m[0]).length).join('') : null;
}

/** A part without its 'for N seconds', and N (null without one). */
function duration(part) {
  const m = DURATION.exec(lower(part));
  if (m === null) return [part, null];
  const [, amount, unit] = m;
  const seconds = (amount in NUMBER_WORDS ? NUMBER_WORDS[amount] : Number(asciiDigits(amount))) * UNITS[unit];
  const all = chars(part), start = chars(m.input.slice(0, m.index)).length, end = start + chars(m[0]).length;
  if (!(seconds > 0 && seconds <= MOST_SECONDS)) {
    throw new RangeError(`an action's duration must be more than 0 and at most ${MOST_SECONDS} seconds, got `
      + `${shown(stripped(all.slice(start, end).join('')))}`);
  }
  return [stripped(all.slice(0, start).join('') + all.slice(end).join(''), ' ,'), seconds];
}

/** Decimal digits of any script as ASCII ones, as Python's float() reads them (each script's digits run 0 to 9). */
function asciiDigits(number) {
  return [...number].map((c) => {
    if (c === '.' || (c >= '0' && c <= '9')) return c;
    let zero = c.codePointAt(0);
    while (/\p{Nd}/u.test(String.fromCodePoint(zero - 1))) zero -= 1;
    return String((c.codePointAt(0) - zero) % 10);
  }).join('');
}
