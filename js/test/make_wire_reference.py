"""Token streams the Python runtime writes, and what its decode-only client makes of them, for js/test/wire.test.mjs.

    python js/test/make_wire_reference.py --out REF --compact TOY_PORTABLE --steered TOY_CONTROL   (run.sh does this)

Writes REF/wire.json:
  streams   a crowd's stream (tests/runtime/test_wire.py crowd_stream: joins, a prompt switch, a leaver) on the
            compact variant of the portable toy, a steered one (walk_to, so WARP records) on the control toy's
            portable variant, and a character joined late (test_wire.py late_stream: START and SYNC) on each: the
            messages (base64), the decoder id, and per client chunk what each message gave (character, first
            frame, frames) and every character's joints as the Python client decodes them
  broken    the broken streams of test_wire.py's refusal test and a few more, each with the message the Python
            client refuses it with
  cut       a message that ends inside a record, and read_message's message for it
  plant     a character's frames moved as a capsule moves them, with the feet the Python FootPlant plants
"""
from __future__ import annotations

import argparse
import base64
import importlib.util
import json
import struct
import sys
from pathlib import Path

import numpy as np

from mogo_runtime import MotionGenerator
from mogo_runtime.bundle.folder import Bundle
from mogo_runtime.control.plant import FootPlant, legs_of
from mogo_runtime.wire import format as wire
from mogo_runtime.wire.client import MotionClient

TESTS = Path(__file__).resolve().parents[2] / "tests" / "runtime"


def _test_wire():
    """tests/runtime/test_wire.py, whose crowd_stream makes the streams both runtimes read (it imports toy_bundle)."""
    sys.path.insert(0, str(TESTS))
    spec = importlib.util.spec_from_file_location("test_wire", TESTS / "test_wire.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _b64(messages: list[bytes]) -> list[str]:
    return [base64.b64encode(m).decode() for m in messages]


def client_run(bundle: Path, variant: str, messages: list[bytes], chunk: int) -> dict:
    """The Python client on `messages`: per message, the frames it gave each character; each character's joints."""
    client = MotionClient(bundle, variant=variant, chunk=chunk)
    received, joints = [], {}
    for m in messages:
        out = client.receive(m)
        received.append([[ident, f.index, len(f.joints)] for ident, f in out.items()])
        for ident, f in out.items():
            joints.setdefault(ident, []).append(f.joints)
    return {"chunk": chunk, "received": received,
            "joints": {str(i): np.concatenate(j).astype(np.float32).ravel().tolist() for i, j in joints.items()}}


def stream(name: str, bundle: Path, variant: str, messages: list[bytes], chunks=(1,)) -> dict:
    manifest = Bundle.load(bundle, variant, ("lookup", "decoder")).manifest
    return {"name": name, "bundle": str(bundle), "variant": variant, "messages": _b64(messages),
            "decoder_id": wire.decoder_id(manifest, variant).hex(),
            "runs": [client_run(bundle, variant, messages, c) for c in chunks]}


# test_wire.py's broken streams (test_a_broken_stream_is_refused_with_what_is_wrong), by what breaks them
BROKEN = [
    ("lost message", lambda ms, L: [ms[0], ms[2]] + ms[3:]),
    ("repeated token", lambda ms, L: ms[:3] + [ms[2]] + ms[3:]),
    ("no HELLO", lambda ms, L: ms[1:]),
    ("bad magic", lambda ms, L: [b"\x01XXXX" + ms[0][5:]] + ms[1:]),
    ("wrong version", lambda ms, L: [ms[0][:5] + b"\x09" + ms[0][6:]] + ms[1:]),
    ("wrong decoder id", lambda ms, L: [ms[0][:-8] + b"\x00" * 8] + ms[1:]),
    ("unknown record type", lambda ms, L: ms[:2] + [b"\x09" + ms[2][1:]]),
    ("unknown event", lambda ms, L: ms[:2] + [struct.pack("<BIIBH", 3, 0, 1, 99, 0)]),
    ("non-UTF-8 text", lambda ms, L: ms[:2] + [struct.pack("<BIIBH", 3, 0, 1, 2, 2) + b"\xff\xfe"]),
    ("code outside codebook",
     lambda ms, L: ms[:2] + [struct.pack("<BIIB", 2, 0, 1, 1) + struct.pack(f"<{L}H", 9999, *[0] * (L - 1))]),
    ("no tokens", lambda ms, L: ms[:2] + [struct.pack("<BIIB", 2, 0, 1, 0)]),
    ("non-finite WARP", lambda ms, L: ms[:2] + [struct.pack("<BIIH5d", 4, 0, 8, 4, float("nan"), 0, 0, 0, 0)]),
    # beyond test_wire.py: tokens of other levels, a token lost mid-stream, a character started twice, a record
    # after its END
    ("wrong levels", lambda ms, L: [ms[0][:6] + bytes([L + 1]) + ms[0][7:]] + ms[1:]),
    ("lost token", lambda ms, L: ms[:3] + ms[4:]),
    ("started twice", lambda ms, L: ms[:2] + [struct.pack("<BIIBH", 3, 0, 0, 1, 0)]),
    ("records after END",
     lambda ms, L: ms[:2] + [struct.pack("<BIIBH", 3, 0, 1, 5, 0) + struct.pack("<BIIBH", 3, 0, 1, 2, 0)]),
    # a SYNC that does not fit the client: a decoder state of another size, a window of the wrong length, none of
    # the eases a warp always has, a number that is not finite
    ("SYNC state size", lambda ms, L: ms[:2] + [wire.encode(_sync(L, state=3))]),
    ("SYNC window", lambda ms, L: ms[:2] + [wire.encode(_sync(L, rows=0))]),
    ("SYNC no eases", lambda ms, L: ms[:2] + [wire.encode(_sync(L))[:13] + b"\x00" + wire.encode(_sync(L))[14:]]),
    ("SYNC non-finite", lambda ms, L: ms[:2] + [wire.encode(_sync(L, angle=float("inf")))]),
]


def _sync(levels: int, state: int = 0, rows: int = 1, angle: float = 0.0) -> wire.Sync:
    """A SYNC of character 0 at token 1, one token pending (the broken streams' second message has token 0)."""
    return wire.Sync(0, 1, min(rows, 1), np.zeros((rows, levels), np.int64), np.zeros(state, np.float32),
                     np.array([angle, *[0.0] * 7]), None, (False, False), False, ((0, *[0.0] * 8, 0),),
                     (False, False), np.zeros(8))


def broken(bundle: Path, variant: str, messages: list[bytes], levels: int) -> list[dict]:
    out = []
    for name, mutate in BROKEN:
        ms = mutate(messages, levels)
        client = MotionClient(bundle, variant=variant)
        try:
            for m in ms:
                client.receive(m)
        except wire.WireError as e:
            out.append({"name": name, "messages": _b64(ms), "error": str(e)})
        else:
            raise SystemExit(f"broken stream {name!r}: the Python client took it")
    return out


def plant_case(joints: np.ndarray, skeleton) -> dict:
    """A character's frames moved as a game's capsule would (drifting 3 cm a frame, turning), planted by the Python
    FootPlant in chunks of 1 to 5 frames, the first 6 frames not moved: the input and what it gives."""
    t = np.arange(len(joints))[:, None]
    moved = joints.copy()
    moved[..., 0] += (0.03 * t + 0.2 * np.sin(t / 7.0)).astype(np.float32)
    moved[..., 2] += (0.01 * t).astype(np.float32)
    flags = [i >= 6 for i in range(len(joints))]
    plant, out, chunks, at = FootPlant(legs_of(skeleton)), [], [], 0
    while at < len(joints):
        n = min(1 + at % 5, len(joints) - at)
        out.append(plant.apply(moved[at:at + n], flags[at:at + n]))
        chunks.append(n)
        at += n
    out = np.concatenate(out)
    pinned, floats = plant.state()
    return {"frames": len(joints), "joints": len(joints[0]), "chunks": chunks, "moved": flags,
            "input": base64.b64encode(moved.astype("<f4").tobytes()).decode(),
            "output": base64.b64encode(out.astype("<f4").tobytes()).decode(),
            "changed": int((out != moved).any(-1).any(-1).sum()), "state": {"pinned": pinned, "floats": floats}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--compact", type=Path, required=True, help="a toy bundle with the compact variant")
    ap.add_argument("--steered", type=Path, required=True, help="a toy bundle with control and the portable variant")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    test_wire = _test_wire()
    crowd_stream, late_stream = test_wire.crowd_stream, test_wire.late_stream
    gen = MotionGenerator(args.compact, variant="compact")
    messages, crowd_joints = crowd_stream(gen)
    short, _ = crowd_stream(gen, ticks=6)
    steered_gen = MotionGenerator(args.steered, variant="portable")
    steered, _ = crowd_stream(steered_gen, ticks=30, steer=True)
    late, _ = late_stream(gen, 9)
    late_steered, _ = late_stream(steered_gen, 12, steer=True)
    L = gen.dims.num_levels
    cut = short[1][:-1]
    try:
        wire.read_message(cut, levels=L)
        raise SystemExit("read_message took a cut record")
    except wire.WireError as e:
        cut_error = str(e)
    ref = {
        "streams": [stream("crowd", args.compact, "compact", messages, (1, 3)),
                    stream("steered", args.steered, "portable", steered),
                    stream("late", args.compact, "compact", late, (1, 3)),
                    stream("late steered", args.steered, "portable", late_steered)],
        "broken": broken(args.compact, "compact", short, L),
        "cut": {"message": _b64([cut])[0], "levels": L, "error": cut_error},
        "plant": plant_case(crowd_joints[0], gen.skeleton),
    }
    (args.out / "wire.json").write_text(json.dumps(ref))
    print(f"wrote {args.out / 'wire.json'} ({len(messages)} + {len(steered)} messages, {len(ref['broken'])} broken streams)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
