"""Control benchmark (issue 26): does a character go where the game sends it, with its feet planted, while the text
still says what it does? On a bundle whose model has control.

    python -m benchmarks.control bundles/base [--variant int8] [--data data/procedural] [--json outputs/control.json]

Sections (each seeded; counts on the command line):
  paths      random game paths, 20 s each: smooth curves (curvature up to what the speed allows) and polylines with sharp
             corners (45-135 degrees), speeds 0.8-3.5 m/s, each with a walk, jog or run prompt as the data's captions
             name the gait at that speed (`prompt_for`).
             Per frame: the root's distance to the path and the body's facing against the path's direction there;
             per path: the speed along the path (from 2 s to 2 s before its end) over the path's.
  waypoints  walk_to a goal 2-15 m away in any direction (at walk_to's default speed): reached (within ARRIVE) within
             1.3x the straight-line time at the walk prompt's typical speed (the data's median walking speed), then
             standing still (for the next 2 s
             within STAND_RADIUS of the goal, moving under STAND_SPEED on average over its last second).
  game_root  the game moves the capsule (a scripted loop: a random smooth path, speeds changing 0-2 m/s, strafing part of
             the time): set_root before every frame; the motion's root against the capsule on every frame, and the
             model's own travel (its features' root, before the frames are put on the capsule) against the capsule's
             over 0.5 s windows: how often it heads more than 45 degrees off, and its speed over the capsule's.
  feet       foot skating (mogo_eval.streaming's measure) over the path and game-root motions against the data's own path
             sequences; peak jerk in +-1 s around each sharp corner against the data's around its path sequences'
             segment boundaries (where direction or gait changes).
  text       streams that walk a path, run on, then stand at a waypoint doing an in-place action: each segment (without
             its first second) judged by the project's action classifier.
  cost       a 64-character crowd (int8_fixed) with every character on a path against the same crowd without control.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mogo_runtime.control.vector import root_poses

from .control_paths import (corner_frames, facing_error, path_progress, random_path, smooth_path,
                            travel_agreement, walking_speed)

WALK = "a person walks forward"
PATH_SECONDS = 20.0
ARRIVE = 0.3                 # m: the runtime's own arrival radius (mogo_runtime/control/targets.py)
STAND_RADIUS, STAND_SPEED = 0.5, 0.3      # m, m/s: "then standing still"
IN_PLACE = ("wave_right_hand", "wave_left_hand", "clap", "punch", "kick_left", "kick_right", "bow", "squat",
            "raise_both_arms")


def collect(stream, frames: int, before=None) -> tuple[np.ndarray, np.ndarray]:
    """`frames` frames of `stream` -> (joints (T, J, 3), features (T, D)); `before(i)` runs before frame i."""
    joints, feats = [], []
    for i in range(frames):
        if before is not None:
            before(i)
        f = next(stream)
        joints.append(f.joints)
        feats.append(f.features)
    return np.asarray(joints, np.float64), np.asarray(feats, np.float32)


def prompt_for(speed: float) -> str:
    """A walk, jog or run prompt that fits a path's speed: the verb the data's captions give the gait at that speed
    (naming the speed too, "walks forward slowly" ... "runs forward fast", made no character faster or slower:
    benchmarks/NOTES.md, "Issue 26: the speed a character walks at")."""
    from mogo_export.data.procedural.paths import gait_verb

    return f"a person {gait_verb(speed)} forward"


# ---------------------------------------------------------------------------------------------------- sections

def paths(gen, n: int, seed: int) -> dict:
    rng = np.random.default_rng([seed, 1])
    fps, face = gen.dims.fps, gen.skeleton.face_joints
    frames = round(PATH_SECONDS * fps)
    dist, facing, ratios, motions, kinds = [], [], [], [], []
    for i in tqdm(range(n), desc="paths", unit="path"):
        speed = float(rng.uniform(0.8, 3.5))
        points, corners, kind = random_path(rng, speed, PATH_SECONDS)
        stream = gen.stream(prompt_for(speed), seed=seed * 1000 + i)
        stream.follow_path(points, speed=speed)
        joints, _ = collect(stream, frames)
        stream.close()
        d, arc, tangent = path_progress(points, joints[:, 0, [0, 2]])
        dist.append(d)
        facing.append(facing_error(joints, face, tangent))
        # from 2 s in (it starts standing) to 2 s before the path's end at the path's speed (it slows to stop)
        t0 = round(2 * fps)
        end = min(frames - 1, int(np.searchsorted(arc, path_length(points) - 2 * speed)))
        if end - t0 > fps:
            ratios.append((arc[end] - arc[t0]) / ((end - t0) / fps) / speed)
        motions.append((joints, corner_frames(arc, corners)))
        kinds.append(kind)
    d, f, r = np.concatenate(dist), np.degrees(np.concatenate(facing)), np.array(ratios)
    return {"paths": n, "kinds": {k: kinds.count(k) for k in sorted(set(kinds))},
            "position_error_m": {"median": float(np.median(d)), "p95": float(np.percentile(d, 95)),
                                 "max": float(d.max())},
            "facing_error_deg": {"median": float(np.median(f)), "p95": float(np.percentile(f, 95))},
            "speed_ratio": {"median": float(np.median(r)), "p05": float(np.percentile(r, 5)),
                            "p95": float(np.percentile(r, 95)),
                            "within_10pct": float(np.mean(np.abs(r - 1) <= 0.10)), "measured": int(len(r))},
            "_motions": motions}


def path_length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def waypoints(gen, n: int, seed: int, typical: float) -> dict:
    rng = np.random.default_rng([seed, 2])
    fps = gen.dims.fps
    reached, still, late, times = [], [], [], []
    for i in tqdm(range(n), desc="waypoints", unit="goal"):
        d, a = float(rng.uniform(2, 15)), float(rng.uniform(-math.pi, math.pi))
        goal = np.array([d * math.sin(a), d * math.cos(a)])
        limit = 1.3 * d / typical
        stream = gen.stream(WALK, seed=seed * 1000 + i)
        stream.walk_to(goal)                            # the default speed, as a game would call it
        joints, _ = collect(stream, round((limit + 2.0) * fps) + 1)
        stream.close()
        away = np.hypot(*(joints[:, 0, [0, 2]] - goal).T)
        hit = np.nonzero(away < ARRIVE)[0]
        ok = len(hit) > 0 and hit[0] / fps <= limit
        reached.append(ok)
        if ok:
            times.append(hit[0] / fps / (d / typical))
            after = joints[hit[0]:hit[0] + round(2 * fps) + 1, 0, :][:, [0, 2]]
            last = after[-round(fps) - 1:]
            speed = np.hypot(*(last[-1] - last[0])) / ((len(last) - 1) / fps)
            still.append(bool(np.hypot(*(after - goal).T).max() <= STAND_RADIUS and speed < STAND_SPEED))
        else:
            late.append({"distance": round(d, 2), "bearing_deg": round(math.degrees(a)), "closest": float(away.min())})
    return {"goals": n, "typical_speed": typical, "reached": float(np.mean(reached)),
            "reached_and_standing": float(np.sum(still) / n), "time_over_straight_line": {
                "median": float(np.median(times)) if times else None, "max": float(np.max(times)) if times else None},
            "missed": late[:10]}


def game_root(gen, n: int, seed: int) -> dict:
    rng = np.random.default_rng([seed, 3])
    fps = gen.dims.fps
    frames = round(PATH_SECONDS * fps)
    errors, motions, angles, ratios = [], [], [], []
    for i in tqdm(range(n), desc="game root", unit="loop"):
        capsule = scripted_capsule(rng, frames, fps)
        stream = gen.stream(WALK, seed=seed * 1000 + i)
        joints, features = collect(stream, frames, before=lambda f: stream.set_root(*capsule[f]))
        stream.close()
        errors.append(np.hypot(*(joints[:, 0, [0, 2]] - capsule[:, :2]).T))
        motions.append((joints, []))
        # the model's own root (its features, before the frames are put on the capsule): does it move as asked?
        angle, ratio = travel_agreement(root_poses(features)[:, :2], capsule[:, :2], fps)
        angles.append(angle)
        ratios.append(ratio)
    e, angle, ratio = np.concatenate(errors), np.concatenate(angles), np.concatenate(ratios)
    return {"loops": n, "root_to_capsule_m": {"max": float(e.max()), "p99": float(np.percentile(e, 99)),
                                              "median": float(np.median(e))},
            "model_travel": {"windows": len(angle), "off_by_45deg": float((angle > math.pi / 4).mean()),
                             "angle_median_deg": float(np.degrees(np.median(angle))),
                             "speed_ratio_median": float(np.median(ratio))} if len(angle) else None,
            "_motions": motions}


def scripted_capsule(rng, frames: int, fps: float) -> np.ndarray:
    """A game's capsule: (frames, 3) x, z, heading. Its speed changes every 2-5 s between standing and 2 m/s, its path
    curves, and a third of the time it strafes (faces 90 degrees off the way it moves)."""
    pose, out = np.zeros(3), []
    direction = 0.0
    f = 0
    while f < frames:
        n = int(rng.integers(round(2 * fps), round(5 * fps)))
        speed = 0.0 if rng.random() < 0.2 else float(rng.uniform(0.5, 2.0))
        turn = float(rng.uniform(-1.0, 1.0)) * min(1.5, 3.0 / max(speed, 0.5)) / fps    # rad per frame
        strafe = (math.pi / 2) * float(rng.choice([-1, 1])) if rng.random() < 0.33 else 0.0
        for _ in range(n):
            direction += turn
            pose = np.array([pose[0] + speed / fps * math.sin(direction),
                             pose[1] + speed / fps * math.cos(direction), direction + strafe])
            out.append(pose)
        f += n
    return np.array(out[:frames])


def feet(path_motions, root_motions, data: Path, fps: float, toes) -> dict:
    from mogo_eval.streaming import transition_measures

    ref = reference_path_sequences(data)
    data_m = transition_measures(ref, fps, toes)
    corners = [(j, b) for j, b in path_motions if b]
    gen_m = transition_measures(corners, fps, toes) if corners else None
    skate_paths = transition_measures([(j, b or [len(j) // 2]) for j, b in path_motions], fps, toes)["skating_ratio"]
    skate_root = transition_measures([(j, [len(j) // 2]) for j, _ in root_motions], fps, toes)["skating_ratio"]
    return {"data_path_sequences": len(ref), "skating_data": data_m["skating_ratio"], "skating_paths": skate_paths,
            "skating_game_root": skate_root, "peak_jerk_data": data_m["peak_jerk"],
            "peak_jerk_corners": gen_m["peak_jerk"] if gen_m else None,
            "corners": gen_m["transitions"] if gen_m else 0,
            "jerk_ratio": gen_m["peak_jerk"] / data_m["peak_jerk"] if gen_m else None}


def reference_path_sequences(data: Path) -> list[tuple[np.ndarray, list[int]]]:
    info = json.loads((data / "dataset.json").read_text())
    first = info["num_clips"] + info["num_long_sequences"]
    ids = {line for split in ("test", "val") for line in (data / f"{split}.txt").read_text().split()}
    out = []
    for cid, segs in sorted(info["segments"].items()):
        if int(cid) >= first and cid in ids:
            out.append((np.load(data / "new_joints" / f"{cid}.npy").astype(np.float64), [s["start"] for s in segs[1:]]))
    return out


def text_rules(gen, n: int, seed: int, data: Path, classifier: Path) -> dict:
    """Walk a path (6 s), run on along it (6 s), then stand at a goal doing an in-place action (6 s)."""
    from mogo_eval.quality import classify, load_classifier
    from mogo_eval.streaming import held_out_captions
    from mogo_export.data.dataset import load_mean_std, normalize

    model, families = load_classifier(classifier)
    captions = held_out_captions(data, families)
    mean, std = load_mean_std(data)
    rng = np.random.default_rng([seed, 4])
    fps = gen.dims.fps
    seg = round(6 * fps)
    clips, truth = [], []
    for i in tqdm(range(n), desc="text", unit="stream"):
        acts = ["walk_forward", "run", str(rng.choice(IN_PLACE))]
        texts = [str(rng.choice(captions[a])) for a in acts]
        points = smooth_path(rng, 3.0, 14.0)
        stream = gen.stream(texts[0], seed=seed * 1000 + i)
        stream.follow_path(points, speed=1.3)
        _, f0 = collect(stream, seg)
        stream.set_prompt(texts[1])
        stream.follow_path(points, speed=3.0)
        _, f1 = collect(stream, seg)
        stream.set_prompt(texts[2])
        stream.walk_to(stream.steering.pose[:2])          # stand where it is
        _, f2 = collect(stream, seg)
        stream.close()
        for f, a in zip((f0, f1, f2), acts):
            clips.append(normalize(f[round(fps):], mean, std))
            truth.append(a)
    pred = classify(model, families, clips)[0]
    hits = np.array(pred) == np.array(truth)
    per = {a: float(hits[[t == a for t in truth]].mean()) for a in sorted(set(truth))}
    return {"streams": n, "segments": len(truth), "accuracy": float(hits.mean()), "per_family": per,
            "confusions": sorted({f"{t}->{p}" for t, p in zip(truth, pred) if t != p})[:20]}


ROUND = 8           # ticks timed together in the cost section (two chunks of 4)
FRESH = (8, 48)     # ticks of the cost section's first phase: every context shorter than window + refresh
STEADY = 100        # the tick its second phase starts at: characters that have not ended rebuild their contexts


def cost(bundle: str, characters: int, ticks: int, seed: int) -> dict:
    """Per character-token time of a crowd walking paths against the same crowd without control, in two phases:
    `fresh` (no context long enough to be rebuilt yet) and `steady` (`ticks` ticks from tick STEADY on). Timed in
    rounds of whole decode periods: at chunk 4 three ticks in four decode nothing, so a median tick (as this
    measured before) left the decode out of the uncontrolled crowd's cost. The crowds run side by side, a round each
    in turn, so a slow spell of the machine falls on all of them (one crowd after another, the ratio moved by 10%
    between runs). Step rows per tick are counted: a character that does not end its motion rebuilds its context
    every `refresh` tokens (window + 1 rows)."""
    from mogo_runtime import MotionGenerator
    from mogo_runtime.crowd import Crowd

    gen = MotionGenerator(bundle, variant="int8_fixed", threads=1)
    rng = np.random.default_rng([seed, 5])
    names = ("free_chunk4", "free_chunk1", "controlled")
    crowds, rows = {}, {name: [] for name in names}
    step = gen.backend.step_in_place
    for name, chunk, controlled in zip(names, (4, 1, 4), (False, False, True)):
        crowds[name] = Crowd(gen, chunk=chunk)
        for c in range(characters):
            ch = crowds[name].add(WALK, seed=c)
            if controlled:
                ch.follow_path(smooth_path(rng, 1.3, 120.0), speed=1.3)

    def run(name: str, n: int) -> float:
        def counted(emb, *args):
            rows[name].append(len(emb))
            return step(emb, *args)
        gen.backend.step_in_place = counted
        try:
            t = time.perf_counter()
            for _ in range(n):
                crowds[name].tick()
            return time.perf_counter() - t
        finally:
            del gen.backend.step_in_place           # the generator's backend, shared by the crowds

    def timed(n: int) -> dict:
        for name in names:
            rows[name].clear()
        rounds = {name: [] for name in names}
        for _ in range(max(1, n // ROUND)):
            for name in names:
                rounds[name].append(run(name, ROUND))
        return {name: {"per_character_token_ms": 1e3 * float(np.median(rounds[name])) / ROUND / characters,
                       "step_rows_per_character_token": sum(rows[name]) / (len(rounds[name]) * ROUND * characters)}
                for name in names}
    for name in names:                              # warm: every context built, allocations made
        run(name, FRESH[0])
    fresh = timed(FRESH[1] - FRESH[0])
    for name in names:
        run(name, STEADY - FRESH[1])
    steady = timed(ticks)
    out: dict = {name: {"fresh": fresh[name], "steady": steady[name],
                        "restarts_per_character_minute": sum(c.restarts for c in crowds[name].characters) / characters
                        / ((STEADY + ticks) * gen.dims.downsample / gen.dims.fps / 60)} for name in names}
    for phase in ("fresh", "steady"):
        ms = {name: out[name][phase]["per_character_token_ms"] for name in names}
        out[f"controlled_over_free_{phase}"] = ms["controlled"] / ms["free_chunk4"]
        out[f"controlled_over_free_chunk1_{phase}"] = ms["controlled"] / ms["free_chunk1"]
    return {"characters": characters, "ticks": ticks, **out}


# ---------------------------------------------------------------------------------------------------- main

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bundle")
    ap.add_argument("--variant", default="int8")
    ap.add_argument("--data", type=Path, default=Path("data/procedural"))
    ap.add_argument("--classifier", type=Path, default=None,
                    help="the action classifier (default: trained once into outputs/control_bench/)")
    ap.add_argument("--paths", type=int, default=200)
    ap.add_argument("--waypoints", type=int, default=100)
    ap.add_argument("--game-root", type=int, default=20)
    ap.add_argument("--text", type=int, default=40)
    ap.add_argument("--crowd", type=int, default=64)
    ap.add_argument("--ticks", type=int, default=160, help="ticks timed per crowd in the cost section's steady phase")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sections", default="paths,waypoints,game_root,feet,text,cost")
    ap.add_argument("--json", type=Path, default=Path("outputs/control.json"))
    args = ap.parse_args(argv)
    from mogo_runtime import MotionGenerator

    gen = MotionGenerator(args.bundle, variant=args.variant, threads=1)
    if gen.backend.control is None:
        raise SystemExit(f"{args.bundle}: its model has no control (no 'control' section in the manifest)")
    want = set(args.sections.split(","))
    report: dict = {"bundle": args.bundle, "variant": args.variant, "seed": args.seed}
    t0 = time.perf_counter()
    if "paths" in want or "feet" in want:
        report["paths"] = paths(gen, args.paths, args.seed)
    if "waypoints" in want:
        report["waypoints"] = waypoints(gen, args.waypoints, args.seed, walking_speed(args.data))
    if "game_root" in want or "feet" in want:
        report["game_root"] = game_root(gen, args.game_root, args.seed)
    if "feet" in want:
        toes = (gen.skeleton.foot_left[1], gen.skeleton.foot_right[1])
        report["feet"] = feet(report["paths"]["_motions"], report["game_root"]["_motions"], args.data,
                              gen.dims.fps, toes)
    if "text" in want:
        classifier = args.classifier
        if classifier is None:
            from mogo_eval.quality import train_classifier

            out = Path("outputs/control_bench")
            out.mkdir(parents=True, exist_ok=True)
            classifier = train_classifier(args.data, out)
        report["text"] = text_rules(gen, args.text, args.seed, args.data, classifier)
    if "cost" in want:
        report["cost"] = cost(args.bundle, args.crowd, args.ticks, args.seed)
    for section in ("paths", "game_root"):
        report.get(section, {}).pop("_motions", None)
    report["seconds"] = time.perf_counter() - t0
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
