// The page's downloads: the motion on screen as the BVH and the JSON the Python runtime writes for the same joints
// (app.js keeps the motion: {frames, fps, texts, seed, kind, variant, tokens, levels, switches}).

import { jointsToBvhText } from '../js/src/outputs/bvh.js';

const JSON_DECIMALS = 4;   // as runtime/mogo_runtime/outputs/motion.py writes .json files: 0.1 mm

function joinedJoints(m, skeleton) {
  const J3 = skeleton.parents.length * 3;
  const out = new Float32Array(m.frames.length * J3);
  m.frames.forEach((f, i) => out.set(f, i * J3));
  return out;
}

export function bvhText(m, skeleton) {
  return jointsToBvhText(joinedJoints(m, skeleton), m.frames.length, skeleton, { fps: m.fps });
}

/** The `.json` the Python runtime writes (Motion.to_dict), plus what made it: variant, tokens, prompt switches. */
export function jsonText(m, sk, bundle) {
  const J3 = sk.parents.length * 3;
  const frames = m.frames.map((f) => Array.from({ length: J3 / 3 }, (_, j) => [0, 1, 2].map((k) => roundTo(f[3 * j + k], JSON_DECIMALS))));
  const data = {
    text: m.texts.join(' | '), aligned_text: null, seed: '@SEED@', fps: m.fps, num_frames: m.frames.length,
    skeleton: sk, frames,
    variant: m.variant, bundle,
    tokens: m.tokens ? Array.from({ length: m.tokens.length / m.levels }, (_, t) => Array.from(m.tokens.subarray(t * m.levels, (t + 1) * m.levels))) : null,
    prompts: [{ text: m.texts[0], token: 0, frame: 0 }, ...m.switches],
  };
  // the seed is a BigInt: written as JSON's integer (no prompt can hold this text unescaped)
  return JSON.stringify(data).replace('"seed":"@SEED@"', `"seed":${m.seed}`);
}

/** numpy's round(x, decimals): x * 10**d rounded half to even, divided back. */
function roundTo(x, decimals) {
  const f = 10 ** decimals, y = x * f, r = Math.round(y);
  return (Math.abs(y % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r) / f;
}

export function download(text, name, type) {
  const url = URL.createObjectURL(new Blob([text], { type }));
  const a = Object.assign(document.createElement('a'), { href: url, download: name });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

export function fileStem(m) {
  const words = m.texts[0].toLowerCase().replace(/[^a-z0-9]+/g, '_').replace(/^_|_$/g, '').slice(0, 48) || 'motion';
  return `${words}_seed${m.seed}${m.kind === 'stream' ? '_stream' : ''}`;
}
