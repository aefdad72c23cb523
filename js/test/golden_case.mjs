// One case of tests/golden/toy.json, run as tests/golden/make_golden.py's run_case runs it: shared by Node's golden
// test (golden.test.mjs) and the browser's (web/test/page.test.mjs imports it into the page), so both read it the
// same way. No Node imports: it runs in a page too.

const RESULTS = ['tokens', 'aligned', 'landed'];   // what a case checks, those of them it holds (make_golden.RESULTS)

/** A motion's (T, L) tokens as nested arrays, as the golden file holds them. */
function rows(data, L) {
  return Array.from({ length: data.length / L }, (_, t) => Array.from(data.subarray(t * L, (t + 1) * L)));
}

/**
 * Golden case `c` on `gen` (a MotionGenerator of the toy bundle) -> {tokens: one (T, L) list per motion, and where a
 * prompt was split into its actions, aligned: each motion's alignedText}; a stream case (`c.stream`: [token, prompt]
 * switches, each made before the first frame of its token is read): {tokens: [the stream's tokens], aligned: its
 * alignedText at the start and after each switch, landed: the token each switch landed at}.
 */
export async function runGoldenCase(gen, c, sampling) {
  const L = gen.dims.numLevels;
  if (c.stream) return runStream(gen, c, sampling);
  const out = await gen.generate(c.text, { seconds: c.seconds ?? null, seed: BigInt(c.seed), sampling });
  const motions = Array.isArray(out) ? out : [out];
  const got = { tokens: motions.map((m) => rows(m.tokens.data, L)) };
  if (motions.some((m) => m.alignedText !== null)) got.aligned = motions.map((m) => m.alignedText);
  return got;
}

async function runStream(gen, c, sampling) {
  const s = await gen.stream(c.text, { seconds: c.seconds ?? null, seed: BigInt(c.seed), sampling });
  const context = s.loop.streams[0], ds = gen.dims.downsample, L = gen.dims.numLevels;
  const tokens = [], aligned = [s.alignedText], landed = [];
  for (let frames = 0; ; frames++) {
    if (frames % ds === 0) {
      for (const [t, text] of c.stream) {
        if (t !== frames / ds) continue;
        await s.setPrompt(text);
        landed.push(s.switches[s.switches.length - 1].token);
        aligned.push(s.alignedText);
      }
    }
    if ((await s.next()).done) break;
    if (context.count - tokens.length > context.span) throw new Error('tokens picked faster than the ring holds them');
    for (let t = tokens.length; t < context.count; t++) {
      const slot = t % context.span;
      tokens.push(Array.from(context.history.subarray(slot * L, (slot + 1) * L)));
    }
  }
  return { tokens: [tokens], aligned, landed };
}

/** Whether `got` (runGoldenCase) is what golden case `c` holds. */
export function sameAsGolden(got, c) {
  const want = Object.fromEntries(RESULTS.filter((k) => k in c).map((k) => [k, c[k]]));
  return JSON.stringify(got) === JSON.stringify(want);
}
