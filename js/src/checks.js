// Values from outside (a manifest, a graph file, a user's arguments) in error messages, as runtime/mogo_runtime/
// checks.py `shown` and cli.py `one_line`: a message stays one short line, whatever a file name or a prompt holds.

const CONTROL = /[\p{Cc}\p{Cf}\p{Zl}\p{Zp}]/gu;   // what could add a line, move the cursor or reverse the text

/** `text` with control characters escaped (a newline in a file name adds no line), cut after `limit` characters. */
export function oneLine(text, limit = 1000) {
  const line = String(text).replace(CONTROL, (c) => ({ '\n': '\\n', '\r': '\\r', '\t': '\\t' })[c]
    ?? `\\u${c.codePointAt(0).toString(16).padStart(4, '0')}`);
  return line.length <= limit ? line : `${line.slice(0, limit).replace(/[\ud800-\udbff]$/, '')}...`;
}

/** `value` for an error message: as JSON (a string quoted), on one line, cut after `limit` characters. */
export function shown(value, limit = 60) {
  let text;
  try {
    // NaN and infinities as themselves (JSON writes null); undefined or a function: not JSON
    text = typeof value === 'number' ? String(value) : JSON.stringify(value) ?? String(value);
  } catch {
    text = String(value);                             // a BigInt, an object with a cycle
  }
  return oneLine(text, limit);
}

/** `value`, a number in [lo, hi] (checks.py as_real): a TypeError for a non-number, a RangeError outside. */
export function asReal(name, value, must, lo = -Infinity, hi = Infinity) {
  if (typeof value !== 'number') throw new TypeError(`${name} must be a number ${must}, got ${shown(value)}`);
  if (!(value >= lo && value <= hi)) throw new RangeError(`${name} must be ${must}, got ${shown(value)}`);
  return value;
}
