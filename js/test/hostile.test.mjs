// Hostile files and values (runtime/mogo_runtime/checks.py read_file and shown): a file larger than it may be is
// refused before it is read, and never read past its limit whatever its size says; a device, a pipe, a folder or a
// link is refused unread; a server's body is read no further than the limit; and an error message stays one short
// line whatever a file name, a prompt or a setting holds.

import test from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { cpSync, mkdtempSync, readFileSync, rmSync, symlinkSync, truncateSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { Bundle } from '../src/bundle/folder.js';
import { fileLoader, urlLoader } from '../src/bundle/io.js';
import { parseManifest } from '../src/bundle/manifest.js';
import { BundleError } from '../src/bundle/sections.js';
import { MotionGenerator } from '../src/generator.js';
import { readReference } from './reference.mjs';

const toy = readReference('bundle-toy.json');
const work = mkdtempSync(join(tmpdir(), 'mogo-hostile-'));
test.after(() => rmSync(work, { recursive: true, force: true }));
const WALK = 'a person walks forward';
const MIB = 1 << 20;

/** A copy of the toy bundle, its manifest edited by `edit` (and saved unless it returns false). */
function copy(name, edit = () => {}) {
  const dir = join(work, name), path = join(dir, 'manifest.json');
  cpSync(toy.path, dir, { recursive: true });
  const manifest = JSON.parse(readFileSync(path, 'utf8'));
  if (edit(manifest, dir) !== false) writeFileSync(path, JSON.stringify(manifest));
  return dir;
}

/** Resident memory added, and milliseconds taken, while `run()` is refused. */
async function refusedCost(run, pattern) {
  const rss = process.memoryUsage().rss, start = performance.now();
  await assert.rejects(run(), (e) => e instanceof BundleError && pattern.test(e.message) && !e.message.includes('\n'));
  return { grew: (process.memoryUsage().rss - rss) / MIB, ms: performance.now() - start };
}

test('a manifest or a graph larger than it may be is refused before a byte is read', async () => {
  const big = copy('big-manifest', (m, dir) => {
    truncateSync(join(dir, 'manifest.json'), 256 * MIB);   // sparse: it costs no disk, but would cost memory read
    return false;
  });
  const manifest = await refusedCost(() => Bundle.load(fileLoader(big)),
    /manifest\.json: 268,435,456 bytes, more than the 16,777,216 bytes expected/);
  const graph = copy('big-graph', (m, dir) => truncateSync(join(dir, 'step.onnx'), 256 * MIB));
  const step = await refusedCost(() => MotionGenerator.load(graph),
    /step\.onnx: listed in manifest 'files' but cannot be read \(.*step\.onnx: 268,435,456 bytes, more than the [\d,]+ bytes expected\)/);
  for (const { grew, ms } of [manifest, step]) assert.ok(grew < 64 && ms < 2000, `refused after ${ms} ms, ${grew} MiB more`);
  const huge = copy('huge-graph', (m, dir) => {
    truncateSync(join(dir, 'step.onnx'), 2 ** 31);
    m.files['step.onnx'].bytes = 2 ** 31;
  });
  await assert.rejects(MotionGenerator.load(huge), /step\.onnx: 2147483648 bytes; an ONNX graph without external data is at most/);
});

test('a manifest of 2**31 layers is refused before any cache name is made', () => {
  const m = JSON.parse(readFileSync(join(toy.path, 'manifest.json'), 'utf8')), start = performance.now();
  m.model.n_layers = 2 ** 31;
  assert.throws(() => parseManifest(m, 'm.json'), /m\.json: field graphs\.step\.inputs: 6 tensors; model\.n_layers 2147483648 makes/);
  assert.ok(performance.now() - start < 1000);
});

test('a file is never read past its limit, whatever its size says; devices, pipes, folders and links are refused unread', async () => {
  // /proc files say they hold 0 bytes
  await assert.rejects(fileLoader('/proc/self').readBytes('status', 16), /status: more than the 16 bytes expected/);
  assert.ok((await fileLoader('/proc/self').readBytes('status', MIB)).length > 16);
  await assert.rejects(fileLoader('/dev').readBytes('zero', MIB), /\/dev\/zero: not a regular file \(a device or a pipe\)/);
  execFileSync('mkfifo', [join(work, 'pipe')]);   // opened without O_NONBLOCK, it would wait for a writer for ever
  await assert.rejects(fileLoader(work).readBytes('pipe', MIB), /pipe: not a regular file \(a device or a pipe\)/);
  await assert.rejects(fileLoader(toy.path).readBytes('.', MIB), /: not a regular file \(a folder\)/);
  const linked = copy('linked-manifest', (m, dir) => {
    cpSync(join(dir, 'manifest.json'), join(work, 'elsewhere.json'));
    rmSync(join(dir, 'manifest.json'));
    symlinkSync(join(work, 'elsewhere.json'), join(dir, 'manifest.json'));   // a valid manifest, elsewhere
    return false;
  });
  await assert.rejects(Bundle.load(fileLoader(linked)), /manifest\.json: a link \(bundle files cannot be links\)/);
});

test('a server is read no further than the limit, whatever it says the size is', async () => {
  let pulled = 0;
  const spaces = (headers = {}) => async () => new Response(new ReadableStream({   // 64 MiB, a MiB at a time
    pull(controller) {
      pulled += MIB;
      controller.enqueue(new Uint8Array(MIB).fill(32));
      if (pulled === 64 * MIB) controller.close();
    },
  }, { highWaterMark: 0 }), { headers });
  await assert.rejects(Bundle.load(urlLoader('https://example.test/b', spaces())),
    /manifest\.json: more than the 16,777,216 bytes expected/);
  assert.ok(pulled <= 18 * MIB, `${pulled / MIB} MiB pulled for a limit of 16`);
  pulled = 0;
  await assert.rejects(Bundle.load(urlLoader('https://example.test/b', spaces({ 'content-length': String(2 ** 40) }))),
    /manifest\.json: 1,099,511,627,776 bytes, more than the 16,777,216 bytes expected/);
  assert.equal(pulled, 0);
  const bytes = readFileSync(join(toy.path, 'manifest.json'));
  const served = await urlLoader('https://example.test/b', async () => new Response(bytes)).readBytes('manifest.json', bytes.length);
  assert.deepEqual(Buffer.from(served), bytes);
});

test('error messages quote hostile values on one short line', async () => {
  const evil = copy('evil-name', (m) => {
    m.files['evil\nstep.onnx'] = m.files['step.onnx'];
    m.variants.fp32.step.file = 'evil\nstep.onnx';
  });
  await assert.rejects(MotionGenerator.load(evil),
    (e) => e instanceof BundleError && e.message.includes('evil\\nstep.onnx: missing') && !e.message.includes('\n'));
  const long = copy('long-name', (m) => { m.files[`${'x'.repeat(300)}.onnx`] = m.files['lookup.onnx']; });
  await assert.rejects(MotionGenerator.load(long),
    (e) => /a file name of more than 255 bytes/.test(e.message) && e.message.length < 300);
  const gen = await MotionGenerator.load(toy.path);
  const oneShortLine = (most) => (e) => !e.message.includes('\n') && e.message.length < most;
  await assert.rejects(gen.generate(' '.repeat(10_000)), oneShortLine(300));
  await assert.rejects(gen.generate('\n'), (e) => e.message.includes('("\\n")'));
  const timeline = [[WALK, 0], ...Array.from({ length: 9999 }, (_, i) => ['a person jumps twice', i + 1])];
  await assert.rejects(gen.generate(timeline, { seconds: 5 }), oneShortLine(400));
  await assert.rejects(gen.generate([[WALK, 0], ['a person jumps', 1e6]], { seconds: 5 }), /a timeline start: it must be between/);
  await assert.rejects(MotionGenerator.load(toy.path, { variant: 'x\n'.repeat(10_000) }), oneShortLine(300));
  await assert.rejects(gen.generate(WALK, { sampling: { ['k\n'.repeat(5000)]: 1 } }), oneShortLine(300));
  await assert.rejects(gen.generate(WALK, { seconds: 'x'.repeat(10_000) }), oneShortLine(300));
  await assert.rejects(gen.generate(WALK, { seed: 'x'.repeat(10_000) }), oneShortLine(300));
});
