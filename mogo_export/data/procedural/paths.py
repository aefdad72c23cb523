"""Path sequences: 20-60 s of locomotion along a random path, one timed caption per segment
(`generate_path_sequence`), written after the long sequences.

They hold what a game's locomotion controller asks a motion model for: walks at any speed from 0.6 to
1.8 m/s and runs from 1.8 to 4 m/s (also speeding up or slowing down), paths of every curvature and sharp
corners, turns on the spot by any angle, starts, stops and standing still, and moving while facing elsewhere
(backward, sideways, diagonally); control sequences (CONTROL_KINDS) also stop inside a walk or run, and change
its speed, without the caption saying so. The families' clips step at three paces, turn 0 or 360 degrees on
the move and 90, 180 or 360 on the spot: a model conditioned on a future root trajectory cannot learn to
follow a path from them.

The body is steered only through the heading track, the cadence and the stride (path_gaits.py): the feet are
planted and the root follows from them (grounding.solve_ground), so a speed is asked for by choosing a cadence
and the stride whose step length (measured, `Pace.steps`) gives it. Every segment starts and ends standing, so
segments join with cross-fades between two stances, and each spans what sequences.py's do.
"""
from __future__ import annotations

import numpy as np

from .action import Action, TimeBudget
from .captions import sequence_captions, single_caption
from .clips import Clip, Segment, blend
from .gaits import MARCH
from .grounding import pose_to_joints
from .in_place import stand_idle
from .locomotion import _sidestep, _take_steps
from .path_gaits import BACK_PACE, RUN_PACE, TURN_EVENT, WALK_PACE, _locomote, _pieces, _speed_profile
from .pose import FPS, SIDES, seconds_to_frames
from .sequences import _still, hold, min_spans

PATH_SECONDS = (20.0, 60.0)
MAX_SPAN = 199          # frames: T2M keeps items shorter than 200, so every segment still loads as one
SEGMENT_SECONDS = 8.6   # a segment's own frames; with holds and half fades its span stays under MAX_SPAN
# segment kinds and how often each is drawn (walks and runs also last longest: ~55% of the frames)
KINDS = {"walk": 0.30, "run": 0.17, "backpedal": 0.09, "sidestep": 0.09, "diagonal": 0.08, "turn": 0.14,
         "stand": 0.13}
# Control sequences (`generate_path_sequence(rng, CONTROL_KINDS)`) add two kinds a model steered by a future root
# trajectory needs in order to follow its speed and its stops: "pause" stops inside a walk or run captioned as only
# that, "pace" changes speed unnamed. In the other data every change of pace is named and every stop is a segment of
# its own, so the control only ever refined what the text implied (benchmarks/NOTES.md, "the speed is the
# prompt's"). They train only the control adapter (mogo_export/adapter.py): mixed into the transformer's data, even
# only ever with their control, they made text-only walks stop unasked (benchmarks/NOTES.md, "stops and speed
# changes the caption does not name").
CONTROL_KINDS = {**KINDS, "pause": 0.25, "pace": 0.20}
PAUSE_HOLD = (0.0, 1.5)  # s of standing added between the two moves of a pause, to their lead-out and lead-in
FADE_FRAMES = (6, 16)   # 0.3-0.8 s: every segment starts and ends standing, so a fade joins two stances


def _events(heading: np.ndarray, bounds: list[int]) -> list[tuple[float, int, int]]:
    """(signed turn deg, > 0 left; first frame, end frame) of the stretches between `bounds` that turn at
    least TURN_EVENT, consecutive ones to the same side merged: the turns a caption names."""
    out: list[tuple[float, int, int]] = []
    joined = False
    for a, b in zip(bounds[:-1], bounds[1:]):
        turn = float(heading[b - 1] - heading[a])
        if abs(turn) < TURN_EVENT:
            joined = False
        elif joined and np.sign(turn) == np.sign(out[-1][0]):
            out[-1] = (out[-1][0] + turn, out[-1][1], b)
        else:
            out.append((turn, a, b))
            joined = True
    return out


def _sides(turns: list[float]) -> str:
    """"left", "left, then right", "right twice", ... (a caption's order of turns)."""
    sides = ["left" if e > 0 else "right" for e in turns]
    if len(sides) == 2 and sides[0] == sides[1]:
        return f"{sides[0]} twice"
    return ", then ".join(sides)


# per gait and speed band: (upper speed m/s, verb, how the band reads as a manner, as an afterthought)
_BANDS = {"walk": ((1.0, "walks", " slowly", "slowly"), (1.45, "walks", "", "at a normal pace"),
                   (9.9, "walks", " quickly", "quickly")),
          "run": ((2.7, "jogs", "", "jogs"), (3.4, "runs", "", "runs"), (9.9, "runs", " fast", "runs fast"))}


def _band(kind: str, v: float) -> tuple:
    return next(b for b in _BANDS[kind] if v < b[0])


def gait_verb(speed: float) -> str:
    """The verb this data's captions give a steady gait at `speed` m/s: "walks" up to the walking pace's top speed,
    then "jogs", then "runs" (the bands above)."""
    return _band("walk" if speed < WALK_PACE.speeds[1] else "run", speed)[1]


def _travel(rng, kind: str, seconds: float, unnamed: bool = False) -> Action:
    """A walk or a run along a path: steady or changing speed, straight stretches, curves and corners;
    `unnamed`: its speed changes and its caption does not say so (a "pace" segment)."""
    pace = WALK_PACE if kind == "walk" else RUN_PACE
    walk_s = rng.uniform(3.0, max(3.1, seconds - 1.8))
    speed, v0, v1 = _speed_profile(rng, pace, unnamed or rng.random() < 0.35)
    pieces = _pieces(rng, pace, walk_s)
    pose, info, tracks = _locomote(rng, pace, walk_s, speed, pieces)
    heading = tracks["heading"]
    i0, i1 = info["walk"]
    bounds = [i0 + int(round(x * FPS)) for x in np.cumsum([0.0] + [p[1] for p in pieces])]
    bounds[-1] = len(heading)  # the last stretch runs out with the lead-out
    events = _events(heading, bounds)
    turns = [e[0] for e in events]
    net = float(heading[-1])
    b0, b1 = _band(kind, v0), _band(kind, v1)
    # a speed that changes band is named only on its own, and then "runs" covers a jog too
    verb, adv = (b0[1], b0[2]) if b0 == b1 else ("walks" if kind == "walk" else "runs", "")
    phrases = [f"{verb}{adv}"]
    if not turns and b0 != b1 and not unnamed:
        first = f"walks {b0[3]}" if kind == "walk" else b0[3]
        phrases = [f"{first}, then {b1[3]}", f"{first} and then {b1[3]}"]
    elif not turns:
        phrases += [f"{verb} forward{adv}"] + ([f"{verb} straight ahead{adv}"] if abs(net) < 15 else [])
    elif len(turns) == 1 and abs(turns[0]) >= 300:
        side = _sides(turns)
        phrases = [f"{verb} in a circle to the {side}{adv}", f"{verb}{adv} in a full circle to the {side}",
                   f"{verb} around in a {'counterclockwise' if turns[0] > 0 else 'clockwise'} circle"]
    else:
        side = _sides(turns)
        phrases = [f"{verb}{adv} and turns {side}", f"{verb} forward{adv} and turns {side}"]
        if len(turns) == 1:
            phrases.append(f"{verb}{adv} and turns {'around ' if abs(turns[0]) >= 150 else ''}to the {side}")
    family = "run" if kind == "run" else "walk_circle" if any(abs(e) >= 300 for e in turns) else "walk_forward"
    params = dict(info, kind=kind, speeds=(round(v0, 3), round(v1, 3)), net_turn=round(net, 1),
                  turns=[(round(e, 1), a, b) for e, a, b in events], pieces=[p[0] for p in pieces],
                  unnamed=unnamed)
    return Action(family, pose, phrases, params)


def _pause(rng, seconds: float) -> Action:
    """A walk or a run that stops for a while (2.0-2.9 s standing: the two moves' lead-out and lead-in and
    PAUSE_HOLD) and goes on at another speed, along one heading, captioned as the walk or run alone: where it
    stops, and how fast each half goes, only the root's own future says."""
    kind = "walk" if rng.random() < 0.65 else "run"
    if seconds < 7.5:  # no room for two moves and a stop
        return _travel(rng, kind, seconds, unnamed=True)
    pace = WALK_PACE if kind == "walk" else RUN_PACE
    still = rng.uniform(*PAUSE_HOLD)
    # each move's own frames add a 0.4-0.9 s lead-in and lead-out (_locomote): 3.6 s at most, less the fade
    move = max(1.8, (seconds - 3.6 - still) / 2)
    poses, speeds, walks, cadences = [], [], [], []
    for _ in range(2):
        speed, v0, _ = _speed_profile(rng, pace, False)
        walk_s = rng.uniform(1.8, max(1.9, min(3.2, move)))
        pose, info, _ = _locomote(rng, pace, walk_s, speed)
        poses.append(pose)
        speeds.append(round(v0, 3))
        walks.append(info["walk"])
        cadences.append(info["cadence"])
    first = hold(poses[0], 0, seconds_to_frames(still))
    fade = 8  # two standing poses
    pose = blend(first, poses[1], fade)
    second = first.T - fade
    verb = "walks" if kind == "walk" else "runs"
    params = dict(kind="pause", gait=kind, speeds=tuple(speeds), cadence=round(float(np.mean(cadences)), 3),
                  walk=(walks[0][0], second + walks[1][1]), stop=(walks[0][1], second + walks[1][0]), turns=[])
    return Action("run" if kind == "run" else "walk_forward", pose,
                  [verb, f"{verb} forward", f"{verb} straight ahead"], params)


def _backpedal(rng, seconds: float) -> Action:
    """Walking backward, facing the way it came, at a steady slow speed."""
    speed, v0, _ = _speed_profile(rng, BACK_PACE, False)
    pose, info, _ = _locomote(rng, BACK_PACE, rng.uniform(1.5, max(1.6, min(5.0, seconds - 1.8))), speed)
    adv = " slowly" if v0 < 0.45 else ""
    phrases = [f"walks backward{adv}", f"walks backwards{adv}", f"moves backward{adv}", "steps back"]
    return Action("walk_backward", pose, phrases, dict(info, kind="backpedal", speeds=(round(v0, 3),) * 2))


def _sideways(rng, seconds: float) -> Action:
    """Sidestepping (locomotion's own sidestep: a stance width of 0.25-0.45 m every 0.7-1.1 s)."""
    side = str(rng.choice(["left", "right"]))
    action = _sidestep(rng, side, TimeBudget.at_most(seconds))
    action.phrases = [f"sidesteps to the {side}", f"steps sideways to the {side}", f"moves sideways to the {side}",
                      f"shuffles sideways to the {side}"]
    action.params["kind"] = "sidestep"
    return action


def _diagonal(rng, seconds: float) -> Action:
    """Walking forward and to one side, 30-45 degrees off the way the body faces (the facing HumanML3D's
    features take: across the hips and the shoulders). As people do, the pelvis turns toward the path, the
    spine turns the shoulders back, and each hip's swing is turned the rest of the way (flexion traded for
    abduction); the feet point between the two. Past ~35 degrees of spine twist or ~25 degrees of turned
    swing the body corkscrews or the legs cross over each other, which bounds the offset."""
    side = str(rng.choice(["left", "right"]))
    sign = 1.0 if side == "left" else -1.0
    off = rng.uniform(30.0, 45.0)
    # the facing lies between the hips and the shoulders, and a turned swing carries the body along 0.78
    # of its angle: the path is off the facing by about twist / 2 + 0.78 swing (1.17 times that, measured)
    twist, swing_deg = 0.68 * off, 0.66 * off
    pace = WALK_PACE._replace(speeds=(0.6, 1.3))
    speed, v0, _ = _speed_profile(rng, pace, False)
    # long enough to hold its offset for a while between turning into it and out of it (2 cycles)
    walk_s = min(rng.uniform(4.0, 6.5), max(2.0, seconds - 1.8))
    # turned over a whole cycle: in the first step's 0.35 cycles the pelvis jerked past 50 m/s^2
    pose, info, tracks = _locomote(rng, pace, walk_s, speed, hips=sign * twist, feet=0.5 * sign * swing_deg,
                                   settle=1.0)
    swing = np.radians(sign * swing_deg) * tracks["steer"]
    for s in SIDES.values():
        flex = -pose.angles[:, s["hip"], 0]
        pose.angles[:, s["hip"], 0] = -flex * np.cos(swing)
        # abduction toward the side for the near leg, adduction for the far one: the same joint angle
        pose.angles[:, s["hip"], 2] += flex * np.sin(swing)
        # keep the foot's pitch (less flexion) and its sole level (the abduction rolls it)
        pose.angles[:, s["ankle"], 0] -= flex * (1 - np.cos(swing))
        pose.angles[:, s["ankle"], 2] -= flex * np.sin(swing)
    phrases = [f"walks forward and to the {side}", f"walks forward and sideways to the {side}",
               f"moves forward and to the {side}"]
    return Action("walk_forward", pose, phrases, dict(info, kind="diagonal", side=side, offset=round(sign * off, 1),
                                                      speeds=(round(v0, 3),) * 2))


def _turn_on_the_spot(rng, seconds: float) -> Action:
    """Stepping in place while turning by any angle, about 30 degrees a step (as locomotion._turn)."""
    side = str(rng.choice(["left", "right"]))
    angle = float(rng.uniform(30.0, 360.0))
    steps = int(np.ceil(angle / 30.0)) + int(rng.integers(0, 2))
    steps += steps % 2  # an even number, so the feet end side by side
    pose, steps, _, _ = _take_steps(rng, TimeBudget.at_most(seconds), MARCH, steps, rng.uniform(1.6, 2.2), 1.0,
                                    turn_deg=angle if side == "left" else -angle, min_steps=steps)
    if angle < 60:
        phrases = [f"turns slightly to the {side}", f"turns a little to the {side}"]
    elif angle < 135:
        phrases = [f"turns to the {side}", f"turns {side}", f"steps in place and turns {side}"]
    elif angle < 225:
        phrases = [f"turns around to the {side}", f"turns {side} and faces the other way"]
    elif angle < 300:
        phrases = [f"turns {side} in place", f"turns a long way to the {side}"]
    else:
        phrases = [f"turns all the way around to the {side}", f"turns in a full circle to the {side}",
                   f"spins around to the {side} in place"]
    return Action(f"turn_{side}", pose, phrases, dict(kind="turn", side=side, angle=round(angle, 1), steps=steps))


def _stand(rng, seconds: float) -> Action:
    """Standing still between moves, 1-4 s drawn (stand_idle: breathing, glances around; it lasts at least
    2.05 s, and a span at least MIN_SPAN frames, so the shorter stands are the moves' own lead-ins and
    lead-outs)."""
    action = stand_idle(rng, TimeBudget.at_most(min(seconds, rng.uniform(1.0, 4.0))))
    action.phrases = ["stands still", "stands in place", "is standing still", "stands still and looks around"]
    action.params["kind"] = "stand"
    return action


_SEGMENTS = {"walk": lambda rng, s: _travel(rng, "walk", s), "run": lambda rng, s: _travel(rng, "run", s),
             "backpedal": _backpedal, "sidestep": _sideways, "diagonal": _diagonal, "turn": _turn_on_the_spot,
             "stand": _stand, "pause": _pause,
             "pace": lambda rng, s: _travel(rng, "walk" if rng.random() < 0.65 else "run", s, unnamed=True)}


def _draw_segments(rng: np.random.Generator, kinds: dict[str, float]) -> tuple[list[Action], list[int]]:
    """Segments of `kinds` and the fades before each (0 before the first), until a drawn 20-60 s is reached;
    never two stands in a row (they would read as one)."""
    wanted = rng.uniform(*PATH_SECONDS) * FPS
    names, p = list(kinds), np.array(list(kinds.values()))
    actions: list[Action] = []
    fades: list[int] = []
    frames = 0
    while frames < wanted:
        fade = int(rng.integers(FADE_FRAMES[0], FADE_FRAMES[1] + 1)) if actions else 0
        room = PATH_SECONDS[1] - (frames - fade) / FPS - 2.0  # 2 s kept for the holds of _padding
        if room < 3.0:
            break
        allowed = p * [not (k == "stand" and actions and actions[-1].params["kind"] == "stand") for k in names]
        kind = str(rng.choice(names, p=allowed / allowed.sum()))
        action = _SEGMENTS[kind](rng, min(SEGMENT_SECONDS, room))
        actions.append(action)
        fades.append(fade)
        frames += action.pose.T - fade
    return actions, fades


def _padding(actions: list[Action], fades: list[int]) -> list[tuple[int, int]]:
    """Frames each segment is held longer (before, after) so that a cross-fade joins two standing poses
    only (sequences._padding keeps each half of it still; a first step faded in from a stance was damped
    short of the floor and the root jerked), and each span lasts MIN_SPAN frames."""
    pads = [[0, 0] for _ in actions]
    for i in range(1, len(actions)):
        pads[i - 1][1] += max(0, fades[i] - _still(actions[i - 1].pose.angles[::-1]))
        pads[i][0] += max(0, fades[i] - _still(actions[i].pose.angles))
    return min_spans(actions, fades, pads)


def _to_span(params: dict, shift: int, length: int) -> None:
    """The frames a segment steps on ("walk"), keeps its pace on ("steady"), stands on between two moves ("stop")
    and turns on ("turns"), from its own pose's frames to its span's (what a reader of the sequence measures)."""
    def frame(f):
        return int(np.clip(f + shift, 0, length))
    for key in ("walk", "steady", "stop"):
        if key in params:
            params[key] = (frame(params[key][0]), frame(params[key][1]))
    if "turns" in params:
        params["turns"] = [(deg, frame(a), frame(b)) for deg, a, b in params["turns"]]


def generate_path_sequence(rng: np.random.Generator, kinds: dict[str, float] = KINDS) -> Clip:
    """World joints (T, 22, 3) of 20-60 s of locomotion along a random path, 1-2 captions of the whole,
    and one segment per move (or stand) with its own caption, drawn from `kinds` (CONTROL_KINDS: a control
    sequence). Segments meet at the middle of each cross-fade, as in sequences.generate_long."""
    heading = rng.uniform(-180.0, 180.0)
    for _ in range(100):  # redraw the rare path whose spans or total fall outside the bounds
        actions, fades = _draw_segments(rng, kinds)
        pads = _padding(actions, fades)
        lengths = [a.pose.T + b + e for a, (b, e) in zip(actions, pads)]
        total = sum(n - f for n, f in zip(lengths, fades))
        spans = [n - f // 2 - (g - g // 2) for n, f, g in zip(lengths, fades, fades[1:] + [0])]
        if PATH_SECONDS[0] * FPS <= total <= PATH_SECONDS[1] * FPS and max(spans) <= MAX_SPAN:
            break
    else:
        raise RuntimeError("no path sequence of 20-60 s in 100 draws")
    poses = [hold(a.pose, *p) for a, p in zip(actions, pads)]
    pose, cuts, firsts = poses[0], [0], [0]
    for nxt, fade in zip(poses[1:], fades[1:]):
        cuts.append(pose.T - fade + fade // 2)
        firsts.append(pose.T - fade)
        pose = blend(pose, nxt, fade)
    cuts.append(pose.T)
    for a, (before, _), first, cut, end in zip(actions, pads, firsts, cuts, cuts[1:]):
        _to_span(a.params, first + before - cut, end - cut)
    pose.angles[:, 0, 1] += heading
    joints = pose_to_joints(pose)
    segments = [Segment(a.family, s, e, a.params, single_caption(a.phrases, rng))
                for a, s, e in zip(actions, cuts[:-1], cuts[1:])]
    return Clip(joints, sequence_captions([a.phrases for a in actions], rng), segments)
