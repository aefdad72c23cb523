// The JavaScript runtime against the Python runtime on whole bundles: the same tokens for the same prompt,
// seed and settings (greedy and sampled, guidance 1 and 2, clips, fixed lengths with restarts, batches,
// timelines, a stream whose prompt changes), embeddings within 1e-5, joints within 1e-4 m.

import test from 'node:test';
import assert from 'node:assert/strict';
import { MotionGenerator } from '../src/generator.js';
import { SamplingConfig } from '../src/bundle/sampling.js';
import { EndlessLoop } from '../src/endless.js';
import { compareControlCase, runControlCase, samplingOf } from './control_case.mjs';
import { bundleReferences, maxAbsDiff, report } from './reference.mjs';

const EMBEDDING_TOLERANCE = 1e-5;
const JOINT_TOLERANCE = 1e-4;   // metres

const sampling = (cfg) => (cfg === null ? null : new SamplingConfig({
  temperature: cfg.temperature, topK: cfg.top_k, topP: cfg.top_p, guidance: cfg.guidance,
}));
const rows = (data, width) => Array.from({ length: data.length / width }, (_, i) => Array.from(data.slice(i * width, (i + 1) * width)));

for (const ref of bundleReferences()) {
  for (const [variant, want] of Object.entries(ref.variants)) {
    test(`${ref.name} bundle, ${variant}: the JavaScript runtime gives the Python runtime's tokens and motions`, async (t) => {
      const gen = await MotionGenerator.load(ref.path, { variant, threads: 1 });
      const L = gen.dims.numLevels;
      const stats = { tokens: 0, embedding: 0, logits: 0, features: 0, joints: 0, restarts: 0 };
      const sameTokens = (got, expected, what) => {
        assert.deepEqual(rows(got, L), expected, what);
        stats.tokens += got.length;
      };
      const sameMotion = (m, expected, what) => {
        sameTokens(m.tokens.data, expected.tokens, what);
        stats.features = Math.max(stats.features, maxAbsDiff(m.features.data, expected.features));
        stats.joints = Math.max(stats.joints, maxAbsDiff(m.joints.data, expected.joints));
      };

      await t.test('tokenizer ids, text embeddings and the first step logits', async () => {
        const { inputIds, attentionMask } = gen.backend.tokenizer.encodeBatch(want.prompts);
        assert.deepEqual(Array.from(inputIds, Number), want.input_ids.flat());
        assert.deepEqual(Array.from(attentionMask, Number), want.attention_mask.flat());
        const batched = await gen.backend.encodeText(want.prompts);
        const single = [];
        for (const p of want.prompts) single.push(...(await gen.backend.encodeText([p])));
        stats.embedding = Math.max(maxAbsDiff(batched, want.embeddings), maxAbsDiff(single, want.embeddings_single));
        assert.ok(stats.embedding <= EMBEDDING_TOLERANCE, `embeddings differ by ${stats.embedding}`);
        const bos = new Int32Array(L).fill(gen.dims.bosId);
        const { logits } = await gen.backend.step(Float32Array.from(single.slice(0, gen.dims.textDim)), bos, 1, gen.backend.emptyPast(1));
        stats.logits = maxAbsDiff(logits, want.first_logits);
        assert.ok(stats.logits <= 1e-4, `first step logits differ by ${stats.logits}`);
      });

      await t.test('single prompts: prompts x seeds x sampling settings, clips and fixed lengths', async () => {
        for (const c of want.cases) {
          const m = await gen.generate(c.text, { seed: BigInt(c.seed), seconds: c.seconds, sampling: sampling(c.sampling) });
          sameTokens(m.tokens.data, c.tokens, `${c.text} seed ${c.seed} ${JSON.stringify(c.sampling)} ${c.seconds} s`);
        }
      });

      await t.test('a batch of prompts in one loop', async () => {
        const motions = await gen.generate(want.batch.texts, { seed: BigInt(want.batch.seed) });
        motions.forEach((m, i) => sameTokens(m.tokens.data, want.batch.tokens[i], `batch prompt ${i}`));
      });

      await t.test('a batch of prompts with a fixed length (endless bundles: one EndlessLoop of several streams)', async () => {
        const w = want.batch_fixed;
        const motions = await gen.generate(w.texts, { seed: BigInt(w.seed), seconds: w.seconds, sampling: sampling(w.sampling) });
        motions.forEach((m, i) => sameTokens(m.tokens.data, w.tokens[i], `fixed batch prompt ${i}`));
      });

      await t.test('features and joints of whole motions', async () => {
        for (const c of want.motions) {
          const m = await gen.generate(c.text, { seed: BigInt(c.seed), seconds: c.seconds, sampling: sampling(c.sampling) });
          sameMotion(m, c, `${c.text} seed ${c.seed}`);
        }
      });

      await t.test('the same motion on every platform: 20 prompts x 3 seeds, greedy and the sampling defaults', async () => {
        let worst = 0;
        for (const c of want.cross) {
          const m = await gen.generate(c.text, { seed: BigInt(c.seed), sampling: sampling(c.sampling) });
          sameTokens(m.tokens.data, c.tokens, `${c.text} seed ${c.seed} ${JSON.stringify(c.sampling)}`);
          worst = Math.max(worst, maxAbsDiff(m.joints.data, c.joints));
        }
        assert.equal(want.cross.length, 20 * 3 * 2);
        assert.ok(worst <= JOINT_TOLERANCE, `joints differ by ${worst} m`);
        stats.joints = Math.max(stats.joints, worst);
        report(`${ref.name}/${variant}: 20 prompts x 3 seeds x 2 samplings, tokens identical, joints max |diff| ${worst.toExponential(2)} m`);
      });

      if (want.timeline) {
        await t.test('an endless timeline: prompt switches, context rebuilds, restarts', async () => {
          const { timeline, seconds, seed } = want.timeline;
          sameMotion(await gen.generate(timeline, { seconds, seed: BigInt(seed) }), want.timeline, 'timeline');
        });
      }

      if (want.timeline) {
        await t.test('a prompt switch asked for while a step is running lands cleanly at the next token', async () => {
          const [first, second] = [want.prompts[0], want.prompts[1]];
          const perToken = gen.dims.downsample / gen.fps, frames = 40 * gen.dims.downsample;
          const s = await gen.stream(first, { seed: 5n, chunk: 1 });
          // the switch is asked for, and its text encoded, while the 30th step call is still running
          const step = gen.backend.step;
          let calls = 0;
          gen.backend.step = async (...args) => {
            const out = await step.apply(gen.backend, args);
            if (++calls === 30) await s.setPrompt(second);
            return out;
          };
          const joints = [];
          try {
            for await (const frame of s) {
              joints.push(...frame.joints);
              if (frame.index + 1 === frames) break;
            }
          } finally {
            delete gen.backend.step;
          }
          assert.equal(s.switches.length, 1);
          const at = s.switches[0].token;
          const want2 = await gen.generate([[first, 0], [second, at * perToken]], { seconds: frames / gen.fps, seed: 5n });
          const err = maxAbsDiff(joints, Array.from(want2.joints.data));
          assert.ok(err <= 1e-5, `the stream is not the timeline switching at token ${at}: joints differ by ${err} m`);
        });
      }

      if (want.loop) {
        await t.test('an EndlessLoop of two streams, step by step, with its END restarts', async () => {
          const w = want.loop;
          const loop = new EndlessLoop(gen.backend, await gen.backend.encodeText(w.texts), sampling(w.sampling),
            w.seeds.map(BigInt), gen.bundle.manifest.streaming);
          for (const [step, expected] of w.tokens.entries()) {
            assert.deepEqual(rows(await loop.step(), L), expected, `step ${step}`);
            stats.tokens += expected.length * L;
          }
          assert.equal(loop.restarts, w.restarts);
          stats.restarts = loop.restarts;
        });
      }

      await t.test(want.timeline ? 'a stream whose prompt changes while its frames are read' : 'a clip streamed frame by frame', async () => {
        const w = want.stream;
        const switchAt = new Map(w.switch_at);
        const s = await gen.stream(w.text, { seed: BigInt(w.seed), chunk: w.chunk });
        const features = [], joints = [];
        for await (const frame of s) {
          features.push(...frame.features);
          joints.push(...frame.joints);
          if (switchAt.has(frame.index)) s.setPrompt(switchAt.get(frame.index));
          if (frame.index + 1 === w.frames) await s.close();
        }
        assert.deepEqual(s.switches.map(({ token, text }) => [token, text]), w.switches);
        stats.features = Math.max(stats.features, maxAbsDiff(features, w.features));
        const err = maxAbsDiff(joints, w.joints);
        stats.joints = Math.max(stats.joints, err);
        assert.ok(err <= JOINT_TOLERANCE, `stream joints differ by ${err} m`);
        assert.equal(joints.length, w.joints.length);
        if (!gen.endless) assert.throws(() => s.setPrompt('a person waves'), /not trained for endless streams/);
      });

      if (want.control) {
        await t.test('controlled streams: requests at the same frames give the same tokens', () => checkControl(gen, want.control, ref, variant));
      }

      report(`${ref.name}/${variant}: ${stats.tokens} token ids identical; max |diff| embeddings ${stats.embedding.toExponential(2)}, `
        + `first logits ${stats.logits.toExponential(2)}, features ${stats.features.toExponential(2)}, joints ${stats.joints.toExponential(2)} m`
        + (want.loop ? `; END restarts in the two-stream loop: ${stats.restarts}` : ''));
      assert.ok(stats.joints <= JOINT_TOLERANCE, `joints differ by ${stats.joints} m`);
      await gen.release();
    });
  }
}

/** tests/golden/make_golden.py's controlled streams on a bundle with control, as Python ran them (make_reference.py). */
async function checkControl(gen, cases, ref, variant) {
  let same = 0, vectors = 0, exact = 0, worst = 0, tokens = 0;
  const wrong = [];
  for (const [i, c] of cases.entries()) {
    const r = compareControlCase(await runControlCase(gen, c, new SamplingConfig(samplingOf(c.sampling))), c);
    [vectors, exact, worst, tokens] = [vectors + r.vectors, exact + r.exact, Math.max(worst, r.worst), tokens + c.tokens.length];
    if (r.same) same += 1;
    else wrong.push(i);
  }
  report(`${ref.name}/${variant}: ${same} of ${cases.length} controlled streams (${tokens} tokens) identical to Python's; `
    + `control vectors ${exact} of ${vectors} bit-identical, max |diff| ${worst.toExponential(1)}`);
  assert.deepEqual(wrong, [], `controlled streams ${wrong.join(', ')} differ`);
}
