// One controlled stream of tests/golden/toy_control.json, run and compared as tests/golden/make_golden.py's
// run_control_case runs it: shared by Node's golden test (golden.test.mjs) and the browser's (web/test/page.test.mjs
// imports it into the page), so both read the stream the same way. No Node imports: it runs in a page too.

const REQUEST_METHODS = { walk_to: 'walkTo', follow_path: 'followPath', steer: 'steer', set_root: 'setRoot', release: 'release' };

export const CONTROL_TOLERANCE = 1e-5;   // a control vector is read from joints, which onnxruntime builds may round apart

/**
 * A golden case `c` on `gen` (a MotionGenerator of the control toy bundle) read frame by frame -> {tokens, controls,
 * landed, arrived}: each request made before the first frame of its token is read; the tokens and their controls
 * read from the stream's context as they are picked (its ring holds the last few).
 */
export async function runControlCase(gen, c, sampling) {
  const s = await gen.stream(c.text, { seconds: c.seconds, seed: BigInt(c.seed), sampling });
  const context = s.steering.context, ds = gen.dims.downsample, L = gen.dims.numLevels, C = context.controlDim;
  const out = { tokens: [], controls: [], landed: [], arrived: [] };
  for (let frames = 0; ; frames++) {
    if (frames % ds === 0) {
      for (const [t, name, args] of c.requests) {
        if (t !== frames / ds) continue;
        s[REQUEST_METHODS[name]](...args);
        out.landed.push(s.tokens);
      }
    }
    if ((await s.next()).done) break;
    if (context.count - out.tokens.length > context.span) throw new Error('tokens picked faster than the ring holds them');
    for (let t = out.tokens.length; t < context.count; t++) {
      const slot = t % context.span;
      out.tokens.push(Array.from(context.history.subarray(slot * L, (slot + 1) * L)));
      out.controls.push(Array.from(context.controls.subarray(slot * C, (slot + 1) * C)));
    }
    if ((frames + 1) % ds === 0) out.arrived.push(s.arrived);
  }
  return out;
}

/**
 * `got` against golden case `c` -> {same: tokens, landing tokens and arrivals identical and every control vector
 * within CONTROL_TOLERANCE, vectors, exact: bit-identical vectors, worst: the largest difference}.
 */
export function compareControlCase(got, c) {
  const diffs = got.controls.slice(0, c.controls.length)
    .map((v, t) => Math.max(...v.map((x, k) => Math.abs(x - c.controls[t][k]))));
  const worst = Math.max(0, ...diffs);
  const close = got.controls.length === c.controls.length && worst <= CONTROL_TOLERANCE;
  const identical = ['tokens', 'landed', 'arrived'].every((k) => JSON.stringify(got[k]) === JSON.stringify(c[k]));
  return { same: identical && close, vectors: diffs.length, exact: diffs.filter((d) => d === 0).length, worst };
}

/** The sampling settings of a golden case (Python's names) as the JavaScript runtime takes them. */
export const samplingOf = (cfg) => ({
  temperature: cfg.temperature, topK: cfg.top_k ?? null, topP: cfg.top_p ?? null, guidance: cfg.guidance ?? 1,
});
