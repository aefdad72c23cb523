"""A character saved and restored (state.py) goes on with the tokens and frames it would have had: bit for bit
against a crowd that never stopped, at any tick (mid-context, right after a prompt switch, steered, a prompt of
several actions); saved data that is wrong is refused naming the field, and changes nothing."""
import base64
import json

import numpy as np
import pytest
from toy_bundle import control_toy_bundle, portable_toy_bundle  # noqa: F401  (fixtures)

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.crowd import Crowd
from mogo_runtime.endless import COMPACTIONS
from mogo_runtime.state import restore_character, save_character

PLAN = [("a person walks forward", 1), ("a person waves with the right hand", 2),
        ("a person jumps in place for 2 seconds, then turns left and then waves with the right hand", 5),
        ("a person walks in a circle", 4)]       # the toy walks its circle long enough to compact its context


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


@pytest.mark.parametrize("save_at", [1, 9, 10, 23, 27, 50, 52, 53])
@pytest.mark.parametrize("sampling", [None, SamplingConfig(temperature=0.0)], ids=["defaults", "greedy"])
def test_a_restored_character_goes_on_as_if_it_never_stopped(gen, save_at, sampling):
    never = run(gen, 60, sampling=sampling)
    restored = run(gen, 60, save_at=save_at, sampling=sampling)
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


def test_a_restore_replays_a_compacted_context(gen):
    """The saves above at ticks 23, 27, 50 and 52 land where the circle walker's context was compacted 1, 2, 3 and 3
    times (its numbers came from tokens no longer in it), and at 53 where its next step rebuilds it; so the restored
    character replayed up to `keep` tokens, compacting where its stream did."""
    crowd = Crowd(gen)
    chars = [crowd.add(p, seed=s) for p, s in PLAN]
    seen = {}
    for t in range(54):
        if t == 9:
            chars[1].set_prompt("a person turns left")
        seen[t] = (chars[3].context.compactions, chars[3].context.cached)
        crowd.tick()
    span = chars[3].context.span
    assert [seen[t][0] for t in (23, 27, 50, 53)] == [1, 2, COMPACTIONS, COMPACTIONS] and seen[53][1] == span
    # at 52 the replay is the longest there is: the whole ring
    assert seen[52][1] + COMPACTIONS * (span - chars[3].context.window + 1) + 1 == chars[3].context.keep


def test_a_state_saved_before_compaction_is_restored(gen):
    """A state written before contexts were compacted (a ring of window + refresh tokens, no `compactions`) restores
    as it would have: at tick 8 no context here is full (its next step neither compacts nor rebuilds), so the
    character goes on as if it never stopped."""
    never = run(gen, 20)
    crowd = Crowd(gen)
    chars = [crowd.add(p, seed=s) for p, s in PLAN]
    for _ in range(8):
        crowd.tick()
    assert all(c.context.cached < c.context.span and not c.context.compactions for c in chars)
    other = Crowd(gen)
    restored = []
    for c in chars:
        d = json.loads(save_character(c))
        ctx, span = d["context"], c.context.span
        del ctx["compactions"]
        ring = np.frombuffer(base64.b64decode(ctx["history"]["data"]), "<i8").reshape(c.context.history.shape)
        held = np.arange(max(0, c.count - span), c.count)
        old = np.zeros((span, ring.shape[1]), np.int64)
        old[held % span] = ring[held % c.context.keep]
        ctx["history"] = {"dtype": "<i8", "shape": list(old.shape), "data": base64.b64encode(old.tobytes()).decode()}
        restored.append(restore_character(other, json.dumps(d).encode()))
    for t in range(8, 20):
        if t == 9:
            restored[1].set_prompt("a person turns left")
        other.tick()
        for i, c in enumerate(restored):
            np.testing.assert_array_equal(c.context.last, never[i][0][t])


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
    ("context.compactions", 4, "context.compactions must be"),
    # a context whose numbers would come from more tokens than the character has picked
    ("context.compactions", 2, "context.cached must be context tokens before the last"),
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
