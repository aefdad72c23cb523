"""Load test of `mogo serve` on loopback: many clients of a few characters each, prompts switching every 4-10 s,
hostile clients for a while, and a SIGTERM and restart mid-run.

    python -m benchmarks.serve_load --bundle .cache/tiny-*/bundle --clients 200 --characters 4 --minutes 10
    python -m benchmarks.serve_load --bundle ... --clients 100 --minutes 2 --simple [--ray 2]   # clients only: real
                                        time and latency, of the plain server or of Ray Serve with 2 replicas (a head
                                        and a worker node started here, one CPU each)

Every client checks every character's sequence numbers (no token lost, repeated or out of order, across the
restart too) and times each tick message from the server's TICK stamp to its arrival (one machine: one monotonic
clock). The server's status lines give its tick times and memory per minute. After the run, a sample of characters
is generated again alone (a Crowd here, the same prompt switches at the same tokens) and must match token for token.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mogo_runtime.wire import format as wire

PROMPTS = ["a person walks forward", "a person waves with the right hand", "a person jumps in place",
           "a person turns left", "a person runs forward", "a person sits down", "a person kicks with the left leg",
           "a person walks backward", "a person raises both arms", "a person turns around"]
TOKEN = "load-test-token-0123456789"


class Stats:
    def __init__(self):
        self.latency: list[tuple[float, float]] = []     # (arrival time, latency s)
        self.errors: list[str] = []
        self.tokens = 0
        self.bytes = 0
        self.characters: dict[tuple[int, int], dict] = {}  # (client, id) -> {"seed", "prompt", "switches", "tokens"}


async def client(n: int, url: str, characters: int, stop: asyncio.Event, stats: Stats, rng: random.Random):
    from websockets.asyncio.client import connect

    session, expected, own = None, {}, {}
    levels = None
    next_switch = time.monotonic() + rng.uniform(4, 10)
    while not stop.is_set():
        try:
            async with connect(url, compression=None, max_size=16 << 20, open_timeout=30) as ws:
                hello = {"op": "hello", "token": TOKEN}
                if session:
                    hello.update(session=session, resume={str(k): v for k, v in expected.items()})
                await ws.send(json.dumps(hello))
                welcome = json.loads(await ws.recv())
                if welcome.get("op") != "welcome":
                    stats.errors.append(f"client {n}: {welcome}")
                    return
                session = welcome["session"]
                while len(own) < characters:
                    prompt, seed = rng.choice(PROMPTS), rng.randrange(2 ** 31)
                    await ws.send(json.dumps({"op": "add", "prompt": prompt, "seed": seed}))
                    while True:
                        m = await ws.recv()
                        if isinstance(m, str):
                            reply = json.loads(m)
                            if reply["op"] != "added":
                                stats.errors.append(f"client {n}: {reply}")
                                return
                            own[reply["id"]] = stats.characters[(n, reply["id"])] = {
                                "seed": seed, "prompt": prompt, "switches": [], "tokens": []}
                            expected.setdefault(reply["id"], 0)
                            break
                        levels = _read(m, n, levels, expected, own, stats)
                while not stop.is_set():
                    try:
                        m = await asyncio.wait_for(ws.recv(), 1.0)
                    except asyncio.TimeoutError:
                        continue
                    if isinstance(m, str):
                        reply = json.loads(m)
                        if reply.get("op") == "error":
                            stats.errors.append(f"client {n}: {reply}")
                        continue
                    levels = _read(m, n, levels, expected, own, stats)
                    if time.monotonic() > next_switch:
                        next_switch = time.monotonic() + rng.uniform(4, 10)
                        ident = rng.choice(list(own))
                        await ws.send(json.dumps({"op": "request", "id": ident, "prompt": rng.choice(PROMPTS)}))
        except (OSError, asyncio.TimeoutError):
            if stop.is_set():
                return
            await asyncio.sleep(0.2)           # the server restarting: connect again
        except Exception as e:                 # the connection closed (a restart): connect again with the session
            if type(e).__name__ not in ("ConnectionClosedError", "ConnectionClosedOK", "InvalidStatus",
                                        "InvalidMessage"):
                stats.errors.append(f"client {n}: {type(e).__name__}: {e}")
                return
            await asyncio.sleep(0.2)


def _read(message: bytes, n: int, levels, expected: dict, own: dict, stats: Stats):
    now = time.monotonic()
    stats.bytes += len(message)
    for r in wire.read_message(message, levels):
        if isinstance(r, wire.Hello):
            levels = r.levels
        elif isinstance(r, wire.Tick):
            stats.latency.append((now, now - r.time))
        elif isinstance(r, wire.Tokens):
            if r.seq != expected.get(r.character):
                stats.errors.append(f"client {n} character {r.character}: token {r.seq}, expected "
                                    f"{expected.get(r.character)}")
            expected[r.character] = r.seq + len(r.codes)
            own[r.character]["tokens"].extend(r.codes.tolist())
            stats.tokens += len(r.codes)
        elif isinstance(r, wire.Event) and r.event == wire.PROMPT and r.character in own:
            own[r.character]["switches"].append((r.seq, r.text))
    return levels


ATTACKS = ("garbage", "huge", "flood", "wrong", "half-open")


async def hostile(url: str, port: int, stop: asyncio.Event, log: list[str], attacks=ATTACKS):
    """Garbage, huge messages, floods, wrong tokens and half-open connections (those of `attacks`), one after
    another, until `stop`."""
    from websockets.asyncio.client import connect

    async def attempt(name, fn):
        try:
            async with connect(url, compression=None, max_size=None, open_timeout=10) as ws:
                await fn(ws)
                while True:
                    await asyncio.wait_for(ws.recv(), 10)
        except asyncio.TimeoutError:
            log.append(f"{name}: NOT disconnected within 10 s")
        except Exception as e:
            log.append(f"{name}: {type(e).__name__}: {str(e)[:70]}")

    async def hello(ws):
        await ws.send(json.dumps({"op": "hello", "token": TOKEN}))
        await ws.recv()

    async def garbage(ws):
        await ws.send(os.urandom(1000))

    async def huge(ws):
        await hello(ws)
        await ws.send("x" * (16 << 20))

    async def flood(ws):
        await hello(ws)
        for _ in range(10_000):
            await ws.send(json.dumps({"op": "joints", "id": 0, "on": True}))

    async def wrong(ws):
        await ws.send(json.dumps({"op": "hello", "token": "wrong-token-xxxxxxxxxxxxxx"}))

    half_open = []
    while not stop.is_set():
        for key, name, fn in (("garbage", "garbage", garbage), ("huge", "16 MB", huge),
                              ("flood", "10,000 messages", flood), ("wrong", "wrong token", wrong)):
            if key in attacks:
                await attempt(name, fn)
        if "half-open" in attacks:
            try:
                half_open.append(socket.create_connection(("127.0.0.1", port)))     # a connection that never speaks
            except OSError as e:
                log.append(f"half-open: {type(e).__name__}: {str(e)[:70]}")
        await asyncio.sleep(0.5)
    for s in half_open:
        s.close()


async def attack(url: str, seconds: float, attacks=ATTACKS) -> list[str]:
    stop, log = asyncio.Event(), []
    task = asyncio.create_task(hostile(url, int(url.rsplit(":", 1)[1]), stop, log, attacks))
    await asyncio.sleep(seconds)
    stop.set()
    await task
    return sorted(set(log))


def _attacks(text: str) -> list[str]:
    names = [a for a in text.split(",") if a]
    unknown = sorted(set(names) - set(ATTACKS))
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"attacks are some of {','.join(ATTACKS)}, got {text!r}")
    return names


def percentile(values, q):
    return float(np.percentile(values, q)) if len(values) else float("nan")


async def main_async(args) -> dict:
    port = _free_port()
    url = f"ws://127.0.0.1:{port}"
    state = Path(tempfile.mkdtemp()) / "serve.state"
    env = dict(os.environ, MOGO_SERVE_TOKEN=TOKEN)
    status: list[tuple[float, str]] = []

    def start():
        proc = subprocess.Popen([sys.executable, "-m", "mogo_runtime.cli", "serve", str(args.bundle), "--port",
                                 str(port), "--variant", args.variant, "--state", str(state), "--status", "60",
                                 "--characters-per-connection", str(args.characters),
                                 "--characters", str(args.clients * args.characters + 10)],
                                env=env, stderr=subprocess.PIPE, text=True)
        line = proc.stderr.readline()
        if "ws://" not in line:
            raise SystemExit(f"the server did not start: {line}{proc.stderr.read()}")

        def read_status():
            for line in proc.stderr:
                status.append((time.monotonic(), line.strip()))
        import threading
        threading.Thread(target=read_status, daemon=True).start()
        return proc

    if args.simple:
        return await simple(args, port, url, env)
    proc = start()
    stats, stop = Stats(), asyncio.Event()
    rng = random.Random(args.seed)
    began = time.monotonic()
    tasks = [asyncio.create_task(client(n, url, args.characters, stop, stats, random.Random(rng.random())))
             for n in range(args.clients)]
    total = 60 * args.minutes
    windows = {}
    await asyncio.sleep(0.4 * total)
    windows["quiet"] = (time.monotonic() - 0.2 * total, time.monotonic())
    # the attackers run in a process of their own: on this one they would slow the clients that measure
    # (--hostile-nice: at a lower priority, so that on a machine whose cores the server and clients already fill the
    # attackers' own CPU does not stand in for what their messages cost the server; attackers are remote in play)
    h = await asyncio.create_subprocess_exec(sys.executable, "-m", "benchmarks.serve_load", "--hostile", url,
                                             "--bundle", "-", "--minutes", str(0.2 * args.minutes),
                                             "--attacks", ",".join(args.attacks),
                                             stdout=subprocess.PIPE,
                                             preexec_fn=(lambda: os.nice(args.hostile_nice)) if args.hostile_nice
                                             else None)
    out, _ = await h.communicate()
    if h.returncode or proc.poll() is not None:
        last = "\n".join(line for _, line in status[-20:])
        raise SystemExit(f"the attackers' process exited {h.returncode}, the server "
                         f"{'exited ' + str(proc.poll()) if proc.poll() is not None else 'runs'}; its last lines:\n{last}")
    hostile_log = json.loads(out)
    windows["hostile"] = (time.monotonic() - 0.2 * total, time.monotonic())
    proc.send_signal(signal.SIGTERM)
    stopped = proc.wait(60)
    restart_at = time.monotonic()
    proc = start()
    await asyncio.sleep(max(0.0, total - (time.monotonic() - began)))
    stop.set()
    await asyncio.gather(*tasks)
    proc.send_signal(signal.SIGTERM)
    proc.wait(60)

    lat = [(t, x) for t, x in stats.latency]
    window = {k: [x for t, x in lat if a <= t <= b] for k, (a, b) in windows.items()}
    after = [x for t, x in lat if t > restart_at + 5]
    status_lines = [line for _, line in status if "tick p50" in line]
    ticks = [float(re.search(r"tick p50 ([\d.]+) ms", s).group(1)) for s in status_lines]
    rss = [float(re.search(r"rss (\d+) MB", s).group(1)) for s in status_lines]
    seconds = time.monotonic() - began
    return {
        "clients": args.clients, "characters": args.clients * args.characters, "minutes": args.minutes,
        "hostile_nice": args.hostile_nice, "attacks": args.attacks,
        "bundle": str(args.bundle), "variant": args.variant, "errors": stats.errors[:20], "error_count": len(stats.errors),
        "tokens": stats.tokens, "bytes_per_character_second": stats.bytes / seconds / (args.clients * args.characters),
        "latency_ms": {k: {"p50": 1e3 * percentile(v, 50), "p99": 1e3 * percentile(v, 99), "n": len(v)}
                       for k, v in {**window, "after restart": after, "all": [x for _, x in lat]}.items()},
        "server_status": status_lines, "tick_p50_last_over_first": ticks[-2] / ticks[0] if len(ticks) > 2 else None,
        "rss_last_over_first": rss[-2] / rss[0] if len(rss) > 2 else None,
        "sigterm_exit": stopped, "hostile": hostile_log,
        "resumed_exactly": check_sample(args, stats),
    }


async def simple(args, port: int, url: str, env: dict) -> dict:
    """Clients only, for `minutes`: how close to real time their characters' tokens come, and how late."""
    from mogo_runtime import MotionGenerator

    ray = str(Path(sys.executable).parent / "ray")
    if args.ray:
        head = _free_port()
        cluster = dict(os.environ, RAY_SERVE_PROXY_PREFER_LOCAL_NODE_ROUTING="0")   # docs/serve.md, "Ray Serve"
        subprocess.run([ray, "start", "--head", f"--port={head}", "--num-cpus=1", "--include-dashboard=false",
                        "--disable-usage-stats"], check=True, capture_output=True, env=cluster)
        subprocess.run([ray, "start", f"--address=127.0.0.1:{head}", "--num-cpus=1", "--disable-usage-stats"],
                       check=True, capture_output=True, env=cluster)
        subprocess.run([sys.executable, "-m", "mogo_runtime.cli", "serve", str(args.bundle), "--ray", "--detach",
                        "--replicas", str(args.ray), "--port", str(port), "--ray-address", f"127.0.0.1:{head}",
                        "--variant", args.variant, "--characters-per-connection", str(args.characters)],
                       check=True, env=env, capture_output=True)
        url += "/"
    else:
        proc = subprocess.Popen([sys.executable, "-m", "mogo_runtime.cli", "serve", str(args.bundle), "--port",
                                 str(port), "--variant", args.variant, "--characters-per-connection",
                                 str(args.characters), "--characters", str(args.clients * args.characters + 10)],
                                env=env, stderr=subprocess.PIPE, text=True)
        proc.stderr.readline()
    try:
        stats, stop = Stats(), asyncio.Event()
        rng = random.Random(args.seed)
        tasks = [asyncio.create_task(client(n, url, args.characters, stop, stats, random.Random(rng.random())))
                 for n in range(args.clients)]
        await asyncio.sleep(20)                          # everyone connected and adding
        start_tokens, began = stats.tokens, time.monotonic()
        await asyncio.sleep(60 * args.minutes)
        rate = (stats.tokens - start_tokens) / (time.monotonic() - began) / (args.clients * args.characters)
        stop.set()
        await asyncio.gather(*tasks)
    finally:
        if args.ray:
            subprocess.run([ray, "stop", "--force"], capture_output=True)
        else:
            proc.send_signal(signal.SIGTERM)
            proc.wait(60)
    dims = MotionGenerator(args.bundle, variant=args.variant).dims
    late = [x for t, x in stats.latency if t > began]
    return {"server": f"ray, {args.ray} replica(s)" if args.ray else "plain", "characters": args.clients *
            args.characters, "real_time": rate / (dims.fps / dims.downsample), "errors": stats.errors[:10],
            "latency_ms": {"p50": 1e3 * percentile(late, 50), "p99": 1e3 * percentile(late, 99)}}


def check_sample(args, stats: Stats, n: int = 12) -> str:
    """A sample of characters generated again alone: the same tokens, the restart included."""
    from mogo_runtime import MotionGenerator
    from mogo_runtime.crowd import Crowd

    gen = MotionGenerator(args.bundle, variant=args.variant)
    sample = random.Random(1).sample(sorted(stats.characters), min(n, len(stats.characters)))
    same = 0
    for key in sample:
        c = stats.characters[key]
        crowd = Crowd(gen)
        ch = crowd.add(c["prompt"], seed=c["seed"])
        switches = dict(c["switches"])
        tokens = []
        for _ in range(len(c["tokens"])):
            if ch.count in switches:
                ch.set_prompt(switches[ch.count])
            crowd.tick()
            tokens.append(ch.context.last.tolist())
        same += tokens == c["tokens"]
    return f"{same} of {len(sample)} characters ({sum(len(stats.characters[k]['tokens']) for k in sample)} tokens)"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, required=True)
    ap.add_argument("--variant", default="compact")
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--characters", type=int, default=4)
    ap.add_argument("--minutes", type=float, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--simple", action="store_true", help="clients only: real time and latency")
    ap.add_argument("--ray", type=int, default=0, metavar="REPLICAS", help="with --simple: on Ray Serve")
    ap.add_argument("--out", type=Path, help="write the results as JSON here too")
    ap.add_argument("--hostile-nice", type=int, default=0, choices=range(0, 20), metavar="0-19",
                    help="run the attackers' process at this nice value (default 0: as the server and clients)")
    ap.add_argument("--attacks", type=_attacks, default=list(ATTACKS),
                    help=f"the hostile clients' attacks, comma-separated (default all: {','.join(ATTACKS)})")
    ap.add_argument("--hostile", metavar="URL", help=argparse.SUPPRESS)    # the attackers' process
    args = ap.parse_args()
    if args.hostile:
        print(json.dumps(asyncio.run(attack(args.hostile, 60 * args.minutes, args.attacks))))
        return
    result = asyncio.run(main_async(args))
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
