// The JavaScript ServerClient (src/serve/client.js) against a real `mogo serve` (runtime/mogo_runtime/serve) on the
// portable toy's compact variant, started here and stopped when the file ends, however it ends (test/until_eof.py):
// clients get their characters' tokens, each the next one, equal to those of a character generated alone
// (test/make_serve_reference.py); the frames the client decodes are the Python decode-only client's; a client
// that reconnects, after a pause or mid-stream, loses and repeats no token; one that joins a session afresh decodes
// from a SYNC; a request is kept until the server applied it, and one in flight at a reconnect is applied once; a
// wrong token and a foreign origin are refused.

import test, { after, before } from 'node:test';
import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import { join } from 'node:path';
import { fileURLToPath } from 'node:url';
import { setTimeout as sleep } from 'node:timers/promises';
import { ConnectionClosed, ServerClient, ServerError } from '../src/serve/client.js';
import { Event, Hello, PROMPT, Tick, Tokens } from '../src/wire/format.js';
import { maxAbsDiff, readReference, report } from './reference.mjs';

const ref = readReference('serve.json');
const ROOT = fileURLToPath(new URL('../../', import.meta.url));
const PY = process.env.PYTHON ?? join(ROOT, '.venv/bin/python');
const TOKEN = 'js-test-token-0123456789';
const ORIGIN = 'https://game.example';   // the server takes this origin only: every client here sends it
const options = { origin: ORIGIN };
let server = null;   // {proc, url}

/** `mogo serve` on a free port; resolves with its URL once its first stderr line names it. */
function startServer() {
  const args = [join(ROOT, 'js/test/until_eof.py'), PY, '-m', 'mogo_runtime.cli', 'serve', ref.bundle, '--variant',
    ref.variant, '--port', '0', '--status', '0', '--origin', ORIGIN];
  const proc = spawn(PY, args, { env: { ...process.env, MOGO_SERVE_TOKEN: TOKEN }, stdio: ['pipe', 'inherit', 'pipe'] });
  return new Promise((resolve, reject) => {
    let err = '';
    proc.stderr.on('data', (chunk) => {
      err += chunk;
      const m = err.match(/ on (ws:\/\/\S+)/);
      if (m) resolve({ proc, url: m[1] });
    });
    proc.on('exit', (code) => reject(new Error(`mogo serve exited with ${code} before listening: ${err}`)));
  });
}

before(async () => {
  if (typeof WebSocket !== 'function') {
    throw new Error('no global WebSocket: Node 22 has one; on Node 20 run with NODE_OPTIONS=--experimental-websocket '
      + '(js/test/run.sh does)');
  }
  server = await startServer();
});

after(async () => {
  if (!server || server.proc.exitCode !== null || server.proc.signalCode !== null) return;   // gone already
  const exited = new Promise((resolve) => server.proc.on('exit', resolve));
  server.proc.stdin.end();   // until_eof.py stops the server (SIGTERM) and exits
  assert.equal(await exited, 0, 'mogo serve did not stop cleanly');
});

/**
 * Records from `client` until each character in `got` (its token rows so far) has `n` tokens; each token must be
 * the one expected next. -> per character, the tokens that came in replays (after a HELLO, before a TICK).
 */
async function tokensOf(client, got, n, seconds = 60) {
  const replayed = new Map([...got.keys()].map((i) => [i, 0]));
  const deadline = Date.now() + seconds * 1000;
  let replay = false;
  while ([...got.values()].some((rows) => rows.length < n)) {
    let timer;
    const r = await Promise.race([client.next(), new Promise((_, reject) => {
      timer = setTimeout(() => reject(new Error(`no record for ${seconds} s`)), Math.max(100, deadline - Date.now()));
    })]).finally(() => clearTimeout(timer));
    if (r instanceof Hello) replay = true;
    if (r instanceof Tick) replay = false;
    if (!(r instanceof Tokens) || !got.has(r.character)) continue;
    const rows = got.get(r.character);
    assert.equal(r.seq, rows.length, `character ${r.character}: token ${r.seq} after ${rows.length}`);
    for (let t = 0; t < r.count; t++) rows.push(Array.from(r.codes.subarray(t * r.levels, (t + 1) * r.levels)));
    if (replay) replayed.set(r.character, replayed.get(r.character) + r.count);
  }
  return replayed;
}

test("clients get their characters' tokens, each the next one; reconnecting loses and repeats none", {
  timeout: 120_000 }, async () => {
  const c = await ServerClient.connect(server.url, TOKEN, options);
  assert.match(c.session, /^\S{20,}$/);
  const ids = [];
  for (const { prompt, seed } of ref.prompts) ids.push(await c.add(prompt, { seed }));
  assert.deepEqual(ids, [0, 1]);
  const got = new Map(ids.map((i) => [i, []]));
  await tokensOf(c, got, 20);
  const session = c.session;
  // gone for a second: the server ticks on, and sends what was missed when the client comes back
  await c.close();
  await sleep(1000);
  const welcome = await c.reconnect();
  assert.equal(c.session, session);
  assert.deepEqual(Object.keys(welcome.characters), ids.map(String));
  const paused = await tokensOf(c, got, 30);
  // again mid-stream, with records read but not yet taken: they stay queued, and what was on its way when it
  // closed is asked for again
  await sleep(500);
  await c.reconnect();
  const midStream = await tokensOf(c, got, 40);
  for (const [i, { prompt, seed, tokens }] of ref.prompts.entries()) {
    assert.deepEqual(got.get(ids[i]).slice(0, 40), tokens.slice(0, 40), `"${prompt}" seed ${seed}: tokens`);
    assert.ok(c.nextSeq.get(ids[i]) >= got.get(ids[i]).length);
  }
  assert.ok([...paused.values()].every((n) => n >= 3), `a 1 s pause replayed ${[...paused.values()]} tokens`);
  await c.remove(ids[0]);
  assert.equal(await c.add('a person turns left', { seed: 3 }), 2);
  // a request the server cannot carry out: a ServerError that is not fatal, in `errors` (a request has no reply of
  // its own, as in Python), and the connection stays: the next add gets its own answer
  await c.request(7, { prompt: 'a person jumps' });
  for (let i = 0; i < 200 && !c.errors.length; i++) await sleep(25);
  assert.deepEqual(c.errors.map((e) => [e.message, e.fatal]), [['no character 7 in this session', false]]);
  assert.equal(await c.add('a person jumps'), 3);
  await assert.rejects(c.add('   '), (e) => e instanceof ServerError && !e.fatal && /blank|empty/.test(e.message));
  await c.close();
  await assert.rejects(c.add('a person jumps'), ConnectionClosed);
  report(`serve: 2 characters, 40 tokens each equal to characters generated alone, every sequence number the next; `
    + `a 1 s disconnection replayed ${[...paused.values()].join(' and ')} tokens, a reconnection mid-stream `
    + `${[...midStream.values()].join(' and ')}, none lost or repeated`);
});

test("the frames the client decodes are the Python decode-only client's", { timeout: 120_000 }, async () => {
  const { prompt, seed } = ref.prompts[0];
  const c = await ServerClient.connect(server.url, TOKEN, { ...options, bundle: ref.bundle, variant: ref.variant });
  const ident = await c.add(prompt, { seed });
  const frameSize = c.decoder.skeleton.parents.length * 3, want = ref.joints.frames;
  const joints = [];
  let frames = 0;
  while (frames < want) {
    const [i, f] = await c.next();
    assert.equal(i, ident);
    assert.equal(f.index, frames, 'frames follow one another');
    joints.push(...f.joints);
    frames += f.joints.length / frameSize;
  }
  await c.close();
  await c.decoder.release();
  const worst = maxAbsDiff(joints.slice(0, want * frameSize), ref.joints.data);
  report(`serve: ${want} frames (${ref.joints.tokens} tokens) decoded from the server's stream by the JS client: `
    + `joints max |diff| ${worst.toExponential(1)} m from Python's decode-only client`);
  assert.ok(worst <= 1e-5, `joints differ from Python's by ${worst} m`);
});

test("a client that joins a session afresh decodes each character from its SYNC, as Python's client does", {
  timeout: 120_000 }, async () => {
  const { prompt, seed } = ref.prompts[0];
  const a = await ServerClient.connect(server.url, TOKEN, options);
  const ident = await a.add(prompt, { seed });
  await tokensOf(a, new Map([[ident, []]]), 3);
  await a.close();
  // a page reloaded: its decoder is new, it knows only the session
  const b = await ServerClient.connect(server.url, TOKEN, { ...options, bundle: ref.bundle, variant: ref.variant,
    session: a.session });
  assert.deepEqual(b.welcome.synced, [ident]);
  const frameSize = b.decoder.skeleton.parents.length * 3, want = ref.joints.frames;
  let first = null, next = null, compared = 0, worst = 0;
  while (compared < 8 * ref.joints.frames / ref.joints.tokens) {
    const [i, f] = await b.next();
    assert.equal(i, ident);
    const n = f.joints.length / frameSize;
    if (first === null) first = f.index;
    else assert.equal(f.index, next, 'frames follow one another from the SYNC on');
    next = f.index + n;
    assert.ok(next <= want, `the SYNC came at frame ${first}, past the ${want} frames of the reference`);
    const mine = f.joints, theirs = ref.joints.data.slice(f.index * frameSize, next * frameSize);
    worst = Math.max(worst, maxAbsDiff(mine, theirs));
    compared += n;
  }
  await b.close();
  await b.decoder.release();
  assert.ok(first > 0, 'it joined the character where it was, not from its start');
  report(`serve: a client joining a session afresh got its character as a SYNC at frame ${first}; ${compared} frames `
    + `decoded from there: joints max |diff| ${worst.toExponential(1)} m from Python's decode-only client's`);
  assert.ok(worst <= 1e-5, `joints differ from Python's by ${worst} m`);
});

test('requests are kept until the server applied them: one in flight at a reconnect is applied once', {
  timeout: 120_000 }, async () => {
  const c = await ServerClient.connect(server.url, TOKEN, options);
  const ident = await c.add(ref.prompts[0].prompt, { seed: ref.prompts[0].seed });
  const prompts = [];
  async function until(done) {
    for (let i = 0; i < 400 && !done(); i++) {
      const r = await c.next();
      if (r instanceof Event && r.event === PROMPT) prompts.push([r.seq, r.text]);
    }
    assert.ok(done(), 'the server did not apply the request');
  }
  await c.request(ident, { prompt: 'a person turns left' });
  assert.deepEqual([...c.unapplied.keys()], [1]);
  await until(() => prompts.length === 1 && !c.unapplied.size);   // "applied" 1 came with or before its PROMPT
  await c.request(ident, { prompt: 'a person jumps' });
  await c.close();                                                // before its "applied" could come
  assert.deepEqual([...c.unapplied.keys()], [2]);
  await assert.rejects(c.request(ident, { prompt: 'a person waves' }), ConnectionClosed);   // not connected: refused
  assert.deepEqual([...c.unapplied.keys()], [2]);
  // the server carries it out at its next tick: before this welcome (which then says 2, and the client does not send
  // it again) or after (the welcome says 1, the client sends it again, and the server skips the copy)
  const welcome = await c.reconnect();
  assert.ok([1, 2].includes(welcome.applied), `welcome: applied ${welcome.applied}`);
  assert.deepEqual([...c.unapplied.keys()], welcome.applied === 2 ? [] : [2]);
  await until(() => prompts.length >= 2 && !c.unapplied.size);
  await c.request(ident, { prompt: 'a person turns left' });
  assert.deepEqual([...c.unapplied.keys()], [3]);
  await until(() => prompts.length >= 3 && !c.unapplied.size);
  await c.close();
  assert.deepEqual(prompts.map(([, text]) => text), ['a person turns left', 'a person jumps', 'a person turns left']);
  assert.ok(prompts[1][0] > prompts[0][0] && prompts[2][0] > prompts[1][0]);
  report(`serve: a request in flight when the client closed was carried out once (welcome "applied" `
    + `${welcome.applied}${welcome.applied === 2 ? ', not sent again' : ', sent again and the copy skipped'}; PROMPT `
    + `events at tokens ${prompts.map(([seq]) => seq).join(', ')}), one made while closed refused`);
});

test("a wrong token and a foreign origin are refused with the server's reasons", { timeout: 60_000 }, async () => {
  await assert.rejects(ServerClient.connect(server.url, 'wrong-token-0123456789', { ...options, bundle: ref.bundle,
    variant: ref.variant }), (e) => {
    assert.ok(e instanceof ServerError, String(e));
    assert.equal(e.message, 'wrong token');
    assert.equal(e.fatal, true);
    return true;
  });
  // the handshake is refused (HTTP 403): a WebSocket only says it could not connect
  await assert.rejects(ServerClient.connect(server.url, TOKEN, { origin: 'https://evil.example' }),
    (e) => e instanceof ConnectionClosed && /could not connect/.test(e.message));
  await assert.rejects(ServerClient.connect(server.url, TOKEN), ConnectionClosed, 'no origin, not on the list');
});
