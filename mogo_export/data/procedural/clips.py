"""One clip of the dataset: which families it shows (`family_plan`, `label_for`), and `generate_clip`, which
turns them into a `Clip` (world joints, captions, and the frames each action occupies): a single action,
or a two-action sequence cross-faded by `blend`. Long sequences of 3-8 actions are in sequences.py.

A sequence is where time budgets come from: the first action is given less than MAX_SECONDS so the
second still fits, and the second gets what is left.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .action import FULL_BUDGET, TimeBudget
from .captions import sample_captions
from .curves import ease
from .families import FAMILIES, LAST_ONLY
from .grounding import pose_to_joints
from .pose import FPS, MAX_SECONDS, MIN_SECONDS, Pose


BLEND_FRAMES = 10  # 0.5 s cross-fade between the two actions of a sequence
SEQUENCE_EVERY = 5  # every 5th clip (index % 5 == 4) is a two-action sequence


class Segment(NamedTuple):
    """One action of a clip: its family, the frames [start, end) of the clip it is shown in (cut at the
    middle of the cross-fades into and out of it), the parameters it was drawn with, and, in long
    sequences, its own timed caption."""
    family: str
    start: int
    end: int
    params: dict
    caption: str = ""


class Clip(NamedTuple):
    joints: np.ndarray          # (T, 22, 3) world positions, metres, y up
    captions: list[str]         # describe the whole clip
    segments: list[Segment]     # in order, covering frames 0..T without gaps


def blend(a: Pose, b: Pose, frames: int = BLEND_FRAMES) -> Pose:
    """`a` then `b`, cross-fading joint angles over `frames` frames; b keeps the heading a ends with.

    Root velocity is not a track here: it follows from the feet (solve_ground), so cross-fading the legs'
    angles cross-fades it too.
    """
    n = min(frames, a.T - 1, b.T - 1)
    b_angles = b.angles.copy()
    b_angles[:, 0, 1] += a.angles[-1, 0, 1] - b.angles[0, 0, 1]
    w = ease((np.arange(n) + 1.0) / (n + 1))
    out = Pose(a.T + b.T - n)
    mid = (1 - w)[:, None, None] * a.angles[a.T - n:] + w[:, None, None] * b_angles[:n]
    out.angles = np.concatenate([a.angles[:a.T - n], mid, b_angles[n:]])
    out.flight = np.concatenate([a.flight[:a.T - n], a.flight[a.T - n:] | b.flight[:n], b.flight[n:]])
    out.leap = np.concatenate([a.leap[:a.T - n], a.leap[a.T - n:] | b.leap[:n], b.leap[n:]])
    out.air_speed = np.concatenate([a.air_speed[:a.T - n], np.maximum(a.air_speed[a.T - n:], b.air_speed[:n]),
                                    b.air_speed[n:]])
    out.support = np.concatenate([a.support[:a.T - n], a.support[a.T - n:] | b.support[:n], b.support[n:]])
    out.resting = np.concatenate([a.resting[:a.T - n], a.resting[a.T - n:] | b.resting[:n], b.resting[n:]])
    return out


def family_plan(num_clips: int, seed: int) -> list[tuple[str, ...]]:
    """Which families each clip shows: singles cycle through every family in a shuffled order (so any
    SEQUENCE_EVERY * 21 / (SEQUENCE_EVERY - 1) consecutive clips cover them all); every SEQUENCE_EVERY-th
    clip is a pair of two different families."""
    names = list(FAMILIES)
    plan, singles, order = [], 0, []
    for i in range(num_clips):
        if i % SEQUENCE_EVERY == SEQUENCE_EVERY - 1:
            rng = np.random.default_rng([seed, i, 1])
            first = str(rng.choice([f for f in names if f not in LAST_ONLY]))
            plan.append((first, str(rng.choice([f for f in names if f != first]))))
            continue
        if singles % len(names) == 0:
            order = list(np.random.default_rng([seed, singles // len(names), 2]).permutation(names))
        plan.append((str(order[singles % len(names)]),))
        singles += 1
    return plan


def label_for(families: tuple[str, ...]) -> str:
    """`walk_forward` for a single action, `seq:walk_forward+jump_in_place+...` for a sequence (in order)."""
    return families[0] if len(families) == 1 else "seq:" + "+".join(families)


def generate_clip(families: tuple[str, ...], rng: np.random.Generator) -> Clip:
    """World joints (T, 22, 3), 3-4 captions and the segments of one action or a two-action sequence."""
    heading = rng.uniform(-180.0, 180.0)
    max_frames = int(round(MAX_SECONDS * FPS))
    if len(families) == 1:
        action = FAMILIES[families[0]](rng, FULL_BUDGET)
        pose, captions = action.pose, sample_captions([action.phrases], rng)
        actions, cuts = [action], []
    else:
        for _ in range(20):  # redraw until both fit in MAX_SECONDS (rarely needed)
            # the first action leaves room for a shortest second one (they overlap by the blend)
            first = FAMILIES[families[0]](rng, TimeBudget.at_most(MAX_SECONDS - MIN_SECONDS + BLEND_FRAMES / FPS))
            second = FAMILIES[families[1]](rng, TimeBudget.at_most(MAX_SECONDS + BLEND_FRAMES / FPS
                                                                   - first.pose.T / FPS))
            pose = blend(first.pose, second.pose)
            if pose.T <= max_frames:
                break
        captions = sample_captions([first.phrases, second.phrases], rng)
        n = min(BLEND_FRAMES, first.pose.T - 1, second.pose.T - 1)
        actions, cuts = [first, second], [first.pose.T - n + n // 2]
    pose.angles[:, 0, 1] += heading
    joints = pose_to_joints(pose)[:max_frames]
    bounds = [0] + [min(c, len(joints)) for c in cuts] + [len(joints)]
    segments = [Segment(a.family, s, e, a.params) for a, s, e in zip(actions, bounds[:-1], bounds[1:])]
    return Clip(joints, captions, segments)
