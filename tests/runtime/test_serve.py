"""The motion server (serve/): clients add characters and get their tokens, the tokens a crowd of their own would
give; hostile clients get one error and are dropped while the others carry on without a gap; a client that
reconnects, or a server stopped with SIGTERM and started again, loses and repeats no token."""
import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from toy_bundle import portable_toy_bundle  # noqa: F401,F811  (a fixture)


from websockets.asyncio.client import connect  # noqa: E402

from mogo_runtime import MotionGenerator  # noqa: E402
from mogo_runtime.crowd import Crowd  # noqa: E402
from mogo_runtime.serve.client import ServerClient  # noqa: E402
from mogo_runtime.serve.protocol import Limits  # noqa: E402
from mogo_runtime.serve.server import MotionServer  # noqa: E402
from mogo_runtime.serve import server as server_module, sessions as sessions_module  # noqa: E402
from mogo_runtime.serve.sessions import (Hosted, LocalStore, Session, SessionStore, catch_up,  # noqa: E402
                                         restore_session, session_state)
from mogo_runtime.wire.tap import CharacterTap  # noqa: E402
from mogo_runtime.wire import format as wire  # noqa: E402

TOKEN = "test-token-0123456789"
PROMPTS = [("a person walks forward", 1), ("a person waves with the right hand", 2), ("a person turns left", 3)]


@pytest.fixture(scope="module")
def gen(portable_toy_bundle):  # noqa: F811
    return MotionGenerator(portable_toy_bundle, variant="compact")


def reference_tokens(gen, prompt, seed, n, switch=None):
    """A character's first n tokens in a crowd of its own (switch: (token, prompt))."""
    crowd = Crowd(gen)
    c = crowd.add(prompt, seed=seed)
    out = []
    for _ in range(n):
        if switch and c.count == switch[0]:
            c.set_prompt(switch[1])
        crowd.tick()
        out.append(c.context.last.copy())
    return np.stack(out)


async def running(gen, limits=Limits(), speed=20.0, **kw):
    """A server on a free port, ticking `speed` times faster than real time -> (server, url, stop, task)."""
    server = MotionServer(gen, TOKEN, limits, speed=speed, **kw)
    stop, port = asyncio.Event(), asyncio.get_running_loop().create_future()
    task = asyncio.create_task(server.serve("127.0.0.1", 0, lambda s: port.set_result(s.sockets[0].getsockname()[1]),
                                            stop))
    return server, f"ws://127.0.0.1:{await port}", stop, task


async def tokens_of(client, counts: dict[int, int], got=None, switches=None, timeout=60.0) -> dict[int, list]:
    """Records from `client` until each character has counts[id] tokens, added to `got` (its tokens so far): each
    token must be the one expected next (none skipped, none repeated). `switches` collects PROMPT events."""
    got = got if got is not None else {i: [] for i in counts}
    deadline = time.monotonic() + timeout
    while any(len(got[i]) < n for i, n in counts.items()):
        r = await asyncio.wait_for(client.next(), max(0.1, deadline - time.monotonic()))
        if isinstance(r, wire.Tokens) and r.character in got:
            assert r.seq == len(got[r.character]), f"character {r.character}: token {r.seq} after {len(got[r.character])}"
            got[r.character].extend(r.codes)
        if switches is not None and isinstance(r, wire.Event) and r.event == wire.PROMPT:
            switches[r.character] = (r.seq, r.text)
    return got


def test_clients_get_the_tokens_of_their_characters(gen):
    async def main():
        server, url, stop, task = await running(gen)
        a = await ServerClient.connect(url, TOKEN)
        b = await ServerClient.connect(url, TOKEN)
        ia = await a.add(*PROMPTS[0][:1], seed=PROMPTS[0][1])
        ib = await b.add(PROMPTS[1][0], seed=PROMPTS[1][1])
        got_a, got_b = await asyncio.gather(tokens_of(a, {ia: 12}), tokens_of(b, {ib: 12}))
        await b.request(ia + 5, prompt="a person jumps")           # b cannot touch a's character
        for _ in range(200):
            if b.errors:
                break
            await asyncio.sleep(0.05)
        assert [(str(e), e.fatal) for e in b.errors] == [(f"no character {ia + 5} in this session", False)]
        await a.close(), await b.close()
        stop.set()
        await task
        return got_a[ia], got_b[ib]
    ta, tb = asyncio.run(main())
    np.testing.assert_array_equal(np.stack(ta[:12]), reference_tokens(gen, *PROMPTS[0], 12))
    np.testing.assert_array_equal(np.stack(tb[:12]), reference_tokens(gen, *PROMPTS[1], 12))


def test_frames_decoded_by_the_client_are_the_crowd_s(gen, portable_toy_bundle):  # noqa: F811
    async def main():
        server, url, stop, task = await running(gen)
        c = await ServerClient.connect(url, TOKEN, bundle=portable_toy_bundle, variant="compact")
        ident = await c.add("a person walks forward", seed=1)
        joints = []
        while sum(len(j) for j in joints) < 40:
            i, frames = await asyncio.wait_for(c.next(), 30)
            joints.append(frames.joints)
        await c.close()
        stop.set()
        await task
        return ident, np.concatenate(joints)
    ident, joints = asyncio.run(main())
    crowd = Crowd(gen, chunk=1)
    ch = crowd.add("a person walks forward", seed=1)
    want = np.concatenate([crowd.tick()[ch].joints for _ in range(10)])
    np.testing.assert_array_equal(joints[:40], want[:40])


def test_a_reconnecting_client_misses_and_repeats_nothing(gen):
    async def main():
        server, url, stop, task = await running(gen)
        c = await ServerClient.connect(url, TOKEN)
        ident = await c.add("a person walks forward", seed=1)
        got = await tokens_of(c, {ident: 5})
        await c.close()                      # gone for a while: the server keeps ticking
        await asyncio.sleep(0.5)
        await c.reconnect()
        await tokens_of(c, {ident: 30}, got)
        await c.close()
        stop.set()
        await task
        return got[ident]
    tokens = asyncio.run(main())
    np.testing.assert_array_equal(np.stack(tokens[:30]), reference_tokens(gen, "a person walks forward", 1, 30))


def test_a_client_that_lost_its_decoder_joins_where_the_character_is(gen, portable_toy_bundle):  # noqa: F811
    """A new client of a session (a page reloaded) names no character: it gets each as a START and a SYNC of where it
    is now; a client away longer than the replay keeps gets a SYNC. Either way its frames from there are the crowd's
    frames of the same numbers, bit for bit."""
    async def frames_of(client, ident, n):
        out = []
        while sum(len(j) for _, j in out) < n:
            i, frames = await asyncio.wait_for(client.next(), 30)
            if i == ident:
                out.append((frames.index, frames.joints))
        return out

    async def main():
        server, url, stop, task = await running(gen, Limits(replay_tokens=5))
        a = await ServerClient.connect(url, TOKEN, bundle=portable_toy_bundle, variant="compact")
        ident = await a.add("a person walks forward", seed=1)
        first = await frames_of(a, ident, 12)
        await a.close()
        await asyncio.sleep(0.5)             # ~50 ticks: more than the 5 kept
        welcome = await a.reconnect()
        assert welcome["synced"] == [ident] and welcome["characters"][str(ident)] > 12
        away = await frames_of(a, ident, 12)
        assert a.next_seq[ident] > welcome["characters"][str(ident)]
        await a.close()
        b = await ServerClient.connect(url, TOKEN, bundle=portable_toy_bundle, variant="compact", session=a.session)
        assert b.welcome["synced"] == [ident]
        fresh = await frames_of(b, ident, 12)
        await b.close()
        stop.set()
        await task
        return first, away, fresh
    first, away, fresh = asyncio.run(main())
    crowd = Crowd(gen, chunk=1)
    ch = crowd.add("a person walks forward", seed=1)
    last = max(index + len(joints) for index, joints in first + away + fresh)    # a's frames may outlast b's
    want = np.concatenate([crowd.tick()[ch].joints for _ in range(-(-last // gen.dims.downsample))])
    # each joined where the character was (b may repeat a's last frames: the tokens a SYNC leaves pending, or all of
    # them when no tick came between the two)
    assert away[0][0] >= first[-1][0] + 4 * gen.dims.downsample and fresh[0][0] >= away[0][0]
    for index, joints in first + away + fresh:
        np.testing.assert_array_equal(joints, want[index:index + len(joints)])


def test_sessions_change_only_on_the_tick_thread(gen):
    """The tick thread iterates the sessions while the event loop welcomes clients: a session registered on the
    loop made the load test's server fail with "dictionary changed size during iteration"."""
    import threading

    changed_on = []

    class Watched(dict):
        def __setitem__(self, k, v):
            changed_on.append(threading.current_thread().name)
            super().__setitem__(k, v)

        def __delitem__(self, k):
            changed_on.append(threading.current_thread().name)
            super().__delitem__(k)

    async def main():
        server, url, stop, task = await running(gen, Limits(linger_seconds=0.2))
        server.sessions = Watched()
        a = await ServerClient.connect(url, TOKEN)
        await a.add("a person walks forward", seed=1)
        await a.close()
        await asyncio.sleep(1.0)          # its session expires
        b = await ServerClient.connect(url, TOKEN)
        await b.close()
        stop.set()
        await task
    asyncio.run(main())
    assert len(changed_on) >= 3, changed_on          # two sessions registered, one expired
    assert all(name.startswith("mogo-tick") for name in changed_on), changed_on


def test_the_server_stops_reading_a_message_it_refused(gen):
    """A client that announces a 64 MB frame and keeps writing: the server answers 1009 and reads no further, so
    the client's writes stall once the kernel's buffers are full (websockets alone would read all 64 MB, and
    discard it, on the server's loop)."""
    async def main():
        server, url, stop, task = await running(gen, Limits(max_message_bytes=4096))
        port = int(url.rsplit(":", 1)[1])
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n")
        assert b" 101 " in await reader.readuntil(b"\r\n\r\n")
        claimed = 64 << 20
        writer.write(bytes([0x81, 0xFF]) + claimed.to_bytes(8, "big") + b"\0\0\0\0")   # masked with 0000
        chunk, sent = bytes(1 << 20), 0
        try:
            while sent < claimed:
                writer.write(chunk)
                await asyncio.wait_for(writer.drain(), 1.0)
                sent += len(chunk)
        except (asyncio.TimeoutError, ConnectionError):
            pass
        close = await asyncio.wait_for(reader.readexactly(4), 5)
        writer.transport.abort()
        stop.set()
        await task
        return sent, claimed, close
    sent, claimed, close = asyncio.run(main())
    assert close[0] == 0x88 and int.from_bytes(close[2:4], "big") == 1009, close
    assert sent < claimed // 2, f"the client wrote {sent >> 20} MB of its {claimed >> 20} MB message"


@pytest.mark.parametrize("send, message", [
    ("not json", "JSON object"),
    (json.dumps({"op": "dance"}), "op of"),
    (json.dumps({"op": "add", "prompt": 5}), "prompt must be a str"),
    (json.dumps({"op": "add", "prompt": "x", "extra": 1}), "unknown field"),
    (json.dumps({"op": "remove", "id": -1}), "id must be"),
    (json.dumps({"op": "request", "id": 0, "prompt": "x", "n": 0}), "n must be a request number"),
    (json.dumps({"op": "joints", "id": 0, "on": True, "n": 2 ** 53}), "n must be a request number"),
    (json.dumps({"op": "remove", "id": 0, "n": 1}), "unknown field"),
    (b"\x00\x01binary", "not binary"),
    ("x" * 5000, "too big|1009"),
    ("flood", "messages a second"),
    (json.dumps({"op": "hello", "token": TOKEN}), "hello once"),
])
def test_a_hostile_client_is_dropped_and_the_others_carry_on(gen, send, message):
    async def main():
        limits = Limits(max_message_bytes=4096, messages_per_second=10)
        server, url, stop, task = await running(gen, limits)
        good = await ServerClient.connect(url, TOKEN)
        ident = await good.add("a person walks forward", seed=1)
        async with connect(url, compression=None) as bad:
            await bad.send(json.dumps({"op": "hello", "token": TOKEN}))
            assert json.loads(await bad.recv())["op"] == "welcome"
            if send == "flood":
                for _ in range(100):
                    await bad.send(json.dumps({"op": "joints", "id": 0, "on": True}))
            else:
                await bad.send(send)
            reason = ""
            try:
                while True:
                    m = await asyncio.wait_for(bad.recv(), 10)
                    if isinstance(m, str) and json.loads(m)["op"] == "error":
                        reason = json.loads(m)["message"]
            except Exception as e:     # closed by the server
                reason = reason or f"{e}"
        tokens = await tokens_of(good, {ident: 20})
        await good.close()
        stop.set()
        await task
        return reason, tokens[ident]
    reason, tokens = asyncio.run(main())
    assert __import__("re").search(message, reason), reason
    np.testing.assert_array_equal(np.stack(tokens[:20]), reference_tokens(gen, "a person walks forward", 1, 20))


def test_wrong_token_late_hello_and_foreign_origin_are_refused(gen):
    async def main():
        server, url, stop, task = await running(gen, Limits(hello_seconds=0.5), origins=[None, "https://game.example"])
        out = []
        async with connect(url) as ws:
            await ws.send(json.dumps({"op": "hello", "token": "wrong-token-0123456789"}))
            out.append(json.loads(await ws.recv())["message"])
        async with connect(url) as ws:
            out.append(json.loads(await asyncio.wait_for(ws.recv(), 5))["message"])
        try:
            async with connect(url, origin="https://evil.example"):
                out.append("connected")
        except Exception as e:
            out.append(str(e))
        stop.set()
        await task
        return out
    wrong, late, origin = asyncio.run(main())
    assert "wrong token" in wrong and "no hello" in late and "403" in origin


def test_a_vanished_client_frees_its_characters(gen):
    async def main():
        server, url, stop, task = await running(gen, Limits(linger_seconds=0.3))
        c = await ServerClient.connect(url, TOKEN)
        await c.add("a person walks forward", seed=1)
        await c.add("a person waves with the right hand", seed=2)
        assert len(server.crowd) == 2
        c._ws.transport.abort()            # gone without a close
        for _ in range(100):
            await asyncio.sleep(0.05)
            if not server.crowd.characters and not server.sessions:
                break
        stop.set()
        await task
        return len(server.crowd), len(server.sessions)
    assert asyncio.run(main()) == (0, 0)


def test_sigterm_saves_and_a_restarted_server_resumes_every_character(gen, portable_toy_bundle, tmp_path):  # noqa: F811
    state, env = tmp_path / "serve.state", dict(os.environ, MOGO_SERVE_TOKEN=TOKEN)

    def start():
        proc = subprocess.Popen([sys.executable, "-m", "mogo_runtime.cli", "serve", str(portable_toy_bundle),
                                 "--port", "0", "--state", str(state)], env=env, stderr=subprocess.PIPE, text=True)
        line = proc.stderr.readline()
        assert "ws://" in line, line + proc.stderr.read()
        return proc, line.split()[-1]

    async def main():
        proc, url = start()
        c = await ServerClient.connect(url, TOKEN)
        ids = [await c.add(p, seed=s) for p, s in PROMPTS]
        switches = {}
        got = await tokens_of(c, {i: 3 for i in ids})
        await c.request(ids[2], prompt="a person jumps in place")     # lands at a token the PROMPT event names
        await tokens_of(c, {i: 6 for i in ids}, got, switches)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0, proc.stderr.read()
        assert state.exists()
        proc, c.url = start()              # on another port: the client follows it
        try:
            await c.reconnect()
            await tokens_of(c, {i: 25 for i in ids}, got, switches)
        finally:
            await c.close()
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)
        return ids, got, switches
    ids, got, switches = asyncio.run(main())
    assert list(switches) == [ids[2]]
    for i, (prompt, seed) in zip(ids, PROMPTS):
        want = reference_tokens(gen, prompt, seed, 25, switches.get(i))
        np.testing.assert_array_equal(np.stack(got[i][:25]), want)


@pytest.mark.parametrize("argv, env, needle", [
    ([], {}, "a bearer token of at least 16 characters is required"),
    ([], {"MOGO_SERVE_TOKEN": "short"}, "a bearer token of at least 16 characters"),
    (["--token-file", "/nonexistent/token"], {}, "--token-file /nonexistent/token: No such file"),
    (["--token-file", "BIG"], {}, "over 4096 bytes"),
    (["--port", "70000"], {"MOGO_SERVE_TOKEN": TOKEN}, "--port must be a port in [0, 65535]"),
    (["--characters", "0"], {"MOGO_SERVE_TOKEN": TOKEN}, "--characters must be an int >= 1"),
    (["--variant", "int8"], {"MOGO_SERVE_TOKEN": TOKEN}, "a crowd steps its characters together"),
])
def test_mogo_serve_refuses_what_would_not_work_in_one_line(portable_toy_bundle, tmp_path, monkeypatch, capsys,  # noqa: F811
                                                            argv, env, needle):
    from mogo_runtime.cli import main

    monkeypatch.delenv("MOGO_SERVE_TOKEN", raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    (tmp_path / "big").write_text("x" * 5000)
    argv = [str(tmp_path / "big") if a == "BIG" else a for a in argv]
    assert main(["serve", str(portable_toy_bundle), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mogo: error: ") and err.count("\n") == 1 and needle in err, err


def test_joints_on_request_are_the_crowd_s(gen):
    async def main():
        server, url, stop, task = await running(gen)
        c = await ServerClient.connect(url, TOKEN)
        ident = await c.add("a person walks forward", seed=1)
        await c.joints(ident, True)
        joints = []
        while sum(len(j.joints) for j in joints) < 40:
            r = await asyncio.wait_for(c.next(), 30)
            if isinstance(r, wire.Joints):
                assert not joints or r.frame == joints[-1].frame + len(joints[-1].joints)    # frames follow on
                joints.append(r)
        await c.close()
        stop.set()
        await task
        return joints
    got = asyncio.run(main())
    crowd = Crowd(gen)                      # the server's crowd decodes 4 tokens at a time, from token 0
    ch = crowd.add("a person walks forward", seed=1)
    want = [f for f in (crowd.tick().get(ch) for _ in range(40)) if f is not None]
    first = next(i for i, f in enumerate(want) if f.index == got[0].frame)
    for record, frames in zip(got, want[first:]):
        assert record.frame == frames.index
        np.testing.assert_array_equal(record.joints, frames.joints)


def test_the_tick_thread_hands_free_memory_back_every_trim_seconds(gen, monkeypatch):
    """glibc keeps what a passing peak freed (a restored server's characters rebuild together); the server trims
    its heap every TRIM_SECONDS, on the tick thread, between ticks."""
    import threading

    from mogo_runtime.serve.memory import malloc_trim

    assert malloc_trim() is not None          # this machine's libc is glibc: the trim is real
    calls = []
    trim = server_module.return_free_memory
    monkeypatch.setattr(server_module, "TRIM_SECONDS", 0.1)
    monkeypatch.setattr(server_module, "return_free_memory",
                        lambda: calls.append((threading.current_thread().name, server.ticks)) or trim())

    async def main():
        nonlocal server
        server, url, stop, task = await running(gen)
        await asyncio.sleep(0.55)
        stop.set()
        await task
    server = None
    asyncio.run(main())
    assert 3 <= len(calls) <= 7, calls
    assert all(name.startswith("mogo-tick") for name, _ in calls), calls
    assert [t for _, t in calls] == sorted(t for _, t in calls) and calls[-1][1] > calls[0][1], calls


def test_a_session_is_taken_over_by_another_server_with_the_same_tokens(gen, monkeypatch):
    """Two servers sharing a session store (as Ray replicas do): a client whose server stops without saving
    reconnects to the other, which takes its session over from the last checkpoint, runs its characters on to the
    tokens the client has, and goes on with the tokens they would have had (a prompt switch included), none lost or
    repeated; a server whose session was taken over while it still runs lets its copy go."""
    store = LocalStore(SessionStore(forget_seconds=30.0))
    # only the checkpoints a change makes, at first: the client is then surely ahead of the last one
    monkeypatch.setattr(sessions_module, "CHECKPOINT_TICKS", 10 ** 9)
    caught_up = []
    monkeypatch.setattr(server_module, "catch_up",
                        lambda gen, states: caught_up.extend(n for _, n in states.values()) or catch_up(gen, states))

    async def main():
        a, url_a, stop_a, task_a = await running(gen, store=store)
        b, url_b, stop_b, task_b = await running(gen, store=store)
        c = await ServerClient.connect(url_a, TOKEN)
        walker = await c.add("a person walks forward", seed=1)
        waver = await c.add(PROMPTS[1][0], seed=PROMPTS[1][1])
        switches = {}
        got = await tokens_of(c, {walker: 6, waver: 6})
        await c.request(walker, prompt="a person turns left")
        await tokens_of(c, {walker: 9, waver: 9}, got, switches)
        stop_a.set()                     # a stops (no state file): only the store has its session
        await task_a
        with pytest.raises(ConnectionError):
            while True:                  # what a sent before it closed, then the close
                await tokens_of(c, {walker: len(got[walker]) + 1}, got, switches, timeout=10)
        await c.close()
        c.url = url_b
        had = dict(c.next_seq)
        welcome = await c.reconnect()
        assert welcome["server"] == b.id and welcome["characters"] == {str(i): n for i, n in had.items()}
        assert welcome["synced"] == [walker, waver] and caught_up == [had[walker], had[waver]]
        await tokens_of(c, {walker: 30, waver: 30}, got, switches)
        monkeypatch.setattr(sessions_module, "CHECKPOINT_TICKS", 5)
        # and back to a, started again on the same store: b still runs, and lets the session go once a has it
        a2, url_a2, stop_a2, task_a2 = await running(gen, store=store)
        await c.close()
        c.url = url_a2
        await c.reconnect()
        await tokens_of(c, {walker: 40, waver: 40}, got, switches)
        for _ in range(100):
            if not len(b.crowd):
                break
            await asyncio.sleep(0.05)
        left_b = len(b.crowd)
        await c.close()
        for stop, task in [(stop_b, task_b), (stop_a2, task_a2)]:
            stop.set()
            await task
        return got, switches, left_b

    got, switches, left_b = asyncio.run(main())
    switch = switches[0]
    assert switch[1] == "a person turns left" and left_b == 0
    np.testing.assert_array_equal(np.stack(got[0][:40]), reference_tokens(gen, "a person walks forward", 1, 40,
                                                                        switch=switch))
    np.testing.assert_array_equal(np.stack(got[1][:40]), reference_tokens(gen, *PROMPTS[1], 40))


def test_the_handover_benchmark_reports_its_costs(portable_toy_bundle, capsys):  # noqa: F811
    """benchmarks/handover.py on the toy: what a SYNC, a checkpoint and a takeover cost (numbers, not timings)."""
    from benchmarks import handover

    assert handover.main(["--bundle", str(portable_toy_bundle), "--characters", "3", "--ticks", "30"]) == 0
    out = capsys.readouterr().out
    found = re.search(r"SYNC record: ([\d.]+) KB\n  checkpoint: ([\d.]+) KB and ([\d.]+) ms a character .*\n"
                      r"  takeover, 25 tokens behind: (\d+) ms", out)
    assert found and float(found[1]) > 0 and float(found[2]) > 0, out


def test_a_checkpoint_keeps_the_last_records_a_lagging_client_needs(gen):
    """A checkpoint holds each character's last CHECKPOINT_RECORDS records: a client a message or two behind it
    when its server went gets them replayed (not a SYNC), from the session restored elsewhere."""
    crowd = Crowd(gen)
    session = Session("s")
    c = crowd.add("a person walks forward", seed=1)
    session.characters[0] = Hosted(c, CharacterTap(c, 0))
    for _ in range(20):
        crowd.tick()
        h = session.characters[0]
        key, records = h.tap.sent, h.tap.read()
        h.replay.append((key, b"".join(map(wire.encode, records))))
    state = session_state(session, sessions_module.CHECKPOINT_RECORDS)
    assert [k for k, _ in state["characters"][0]["replay"]] == list(range(20 - sessions_module.CHECKPOINT_RECORDS, 20))
    assert len(session_state(session)["characters"][0]["replay"]) == 20
    assert session_state(session, 0)["characters"][0]["replay"] == []
    restored = restore_session(Crowd(gen), json.loads(json.dumps(state)))
    assert [k for k, _ in restored.characters[0].replay] == list(range(20 - sessions_module.CHECKPOINT_RECORDS, 20))
    assert restored.characters[0].tap.sent == 20 and not restored.characters[0].sync


def test_a_request_its_server_got_as_it_died_is_sent_again_to_the_next(gen):
    """A request the client sent reaches a server that dies before carrying it out: the client keeps it (numbered)
    until the server says it applied it, so on reconnecting to the server that takes the session over it sends it
    again, and the character switches there, once, with the tokens a character switched at that token has."""
    store = LocalStore(SessionStore(forget_seconds=30.0))

    async def main():
        a, url_a, stop_a, task_a = await running(gen, store=store)
        b, url_b, stop_b, task_b = await running(gen, store=store)
        c = await ServerClient.connect(url_a, TOKEN)
        walker = await c.add("a person walks forward", seed=1)
        switches: dict = {}
        got = await tokens_of(c, {walker: 4})
        await c.request(walker, prompt="a person turns left")    # applied at a's next tick, answered "applied"
        await tokens_of(c, {walker: 8}, got, switches)
        for _ in range(100):
            if not c.unapplied:
                break
            await asyncio.sleep(0.02)
        assert not c.unapplied and switches == {walker: (switches[walker][0], "a person turns left")}
        first = switches.pop(walker)
        lost = asyncio.Event()
        a._dispatch = lambda session, msg: lost.set()          # a gets the next request and dies before its tick
        await c.request(walker, prompt="a person jumps")
        await lost.wait()
        assert list(c.unapplied) == [2]
        stop_a.set()
        await task_a
        with pytest.raises(ConnectionError):
            while True:
                await tokens_of(c, {walker: len(got[walker]) + 1}, got, switches, timeout=10)
        await c.close()
        with pytest.raises(ConnectionError, match="not connected"):     # a request while down: refused, not kept
            await c.request(walker, prompt="a person waves with the right hand")
        assert list(c.unapplied) == [2]
        c.url = url_b
        welcome = await c.reconnect()
        assert welcome["server"] == b.id and welcome["applied"] == 1
        await tokens_of(c, {walker: len(got[walker]) + 12}, got, switches)
        assert not c.unapplied
        await c.close()
        stop_b.set()
        await task_b
        return got[walker], first, switches

    got, first, switches = asyncio.run(main())
    (seq, text), = switches.values()
    assert text == "a person jumps" and seq > first[0]
    crowd = Crowd(gen)
    c = crowd.add("a person walks forward", seed=1)
    want = []
    for _ in range(len(got)):
        for at, prompt in (first, (seq, text)):
            if c.count == at:
                c.set_prompt(prompt)
        crowd.tick()
        want.append(c.context.last.copy())
    np.testing.assert_array_equal(np.stack(got), np.stack(want))


def test_what_a_client_sees_of_its_requests_is_in_the_store_first(gen):
    """A tick that carried out a client's requests goes out only once the store holds the session after it: a
    client told "applied" (or shown the switched tokens) never depends on a write its server may not live to make.
    The store here answers slowly; whenever the client hears "applied n", the store already says n."""
    inner = SessionStore(forget_seconds=30.0)

    class SlowStore(LocalStore):
        async def put(self, owner, states, dropped):
            await asyncio.sleep(0.05)
            return await super().put(owner, states, dropped)

    async def main():
        server, url, stop, task = await running(gen, store=SlowStore(inner))
        seen, binary = [], []
        async with connect(url) as ws:
            await ws.send(json.dumps({"op": "hello", "token": TOKEN}))
            sid = json.loads(await ws.recv())["session"]
            await ws.send(json.dumps({"op": "add", "prompt": "a person walks forward", "seed": 1}))
            for n in range(1, 4):
                await ws.send(json.dumps({"op": "request", "id": 0, "prompt": PROMPTS[n % 3][0], "n": n}))
                await ws.send(json.dumps({"op": "request", "id": 0, "prompt": "a person jumps", "n": n}))  # a copy
                while True:
                    reply = await asyncio.wait_for(ws.recv(), 30)
                    if isinstance(reply, bytes):
                        binary.append(reply)
                    elif json.loads(reply)["op"] == "applied":
                        seen.append((json.loads(reply)["n"], json.loads(inner.sessions[sid][2])["applied"]))
                        break
            for _ in range(3):          # the last switch's tick
                binary.append(await asyncio.wait_for(ws.recv(), 30))
        stop.set()
        await task
        levels, prompts = None, []
        for message in binary:
            for r in wire.read_message(message, levels):
                if isinstance(r, wire.Hello):
                    levels = r.levels
                elif isinstance(r, wire.Event) and r.event == wire.PROMPT:
                    prompts.append(r.text)
        return seen, prompts

    seen, prompts = asyncio.run(main())
    assert seen == [(1, 1), (2, 2), (3, 3)]
    assert prompts == [PROMPTS[1][0], PROMPTS[2][0], PROMPTS[0][0]]     # the copies skipped
