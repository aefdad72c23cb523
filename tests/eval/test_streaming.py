"""`mogo-eval stream`: the measures on motions whose answer is known, and the whole measurement on the tiny bundle."""
import json

import numpy as np
import pytest
import torch

from mogo_eval.cli import main
from mogo_eval.quality import train_classifier
from mogo_eval.streaming import (DEFINITIONS, finite, jerk_per_frame, plan_prompts, reaction_times, root_steps,
                                 skating_frames, transition_measures)

FPS = 20.0
TOES = (10, 11)


def _still(T=60, J=22) -> np.ndarray:
    """A body standing still with both toes on the ground."""
    joints = np.zeros((T, J, 3), np.float32)
    joints[:, :, 1] = np.linspace(0.0, 1.6, J)[None]
    joints[:, list(TOES), 1] = 0.0
    return joints


def test_jerk_is_zero_for_constant_velocity_and_acceleration_and_exact_for_a_cubic():
    t = np.arange(60) / FPS
    moving = _still() + (1.3 * t)[:, None, None]                      # every joint at 1.3 m/s on every axis
    assert np.abs(jerk_per_frame(moving, FPS)).max() < 1e-3
    accelerating = _still() + (0.5 * 2.0 * t ** 2)[:, None, None]     # 2 m/s^2
    assert np.abs(jerk_per_frame(accelerating, FPS)).max() < 1e-2
    cubic = _still().astype(np.float64)
    cubic[:, 3, 0] += 0.7 * t ** 3                                    # one joint: x = 0.7 t^3 -> jerk 4.2 m/s^3
    assert jerk_per_frame(cubic, FPS) == pytest.approx(np.full(57, 4.2), rel=1e-6)


def test_skating_counts_a_grounded_sliding_toe_only():
    slide = _still()
    slide[:, TOES[0], 0] = 0.03 * np.arange(60)                       # 3 cm per frame on the ground: skates
    assert skating_frames(slide, TOES).all()
    slow = _still()
    slow[:, TOES[1], 2] = 0.02 * np.arange(60)                        # 2 cm per frame: within the bar
    assert not skating_frames(slow, TOES).any()
    lifted = slide.copy()
    lifted[:, TOES[0], 1] = 0.10                                      # the same slide 10 cm up: a swing, not skating
    assert not skating_frames(lifted, TOES).any()
    half = _still()
    half[30:, TOES[0], 0] = 0.03 * np.arange(30)                      # slides from frame 30 on
    assert skating_frames(half, TOES).mean() == pytest.approx(29 / 59)


def test_a_root_teleport_shows_in_root_steps_and_in_the_jerk_around_it():
    smooth = _still(120) + (0.05 * np.arange(120))[:, None, None] * np.array([1.0, 0, 0])   # 1 m/s walk
    jump = smooth.copy()
    jump[60:] += np.array([0.5, 0, 0])                                # 50 cm teleport at frame 60
    assert root_steps(smooth).max() == pytest.approx(0.05, abs=1e-5)
    assert root_steps(jump).max() == pytest.approx(0.55, abs=1e-5)
    calm, jolted = (transition_measures([(j, [60])], FPS, TOES) for j in (smooth, jump))
    assert calm["transitions"] == jolted["transitions"] == 1
    assert calm["peak_jerk"] < 1e-2 and calm["area_under_jerk"] < 1e-3
    assert jolted["peak_jerk"] == pytest.approx(0.5 * 2 * FPS ** 3, rel=1e-4)   # 3rd differences of a step: 1, -2, 1
    assert jolted["area_under_jerk"] == pytest.approx(0.5 * (1 + 2 + 1) * FPS ** 3 / FPS, rel=1e-4)
    assert jolted["root_step_max_transitions"] == pytest.approx(0.55, abs=1e-5)
    with pytest.raises(ValueError, match="no boundary"):
        transition_measures([(smooth, [5])], FPS, TOES)               # too close to the start to judge


def test_prompts_switch_every_4_to_10_s_never_repeat_a_family_and_use_the_given_captions():
    captions = {"a": ["a one", "a two"], "b": ["b one"], "c": ["c one", "c two", "c three"], "empty": []}
    prompts, end = plan_prompts(captions, 3000, 0.2, np.random.default_rng(3))
    assert prompts[0].token == 0 and 3000 <= end <= 3000 + 50
    gaps = np.diff([p.token for p in prompts] + [end])
    assert gaps.min() >= 20 and gaps.max() <= 50 and len(set(gaps)) > 10
    assert all(p.family != q.family for p, q in zip(prompts, prompts[1:]))
    assert all(p.text in captions[p.family] for p in prompts) and {p.family for p in prompts} == {"a", "b", "c"}
    assert len({p.text for p in prompts}) == 6                        # every phrasing gets drawn
    with pytest.raises(ValueError, match="2 families"):
        plan_prompts({"a": ["x"], "b": []}, 100, 0.2, np.random.default_rng(0))


class _OneHotJudge(torch.nn.Module):
    """A classifier whose verdict is the class most frames of a clip show (feature k = 1 on frames of class k)."""

    def embedding(self, x, lengths):
        mask = (torch.arange(x.shape[1])[None] < lengths[:, None])[..., None]
        return (x * mask).sum(1) / lengths[:, None]

    def head(self, emb):
        return emb


def test_reaction_is_the_first_window_that_shows_the_new_family():
    families = ["a", "b", "c"]
    feats = np.zeros((400, 3), np.float32)
    feats[:100, 0] = 1                   # a on frames 0..99
    feats[100:130, 0] = 1                # segment 2 asks for b from frame 100; a lingers 30 frames, then b
    feats[130:250, 1] = 1
    feats[250:400, 1] = 1                # segment 3 asks for c from frame 250 and never shows it
    segments = [(100, 250, "b"), (250, 400, "c")]
    got = reaction_times(_OneHotJudge(), families, feats, segments, FPS, step=4)
    # windows of 40 frames from 100 by 4: the first with fewer than 20 frames of a starts at 112 -> 0.6 s
    assert got[0] == {"seconds": pytest.approx(0.6), "detected": True}
    assert got[1] == {"seconds": pytest.approx(150 / FPS), "detected": False}


@pytest.fixture(scope="module")
def data(tiny_checkpoints):
    return tiny_checkpoints.parent / "data"


def test_the_whole_measurement_on_the_tiny_bundle(tiny_bundle, data, tmp_path, one_torch_thread):
    from mogo_runtime import MotionGenerator

    assert MotionGenerator(tiny_bundle, variant="int8").endless, "the tiny bundle must be trained for endless streams"
    classifier = train_classifier(data, tmp_path, steps=30, progress=False)
    out = tmp_path / "stream.json"
    assert main(["stream", "--bundle", str(tiny_bundle), "--variant", "int8", "--minutes", str(24 / 60),
                 "--data", str(data), "--classifier", str(classifier), "--seed", "5", "--json", str(out)]) == 0
    r = json.loads(out.read_text())

    assert finite(r)
    for key in ("follows", "reacts", "judge_on_data", "transitions", "drift", "bounded", "segments", "checks",
                "definitions"):
        assert key in r, key
    assert set(r["definitions"]) == set(DEFINITIONS)
    assert {"accuracy", "per_family", "first_minute", "last_minute"} <= set(r["follows"])
    assert {"median_s", "p90_s", "never", "per_switch"} <= set(r["reacts"])
    assert r["judge_on_data"]["segments"] > r["judge_on_data"]["switches"] > 0
    for side in ("stream", "data"):
        assert {"peak_jerk", "area_under_jerk", "skating_ratio", "skating_ratio_transitions", "root_step_max",
                "root_step_max_transitions", "transitions"} <= set(r["transitions"][side])
    assert {"root_height_change_m", "bone_length_max_rel_change"} <= set(r["drift"])
    assert {"rss_growth_mb", "peak_rss_growth_mb", "token_ms_first_minute", "token_ms_last_minute",
            "token_time_ratio"} <= set(r["bounded"])

    # the segments tile the stream, 4-10 s apart (a switch is at most 3 tokens late), no family twice in a row
    segs = r["segments"]
    assert r["stream_seconds"] >= 24 and segs[0]["start_s"] == 0 and segs[-1]["end_s"] == r["stream_seconds"]
    assert all(a["end_s"] == b["start_s"] for a, b in zip(segs, segs[1:]))
    lengths = np.array([s["end_s"] - s["start_s"] for s in segs])
    assert len(segs) >= 3 and lengths.min() >= 4 - 0.6 - 1e-9 and lengths.max() <= 10 + 0.6 + 1e-9
    assert all(a["family"] != b["family"] for a, b in zip(segs, segs[1:]))
    assert r["follows"]["segments"] == len(segs) and r["reacts"]["switches"] == len(segs) - 1
    assert r["follows"]["accuracy"] == pytest.approx(np.mean([s["correct"] for s in segs]))
    assert r["transitions"]["stream"]["transitions"] == len(segs) - 1
    assert r["transitions"]["data"]["transitions"] > 0
    for rx, seg in zip(r["reacts"]["per_switch"], segs[1:]):
        assert 0 <= rx["seconds"] <= seg["end_s"] - seg["start_s"] + 1e-9 and rx["switch_s"] == seg["start_s"]
        assert rx["detected"] or rx["seconds"] == pytest.approx(seg["end_s"] - seg["start_s"])
    # every number has a row with its bar; a row with a bar says met or missed
    names = {c["name"] for c in r["checks"]}
    assert {"segment accuracy", "reaction median (s)", "reaction p90 (s)", "peak jerk ratio (stream/data)",
            "area under jerk ratio", "skating stream - data (pp)", "RSS growth, first minute -> end (MB)",
            "token time last / first minute"} <= names
    assert all((c["bar"] == "-") == (c["met"] is None) for c in r["checks"])
    assert r["bounded"]["token_ms_first_minute"] > 0 and r["bounded"]["rss_mb_end"] > 50
    assert len(r["bounded"]["memory_marks"]) >= 2
