"""A character saved and restored (state.py) goes on with the tokens and frames it would have had: bit for bit
against a crowd that never stopped, at any tick (mid-context, right after a prompt switch, steered, a prompt of
several actions); saved data that is wrong is refused naming the field, and changes nothing."""
import json

import numpy as np
import pytest
from toy_bundle import control_toy_bundle, portable_toy_bundle  # noqa: F401  (fixtures)

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.crowd import Crowd
from mogo_runtime.state import restore_character, save_character

PLAN = [("a person walks forward", 1), ("a person waves with the right hand", 2),
        ("a person jumps in place for 2 seconds, then turns left and then waves with the right hand", 5)]


def run(gen, ticks, save_at=None, steer=False, sampling=None):
    """-> per character: (tokens, joints), through `ticks` ticks; `save_at`: every character saved at that tick,
    the crowd dropped, and a new crowd restored from the saved bytes (as a server that restarts)."""
    crowd = Crowd(gen, sampling=sampling)
    chars = [crowd.add(p, seed=s) for p, s in PLAN]
    if steer:
        chars[0].walk_to((1.5, 2.0))
    tokens, joints = [[] for _ in chars], [[] for _ in chars]
    for t in range(ticks):
        if t == save_at:
            saved = [save_character(c) for c in chars]
            crowd = Crowd(gen, sampling=sampling)
            chars = [restore_character(crowd, data) for data in saved]
        if t == 9:
            chars[1].set_prompt("a person turns left")
        frames = crowd.tick()
        for i, c in enumerate(chars):
            tokens[i].append(c.context.last.copy())
            if c in frames:
                joints[i].append(frames[c].joints)
    return [(np.stack(tk), np.concatenate(j)) for tk, j in zip(tokens, joints)]


@pytest.fixture(scope="module")
def gen(portable_toy_bundle):  # noqa: F811
    return MotionGenerator(portable_toy_bundle, variant="compact")


@pytest.mark.parametrize("save_at", [1, 9, 10, 23])
@pytest.mark.parametrize("sampling", [None, SamplingConfig(temperature=0.0)], ids=["defaults", "greedy"])
def test_a_restored_character_goes_on_as_if_it_never_stopped(gen, save_at, sampling):
    never = run(gen, 40, sampling=sampling)
    restored = run(gen, 40, save_at=save_at, sampling=sampling)
    for (tk_a, j_a), (tk_b, j_b) in zip(never, restored):
        np.testing.assert_array_equal(tk_a, tk_b)
        np.testing.assert_array_equal(j_a, j_b)


def test_a_steered_character_is_restored_with_its_request_and_correction(control_toy_bundle):  # noqa: F811
    gen = MotionGenerator(control_toy_bundle, variant="portable")
    never, restored = run(gen, 30, steer=True), run(gen, 30, save_at=12, steer=True)
    for (tk_a, j_a), (tk_b, j_b) in zip(never, restored):
        np.testing.assert_array_equal(tk_a, tk_b)
        np.testing.assert_array_equal(j_a, j_b)


def test_a_restored_context_is_fed_again(gen):
    """A restore that skipped feeding the context again (its step cache empty) parts from the character that never
    stopped: what the equality above rests on."""
    never = run(gen, 40)
    crowd = Crowd(gen)
    chars = [crowd.add(p, seed=s) for p, s in PLAN]
    for _ in range(10):
        crowd.tick()
    other = Crowd(gen)
    restored = [restore_character(other, save_character(c)) for c in chars]
    assert sum(c.context.resume for c in restored) >= 2
    for c in restored:
        c.context.resume = False
    tokens = [[] for _ in restored]
    for _ in range(10, 40):
        other.tick()
        for i, c in enumerate(restored):
            tokens[i].append(c.context.last.copy())
    assert any(not np.array_equal(np.stack(t), tk[10:]) for t, (tk, _) in zip(tokens, never))


def _edit(data: bytes, path: str, value) -> bytes:
    d = json.loads(data)
    *keys, last = path.split(".")
    node = d
    for k in keys:
        node = node[k]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    return json.dumps(d).encode()


@pytest.mark.parametrize("path, value, message", [
    ("format", "other", "state.format must be"),
    ("text", "", "empty|blank"),
    ("seed", -1, "state.seed must be"),
    ("context.count", "3", "context.count must be"),
    ("context.history", KeyError, "context.history is missing"),
    ("context.rng", {"bit_generator": "MT19937"}, "context.rng must be"),
    ("context.limits", [0], "context.limits must be"),
    ("context.part", 5, "context.part must be"),
    ("frames.angle", float("nan"), "frames.angle must be"),
    ("frames.position", [1.0], "frames.position must be"),
    ("frames.pending", 99, "frames.pending must be"),
    ("steering", {}, "steering must be present exactly"),
    # the decoder_step graph's state (the portable toy has one): one array per state, float32 of its shape
    ("frames.decoder_state", None, "frames.decoder_state must be present exactly"),
    ("frames.decoder_state", [], "frames.decoder_state must be present exactly"),
    ("frames.decoder_state", [{"dtype": "<f4", "shape": [1, 6], "data": "AAAAAA=="}], "decoder_state.0 must be"),
])
def test_wrong_saved_state_is_refused_naming_the_field(gen, path, value, message):
    crowd = Crowd(gen)
    c = crowd.add(PLAN[0][0], seed=1)
    for _ in range(3):
        crowd.tick()
    data = _edit(save_character(c), path, value)
    other = Crowd(gen)
    with pytest.raises(ValueError, match=message):
        restore_character(other, data)
    assert len(other) == 0


def test_garbage_is_refused(gen):
    crowd = Crowd(gen)
    for data in (b"", b"\xff" * 10, b"[1, 2]", b"{" * 100_000, "text"):
        with pytest.raises(ValueError, match="character state"):
            restore_character(crowd, data)
    assert len(crowd) == 0
