"""Long multi-action sequences: 20-60 s, 3-8 actions back to back, joined by cross-fades of 0.3-1.5 s, with
one timed caption per action besides one or two for the whole sequence (`generate_long`).

They are what a model that keeps a motion stream going, and changes action when given a new prompt, learns
transitions from: the two-action clips of clips.py fit in T2M's 10 s and always blend over 0.5 s. Each
action is a family's own, drawn as for a single clip (with what is left of 60 s as its budget); what a
sequence adds is only the order, the cross-fades and where each action's span starts and ends.
"""
from __future__ import annotations

import numpy as np

from .action import Action, TimeBudget
from .captions import sequence_captions, single_caption
from .clips import Clip, Segment, blend
from .families import FAMILIES, LAST_ONLY
from .grounding import pose_to_joints
from .pose import FPS, Pose

LONG_SECONDS = (20.0, 60.0)
LONG_ACTIONS = (3, 8)
FADE_FRAMES = (6, 30)  # 0.3-1.5 s cross-fades between consecutive actions
# Each action's span, from the middle of the fade into it to the middle of the fade out of it, lasts at
# least this long (2.1 s): its features then keep T2M's 40-frame minimum, so it loads as an item of its own.
MIN_SPAN = 42
STILL_DEG = 3.0  # an action has not started while no joint angle is this far from its first frame's


def hold(pose: Pose, before: int, after: int) -> Pose:
    """`pose` holding its first frame `before` frames longer and its last `after` frames longer (both are
    grounded: every action starts and ends standing, or seated)."""
    idx = np.concatenate([np.zeros(before, int), np.arange(pose.T), np.full(after, pose.T - 1)])
    out = Pose(len(idx))
    for name in ("angles", "flight", "leap", "air_speed", "support", "resting"):
        setattr(out, name, getattr(pose, name)[idx])
    return out


def _draw_actions(rng: np.random.Generator) -> tuple[list[Action], list[int]]:
    """Actions and the fades before each (0 before the first): at least a drawn number of 3-8 actions and
    20 s, at most 8 actions and 60 s; never the same family twice in a row."""
    wanted = int(rng.integers(LONG_ACTIONS[0], LONG_ACTIONS[1] + 1))
    names = list(FAMILIES)
    actions: list[Action] = []
    fades: list[int] = []
    frames = 0
    while len(actions) < LONG_ACTIONS[1]:
        fade = int(rng.integers(FADE_FRAMES[0], FADE_FRAMES[1] + 1)) if actions else 0
        room = LONG_SECONDS[1] - (frames - fade) / FPS - 2.0  # 2 s kept for the holds of _padding
        if room < 3.0:
            break
        prev = actions[-1].family if actions else None
        action = FAMILIES[str(rng.choice([f for f in names if f != prev]))](rng, TimeBudget.at_most(room))
        count, total = len(actions) + 1, frames + action.pose.T - fade
        last = count == LONG_ACTIONS[1] or (count >= wanted and total >= LONG_SECONDS[0] * FPS)
        if action.family in LAST_ONLY and not last:
            continue
        actions.append(action)
        fades.append(fade)
        frames = total
        if last:
            break
    return actions, fades


def _still(angles: np.ndarray) -> int:
    """How many leading frames stay within STILL_DEG of the first (standing before the action starts)."""
    moved = np.abs(angles - angles[0]).max(axis=(1, 2)) > STILL_DEG
    return int(np.argmax(moved)) if moved.any() else len(angles)


def _padding(actions: list[Action], fades: list[int]) -> list[tuple[int, int]]:
    """Frames each action is held longer (before, after) so that (1) each half of a cross-fade has the
    action it belongs to standing still: one action's motion ends before the middle of the fade (where
    its span ends) and the next one's starts after it, so they never overlap and each stays in its own
    span (a long fade into a short kick damped the kick and put its wind-up in the span before); and
    (2) each span lasts MIN_SPAN frames."""
    pads = [[0, 0] for _ in actions]
    for i in range(1, len(actions)):
        half = fades[i] // 2
        pads[i - 1][1] += max(0, fades[i] - half - _still(actions[i - 1].pose.angles[::-1]))
        pads[i][0] += max(0, half - _still(actions[i].pose.angles))
    return min_spans(actions, fades, pads)


def min_spans(actions, fades: list[int], pads: list[list[int]]) -> list[tuple[int, int]]:
    """`pads` (before, after) of each action lengthened evenly on both sides so that its span (its frames, its pads,
    and half of each cross-fade) lasts MIN_SPAN frames."""
    for i, a in enumerate(actions):
        fade_out = fades[i + 1] if i + 1 < len(fades) else 0
        span = a.pose.T + sum(pads[i]) - fades[i] // 2 - (fade_out - fade_out // 2)
        short = max(0, MIN_SPAN - span)
        pads[i][0] += short // 2
        pads[i][1] += short - short // 2
    return [(b, e) for b, e in pads]


def generate_long(rng: np.random.Generator) -> Clip:
    """World joints (T, 22, 3) of a 20-60 s sequence of 3-8 actions, 1-2 captions of the whole of it, and
    one segment per action with its own caption. Segments meet at the middle of each cross-fade."""
    heading = rng.uniform(-180.0, 180.0)
    for _ in range(100):  # redraw the rare sequence whose actions add up to under 20 s (or over 60 s)
        actions, fades = _draw_actions(rng)
        pads = _padding(actions, fades)
        total = sum(a.pose.T + b + e - f for a, (b, e), f in zip(actions, pads, fades))
        if len(actions) >= LONG_ACTIONS[0] and LONG_SECONDS[0] * FPS <= total <= LONG_SECONDS[1] * FPS:
            break
    else:
        raise RuntimeError("no long sequence of 20-60 s in 100 draws")  # 1 redraw in 3,000 sequences
    poses = [hold(a.pose, *p) for a, p in zip(actions, pads)]
    pose, cuts = poses[0], [0]
    for nxt, fade in zip(poses[1:], fades[1:]):
        cuts.append(pose.T - fade + fade // 2)
        pose = blend(pose, nxt, fade)
    cuts.append(pose.T)
    pose.angles[:, 0, 1] += heading
    joints = pose_to_joints(pose)
    phrases = [a.phrases for a in actions]
    segments = [Segment(a.family, s, e, a.params, single_caption(a.phrases, rng))
                for a, s, e in zip(actions, cuts[:-1], cuts[1:])]
    return Clip(joints, sequence_captions(phrases, rng), segments)
