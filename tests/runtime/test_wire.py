"""Tokens on the wire: a crowd's characters written as a token stream (wire/tap.py), read by a decode-only client
(wire/client.py) that makes the crowd's joints bit for bit, with no step graph or text encoder; broken streams are
refused with what is wrong."""
import struct

import numpy as np
import pytest
from toy_bundle import build_toy_bundle, control_toy_bundle, portable_toy_bundle  # noqa: F401  (fixtures)

from mogo_runtime import MotionGenerator
from mogo_runtime.bundle.folder import Bundle
from mogo_runtime.bundle.sections import DECODING_GRAPHS
from mogo_runtime.crowd import Crowd
from mogo_runtime.wire import format as wire
from mogo_runtime.wire.client import MotionClient
from mogo_runtime.wire.tap import CharacterTap

PROMPTS = ["a person walks forward", "a person waves with the right hand", "a person jumps in place",
           "a person turns left"]


def crowd_stream(gen, ticks=40, steer=False):
    """A crowd run with joins, a prompt switch, a leaver and (steer) walk_to goals -> (the stream's bytes as
    messages, each character's joints as the crowd made them)."""
    crowd = Crowd(gen)
    messages = [wire.encode(wire.hello_for(gen.bundle.manifest, gen.variant))]
    taps, joints = {}, {}
    for t in range(ticks):
        if t in (0, 3, 7):
            c = crowd.add(PROMPTS[len(taps)], seed=len(taps) + 1, seconds=6.0 if t == 3 else None)
            taps[c] = CharacterTap(c, len(taps))
            joints[taps[c].ident] = []
            if steer and t == 0:
                c.walk_to((2.0, 1.0))
        if t == 11:
            next(iter(taps)).set_prompt(PROMPTS[3])
        records = []
        for c, frames in crowd.tick().items():
            joints[taps[c].ident].append(frames.joints)
        for c, tap in list(taps.items()):
            if c.slot is None or (t == 25 and tap.ident == 2):
                if c.slot is not None:
                    crowd.remove(c)
                records += tap.end()
                del taps[c]
            else:
                records += tap.read()
        messages.append(b"".join(map(wire.encode, records)))
    return messages, {i: np.concatenate(j) for i, j in joints.items()}


@pytest.fixture(scope="module")
def gen(portable_toy_bundle):  # noqa: F811
    return MotionGenerator(portable_toy_bundle, variant="compact")


@pytest.mark.parametrize("chunk", [1, 3])
def test_a_decode_only_client_makes_the_generator_s_joints_bit_for_bit(gen, portable_toy_bundle, chunk):  # noqa: F811
    messages, want = crowd_stream(gen)
    client = MotionClient(portable_toy_bundle, variant="compact", chunk=chunk)
    assert not hasattr(client.decoder, "step_session")
    got: dict[int, list] = {}
    for m in messages:
        for ident, frames in client.receive(m).items():
            assert frames.index == sum(len(j) for j in got.get(ident, []))
            got.setdefault(ident, []).append(frames.joints)
    assert sorted(got) == sorted(want)
    for ident in want:
        mine = np.concatenate(got[ident])
        n = min(len(mine), len(want[ident]))       # the crowd decodes 4 tokens at a time; the client `chunk`
        assert n >= len(want[ident]) - 4 * gen.dims.downsample and n > 0
        np.testing.assert_array_equal(mine[:n], want[ident][:n])
    assert 2 not in client.characters       # the leaver's END freed it


def test_records_cut_anywhere_are_reassembled(gen, portable_toy_bundle):  # noqa: F811
    messages, _ = crowd_stream(gen, ticks=12)
    data = b"".join(messages)
    whole = [wire.encode(r) for r in wire.RecordReader().feed(data)]
    assert b"".join(whole) == data
    reader, records = wire.RecordReader(), []
    for i in range(0, len(data), 7):
        records += reader.feed(data[i:i + 7])
    assert [wire.encode(r) for r in records] == whole and reader.pending == 0


def test_a_steered_character_s_corrections_travel_with_its_tokens(control_toy_bundle):  # noqa: F811
    messages, want = crowd_stream(MotionGenerator(control_toy_bundle, variant="portable"), ticks=30, steer=True)
    records = wire.RecordReader().feed(b"".join(messages))
    assert sum(isinstance(r, wire.Warp) for r in records) >= 20
    assert any(isinstance(r, wire.Event) and r.event == wire.CONTROL for r in records)
    client = MotionClient(control_toy_bundle, variant="portable")
    got: dict[int, list] = {}
    for m in messages:
        for ident, frames in client.receive(m).items():
            got.setdefault(ident, []).append(frames.joints)
    steered, plain = np.concatenate(got[0]), want[0]
    n = min(len(steered), len(plain))
    np.testing.assert_array_equal(steered[:n], plain[:n])
    unwarped = MotionClient(control_toy_bundle, variant="portable")
    # without its WARP records the same tokens stand elsewhere: they are what places it
    for ident, frames in unwarped.apply([r for r in records if not isinstance(r, wire.Warp)]).items():
        if ident == 0:
            got["raw"] = [frames.joints]
    assert np.abs(np.concatenate(got["raw"])[:n] - plain[:n]).max() > 1e-3


def test_a_decode_only_client_needs_only_the_decoding_graphs(portable_toy_bundle, tmp_path):  # noqa: F811
    bundle = Bundle.load(portable_toy_bundle)
    assert "decoder_step" in bundle.manifest.graph_names       # the lookup, the decoder and its step graph
    keep = {bundle.manifest.graph_file(g, "compact").file for g in DECODING_GRAPHS} | {"manifest.json"}
    for f in portable_toy_bundle.iterdir():
        if f.name in keep:
            (tmp_path / f.name).write_bytes(f.read_bytes())
    client = MotionClient(tmp_path, variant="compact")
    messages, want = crowd_stream(MotionGenerator(portable_toy_bundle, variant="compact"), ticks=6)
    out = {}
    for m in messages:
        out.update(client.receive(m))
    assert out and all(np.isfinite(f.joints).all() for f in out.values())
    with pytest.raises(Exception, match="missing"):
        MotionGenerator(tmp_path, variant="compact")


@pytest.mark.parametrize("mutate, message", [
    (lambda ms, L: [ms[0], ms[2]] + ms[3:], "token 1 where 0 was next|before its START"),      # a message lost
    (lambda ms, L: ms[:3] + [ms[2]] + ms[3:], "came twice|started twice"),                   # a message repeated
    (lambda ms, L: ms[1:], "before the stream's HELLO"),
    (lambda ms, L: [b"\x01XXXX" + ms[0][5:]] + ms[1:], "not a mogo token stream"),
    (lambda ms, L: [ms[0][:5] + b"\x09" + ms[0][6:]] + ms[1:], "version 9"),
    (lambda ms, L: [ms[0][:-8] + b"\x00" * 8] + ms[1:], "generated for decoder"),
    (lambda ms, L: ms[:2] + [b"\x09" + ms[2][1:]], "unknown record type 9"),
    (lambda ms, L: ms[:2] + [struct.pack("<BIIBH", 3, 0, 1, 99, 0)], "unknown event 99"),
    (lambda ms, L: ms[:2] + [struct.pack("<BIIBH", 3, 0, 1, 2, 2) + b"\xff\xfe"], "not UTF-8"),
    (lambda ms, L: ms[:2] + [struct.pack("<BIIB", 2, 0, 1, 1) + struct.pack(f"<{L}H", 9999, *[0] * (L - 1))], "outside the codebook"),
    (lambda ms, L: ms[:2] + [struct.pack("<BIIB", 2, 0, 1, 0)], "no tokens"),
    (lambda ms, L: ms[:2] + [struct.pack("<BIIH5d", 4, 0, 8, 4, float("nan"), 0, 0, 0, 0)], "non-finite"),
])
def test_a_broken_stream_is_refused_with_what_is_wrong(gen, portable_toy_bundle, mutate, message):  # noqa: F811
    messages, _ = crowd_stream(gen, ticks=6)
    client = MotionClient(portable_toy_bundle, variant="compact")
    with pytest.raises(wire.WireError, match=message):
        for m in mutate(messages, gen.dims.num_levels):
            client.receive(m)


def test_a_message_must_hold_whole_records(gen):
    messages, _ = crowd_stream(gen, ticks=3)
    with pytest.raises(wire.WireError, match="ends inside a record"):
        wire.read_message(messages[1][:-1], levels=gen.dims.num_levels)


def test_every_record_round_trips():
    records = [wire.Hello(2, 16, 4, bytes(range(8))), wire.Tokens(3, 9, np.array([[1, 2], [15, 0]])),
               wire.Event(3, 9, wire.PROMPT, "\ufeffa person waves ✋"), wire.Event(3, 11, wire.END),
               wire.Warp(3, 44, 4, (1.5, -2.0), 0.25, (0.01, 0.0)),
               wire.Joints(3, 44, np.arange(6, dtype=np.float32).reshape(1, 2, 3)), wire.Tick(2 ** 40 + 7, 1234.5),
               wire.Sync(3, 12, 2, np.arange(10).reshape(5, 2), np.linspace(-1, 1, 7, dtype=np.float32),
                         np.arange(8) / 3.0, np.array([[0.1, 0.2], [-0.3, 0.4]]), (True, False), True,
                         ((0, *[0.0] * 8, 0), (40, *np.arange(8) / 7.0, 12)), (False, True), np.arange(8) / 9.0),
               wire.Sync(4, 0, 0, np.zeros((0, 2), np.int64), np.zeros(0, np.float32), np.zeros(8), None,
                         (False, False), False, ((0, *[0.0] * 8, 0),), (False, False), np.zeros(8))]
    back = wire.read_message(b"".join(map(wire.encode, records)))
    assert len(back) == len(records)
    for a, b in zip(records, back):
        assert type(a) is type(b)
        for k, v in vars(a).items():
            np.testing.assert_array_equal(np.asarray(v), np.asarray(getattr(b, k)))


def late_stream(gen, late: int, ticks: int = 30, steer: bool = False):
    """A crowd character's stream as a client that joins it after `late` ticks gets it (a tap made then: its START
    and SYNC) -> (the messages, the crowd's frames as (first frame, joints))."""
    crowd = Crowd(gen)
    c = crowd.add(PROMPTS[0], seed=3)
    if steer:
        c.walk_to((2.0, 1.0))
    messages, made, tap = [wire.encode(wire.hello_for(gen.bundle.manifest, gen.variant))], [], None
    for t in range(ticks):
        if t == 18:
            c.set_prompt(PROMPTS[1])
        frames = crowd.tick()
        if c in frames:
            made.append((frames[c].index, frames[c].joints))
        if t == late:
            tap = CharacterTap(c, 0)
            records = tap.read()
            assert isinstance(records[0], wire.Event) and isinstance(records[1], wire.Sync)
            messages.append(b"".join(map(wire.encode, records)))
        elif tap is not None:
            messages.append(b"".join(map(wire.encode, tap.read())))
    return messages, made


def joined_late(gen, bundle, variant, late: int, chunk: int = 1, steer: bool = False):
    """`late_stream` read by a decode-only client -> (its first frame, its joints, the crowd's joints from there)."""
    messages, made = late_stream(gen, late, steer=steer)
    client, got = MotionClient(bundle, variant=variant, chunk=chunk), []
    for m in messages:
        got.extend((f.index, f.joints) for f in client.receive(m).values())
    first = got[0][0]
    return first, np.concatenate([j for _, j in got]), np.concatenate([j for _, j in made])[first - made[0][0]:]


@pytest.mark.parametrize("late, chunk", [(5, 1), (9, 3), (14, 4)])
def test_a_client_that_joins_late_makes_the_generator_s_joints_from_its_sync(gen, portable_toy_bundle, late, chunk):  # noqa: F811
    first, mine, want = joined_late(gen, portable_toy_bundle, "compact", late, chunk=chunk)
    assert first <= (late + 1) * gen.dims.downsample and len(mine) >= 40
    n = min(len(mine), len(want))
    np.testing.assert_array_equal(mine[:n], want[:n])


def test_a_late_join_without_a_decoder_step_graph_decodes_windows_from_its_sync(tmp_path, humanml3d_fixture):
    bundle = build_toy_bundle(tmp_path, np.load(humanml3d_fixture / "Mean.npy"), portable=True,
                              with_decoder_step=False)
    gen = MotionGenerator(bundle, variant="portable")
    assert gen.bundle.manifest.decoder_state is None
    first, mine, want = joined_late(gen, bundle, "portable", 21, chunk=2)
    n = min(len(mine), len(want))
    assert n >= 20
    np.testing.assert_array_equal(mine[:n], want[:n])


def test_a_steered_character_joined_late_stands_where_the_generator_put_it(control_toy_bundle):  # noqa: F811
    gen = MotionGenerator(control_toy_bundle, variant="portable")
    first, mine, want = joined_late(gen, control_toy_bundle, "portable", 12, steer=True)
    n = min(len(mine), len(want))
    assert n >= 20 and np.abs(want[0, 0, [0, 2]]).max() > 0.05      # it has moved: not the origin's frames
    np.testing.assert_array_equal(mine[:n], want[:n])


def test_a_sync_that_does_not_fit_the_client_is_refused(gen, portable_toy_bundle):  # noqa: F811
    """A SYNC is read as untrusted as the rest: its window, pending tokens and decoder state must be what this
    client's decoder holds at that token."""
    crowd = Crowd(gen)
    c = crowd.add(PROMPTS[0], seed=1)
    for _ in range(7):
        crowd.tick()
    good = CharacterTap(c, 0).read()
    assert isinstance(good[1], wire.Sync) and good[1].seq == 7
    hello = wire.encode(wire.hello_for(gen.bundle.manifest, gen.variant))
    s = good[1]
    for bad, message in [
            (wire.Sync(**{**vars(s), "window": s.window[1:]}), "window tokens"),
            (wire.Sync(**{**vars(s), "decoder_state": s.decoder_state[:-1]}), "decoder state values"),
            (wire.Sync(**{**vars(s), "window": s.window + gen.dims.codebook_size}), "outside the codebook"),
            (wire.Sync(**{**vars(s), "root": s.root * np.inf}), "non-finite"),
            (wire.Sync(**{**vars(s), "character": 5}), "before its START")]:
        client = MotionClient(portable_toy_bundle, variant="compact")
        with pytest.raises(wire.WireError, match=message):
            client.receive(hello + wire.encode(good[0]) + wire.encode(bad))
    no_eases = bytearray(wire.encode(s))
    no_eases[13] = 0                                  # the eases count (RootWarp always has one)
    with pytest.raises(wire.WireError, match="0 eases"):
        wire.read_message(hello + bytes(no_eases))
