"""`mogo serve --ray` on a local Ray cluster the test starts (a head and one worker node on this machine): clients get
the tokens of their characters through Ray Serve's proxy, a WebSocket stays on its replica, scaling 1 -> 2 -> 1
replicas drops no connection on a replica that stays (no token lost or repeated), and the clients of the replica
removed reconnect to the one that stays, which takes their sessions over: their characters go on with the tokens
they would have had."""
import asyncio
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_serve import PROMPTS, TOKEN, reference_tokens, tokens_of
from toy_bundle import portable_toy_bundle  # noqa: F401,F811  (a fixture)

from mogo_runtime import MotionGenerator
from mogo_runtime.serve.client import ServerClient

RAY = str(Path(sys.executable).parent / "ray")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A head node and a worker node, one CPU each: the address; stopped afterwards."""
    if shutil.which(RAY) is None:
        raise FileNotFoundError(f"{RAY}: ray is not installed (the runtime's `ray` extra; `make setup` installs it)")
    port, temp = _free_port(), tmp_path_factory.mktemp("ray")
    # one proxy (on the head node) for two nodes on one machine: it must not prefer the replicas of its own node, or
    # every connection goes to the head's replica (Ray's default; measured in CI: 12 clients out of 12)
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", RAY_SERVE_PROXY_PREFER_LOCAL_NODE_ROUTING="0")
    subprocess.run([RAY, "start", "--head", f"--port={port}", "--num-cpus=1", "--include-dashboard=false",
                    "--disable-usage-stats", f"--temp-dir={temp}"], check=True, env=env, capture_output=True)
    try:
        subprocess.run([RAY, "start", f"--address=127.0.0.1:{port}", "--num-cpus=1", "--disable-usage-stats"],
                       check=True, env=env, capture_output=True)
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([RAY, "stop", "--force"], env=env, capture_output=True)


def deploy(bundle, address: str, port: int, replicas: int) -> None:
    done = subprocess.run([sys.executable, "-m", "mogo_runtime.cli", "serve", str(bundle), "--ray", "--detach",
                           "--replicas", str(replicas), "--port", str(port), "--ray-address", address],
                          env=dict(os.environ, MOGO_SERVE_TOKEN=TOKEN), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "on Ray Serve" in done.stderr, done.stderr[-2000:]


async def follow(client, ident, got, seconds) -> bool:
    """Tokens of `ident` for `seconds`, each the next one (added to got[ident]) -> True, or False once closed."""
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            await tokens_of(client, {ident: len(got[ident]) + 1}, got, timeout=5)
    except AssertionError:
        raise                          # a token lost or repeated
    except Exception:                  # closed
        return False
    return True


def test_ray_serve_replicas_scale_without_dropping_connections_that_stay(cluster, portable_toy_bundle):  # noqa: F811
    port = _free_port()
    url = f"ws://127.0.0.1:{port}/"
    deploy(portable_toy_bundle, cluster, port, 1)

    async def main():
        first = await ServerClient.connect(url, TOKEN)
        ident = await first.add(*PROMPTS[0][:1], seed=PROMPTS[0][1])
        got = await tokens_of(first, {ident: 5})
        server = first.welcome["server"]
        await asyncio.get_running_loop().run_in_executor(None, deploy, portable_toy_bundle, cluster, port, 2)
        await tokens_of(first, {ident: len(got[ident]) + 5}, got)       # went on while a replica was added
        others = []                                      # clients until one lands on the new replica
        for _ in range(12):
            c = await ServerClient.connect(url, TOKEN)
            others.append(c)
            if c.welcome["server"] != server:
                break
        servers = {c.welcome["server"] for c in [first, *others]}
        other_ids = [await c.add(*PROMPTS[1][:1], seed=PROMPTS[1][1]) for c in others]
        await asyncio.get_running_loop().run_in_executor(None, deploy, portable_toy_bundle, cluster, port, 1)
        # every client follows its character for 25 s, each token the next one: a client on the replica that goes
        # away is closed (within Ray's 2 s grace), the others must not miss a token meanwhile
        members = [(first, ident, got), *((c, i, {i: []}) for c, i in zip(others, other_ids))]
        prompts = [PROMPTS[0], *[PROMPTS[1]] * len(others)]
        stayed = await asyncio.gather(*(follow(c, i, mine, 25.0) for c, i, mine in members))
        alive = [c.welcome["server"] for (c, _, _), ok in zip(members, stayed) if ok]
        gone = [c.welcome["server"] for (c, _, _), ok in zip(members, stayed) if not ok]
        # the clients closed with their replica come back: the replica that stays takes their sessions over
        moved = []
        for (c, i, mine), prompt, ok in zip(members, prompts, stayed):
            if not ok:
                welcome = await c.reconnect()
                assert welcome["server"] in alive and list(welcome["characters"]) == [str(i)], welcome
                await tokens_of(c, {i: len(mine[i]) + 10}, mine)
                moved.append((prompt, mine[i]))
        for c in [first, *others]:
            await c.close()
        return got[ident], servers, alive, gone, moved

    tokens, servers, alive, gone, moved = asyncio.run(main())
    assert len(servers) == 2, "no client landed on the second replica"
    assert alive and gone and len(set(alive)) == 1 and set(gone) == servers - set(alive), \
        f"clients of the replica that stays carry on ({alive}), those of the one removed are closed ({gone})"
    gen = MotionGenerator(portable_toy_bundle, variant="compact")
    np.testing.assert_array_equal(np.stack(tokens[:10]), reference_tokens(gen, *PROMPTS[0], 10))
    assert moved and all(len(m) >= 20 for _, m in moved)
    for (prompt, seed), m in moved:     # the tokens before and after the handover: the character's generated alone
        np.testing.assert_array_equal(np.stack(m), reference_tokens(gen, prompt, seed, len(m)))
