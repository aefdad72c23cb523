"""Behaviour snapshot: what a bundle gives a user, saved once and compared bit for bit later.

A refactor of the runtime must change nothing a user gets. Before it, save what the bundle produces; after it,
compare:

    python -m benchmarks.snapshot save    bundles/base /tmp/before.npz
    python -m benchmarks.snapshot compare bundles/base /tmp/before.npz     # exit 1 on any difference

What it covers (each motion generated alone unless stated; ~1,000 motions and files on a base bundle):
- clips: 20 prompts x 3 seeds, fp32 and int8, greedy and sampled (the bundle's sampling defaults), with and
  without `align` (TCA);
- every other variant the bundle has (portable, int8_fixed, ORT formats): 20 prompts, greedy and sampled;
- batches: 6 prompts in one `generate` call per variant, greedy and sampled;
- endless (bundles trained for streams): a 30 s timeline of three prompts, and a stream that switches prompt at
  set tokens, per variant and seed;
- crowds (fixed-capacity variants): 6 characters joining at different ticks, switching prompts, leaving after
  `seconds` or removed, under the bundle's sampling and greedy; and `mogo crowd`'s files;
- control (bundles with control): steered characters in crowds (fixed-capacity variants, chunk 4 and 1: a path, a
  goal, a joystick with strafing, a game-owned root moved every tick, a release and a prompt switch under control)
  and in streams (fp32, int8, fixed-capacity variants);
- files: a clip and a timeline saved as .npy, .json, .bvh, .gif and .glb, and as .glb and .bvh on every shipped
  rig (also in place): their bytes.
`--only` picks sections. The "clips" section also runs against the API of the runtime before issue 13 (keyword
sampling arguments), so a "before" file can be written by an old tree.
"""
from __future__ import annotations

import argparse
import inspect
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PROMPTS = (
    "a person walks forward",
    "a person waves with the right hand",
    "a person walks forward and then jumps",
    "someone squats down slowly",
    "a man kicks with his left leg",
    "a person jumps in place twice",
    "a person turns around to the left",
    "the person claps their hands",
    "a person bows",
    "a person runs forward quickly",
    "a person sits down on a chair",
    "a person punches with the right hand",
    "someone walks backwards",
    "a person sidesteps to the right",
    "a person raises both arms above the head",
    "a man walks in a circle",
    "yo make the dude do a lil hop",
    "can you have him wave 👋 with his left hand then bow",
    "A PERSON STANDS STILL.",
    "she jumps forward, and after that she turns right",
)
SEEDS = (0, 1, 7)
TIMELINE = [("a person walks forward", 0.0), ("a person turns left", 10.0), ("a person waves with the right hand",
                                                                            20.0)]
# a stream: (token, new prompt) switches, and how many frames are kept
STREAM_SWITCHES = ((7, "a person jumps in place"), (30, "a person turns left"), (31, "someone squats down slowly"))
STREAM_FRAMES = 400
# a crowd: (prompt, seed, tick it joins at, seconds or None, (token, new prompt) or None, tick it is removed at)
CROWD = [(PROMPTS[0], 1, 0, None, (9, PROMPTS[6]), None), (PROMPTS[1], 2, 0, 6.0, None, None),
         (PROMPTS[5], 3, 3, None, None, 40), (PROMPTS[4], 7, 5, 4.0, None, None),
         (PROMPTS[6], 11, 2, None, (17, PROMPTS[1]), None), (PROMPTS[0], 2 ** 63 - 1, 1, None, None, None)]
CROWD_TICKS = 90
SECTIONS = ("clips", "variants", "batches", "endless", "crowds", "control", "files")
# steered characters (bundles with control): (request, its arguments, the tick a crowd's character gets it at; a
# stream gets it before its first frame); set_root is sent again every tick after
CONTROL = [("follow_path", ([(0.0, 0.0), (2.0, 1.0), (5.0, 1.0), (5.0, -3.0)], 1.3), 0),
           ("walk_to", ((4.0, 2.0), 1.0), 0), ("steer", ((0.0, 1.4), (1.0, 0.0)), 1),
           ("walk_to", ((-3.0, -2.0), 2.5), 2), ("set_root", None, 0),
           ("follow_path", ([(0.0, 0.0), (0.0, 3.0)], 0.8), 4)]
CONTROL_TICKS = 70


def _generate(gen, text, seed: int, greedy: bool, align: bool):
    params = inspect.signature(gen.generate).parameters
    if "sampling" in params:  # the API since issue 13: one SamplingConfig
        from mogo_runtime import SamplingConfig

        sampling = SamplingConfig(temperature=0.0) if greedy else None
        return gen.generate(text, seed=seed, sampling=sampling, align=align)
    return gen.generate(text, seed=seed, temperature=0.0 if greedy else None, align=align)


def _put(out: dict, key: str, m) -> None:
    out[key + "/tokens"] = np.asarray(m.tokens)
    out[key + "/features"] = np.asarray(m.features)
    out[key + "/joints"] = np.asarray(m.joints)


def clips(bundle: str, out: dict) -> None:
    from mogo_runtime import MotionGenerator

    for variant in ("fp32", "int8"):
        gen = MotionGenerator(bundle, variant=variant, threads=1)
        for mode in ("greedy", "sampled"):
            for align in (False, True):
                for i, text in enumerate(PROMPTS):
                    for seed in SEEDS:
                        _put(out, f"{variant}/{mode}/{'align' if align else 'raw'}/p{i:02d}/s{seed}",
                             _generate(gen, text, seed, mode == "greedy", align))


def _others(bundle: str) -> list[str]:
    from mogo_runtime import Bundle

    return [v for v in Bundle.load(bundle).variants if v not in ("fp32", "int8")]


def _fixed(bundle: str) -> list[str]:
    return [v for v in _others(bundle) if v in ("portable", "int8_fixed")]


def variants(bundle: str, out: dict) -> None:
    from mogo_runtime import MotionGenerator

    for variant in _others(bundle):
        gen = MotionGenerator(bundle, variant=variant, threads=1)
        for mode in ("greedy", "sampled"):
            for i, text in enumerate(PROMPTS):
                _put(out, f"variants/{variant}/{mode}/p{i:02d}", _generate(gen, text, 0, mode == "greedy", False))


def batches(bundle: str, out: dict) -> None:
    from mogo_runtime import MotionGenerator

    for variant in ("fp32", "int8", *_others(bundle)):
        gen = MotionGenerator(bundle, variant=variant, threads=1)
        for mode in ("greedy", "sampled"):
            motions = _generate(gen, list(PROMPTS[:6]), 5, mode == "greedy", False)
            for i, m in enumerate(motions):
                _put(out, f"batches/{variant}/{mode}/p{i:02d}", m)
            if gen.endless:      # fixed lengths run the endless loop, a batch of streams
                from mogo_runtime import SamplingConfig

                sampling = SamplingConfig(temperature=0.0) if mode == "greedy" else None
                motions = gen.generate(list(PROMPTS[6:10]), seconds=12, seed=3, sampling=sampling)
                for i, m in enumerate(motions):
                    _put(out, f"batches/{variant}/{mode}/fixed/p{i:02d}", m)


def endless(bundle: str, out: dict) -> None:
    from mogo_runtime import MotionGenerator

    for variant in ("fp32", "int8", *_fixed(bundle)):
        gen = MotionGenerator(bundle, variant=variant, threads=1)
        if not gen.endless:
            return
        for seed in (1, 2):
            _put(out, f"endless/{variant}/timeline/s{seed}", gen.generate(TIMELINE, seconds=30, seed=seed))
            for chunk in (1, 4):
                stream = gen.stream(PROMPTS[0], seed=seed, chunk=chunk)
                switches = list(STREAM_SWITCHES)
                features, joints, events = [], [], []
                for frame in stream:
                    features.append(frame.features)
                    joints.append(frame.joints)
                    if switches and stream.tokens >= switches[0][0]:    # at the first frame from that token on
                        events.append((stream.tokens, frame.index))
                        stream.set_prompt(switches.pop(0)[1])
                    if len(joints) == STREAM_FRAMES:
                        break
                stream.close()
                key = f"endless/{variant}/stream/c{chunk}/s{seed}"
                out[key + "/features"], out[key + "/joints"] = np.stack(features), np.stack(joints)
                out[key + "/switches"] = np.array(events, np.int64)


def crowds(bundle: str, out: dict) -> None:
    from mogo_runtime import MotionGenerator, SamplingConfig
    from mogo_runtime.crowd import Crowd

    for variant in _fixed(bundle):
        gen = MotionGenerator(bundle, variant=variant, threads=1)
        if not gen.endless:
            return
        for mode, sampling in (("defaults", None), ("greedy", SamplingConfig(temperature=0.0))):
            crowd = Crowd(gen, sampling=sampling)
            chars, parts = {}, {}
            for t in range(CROWD_TICKS):
                for i, (prompt, seed, start, seconds, _, leave) in enumerate(CROWD):
                    if t == start:
                        chars[i], parts[i] = crowd.add(prompt, seed=seed, seconds=seconds), []
                    if t == leave and chars[i] in crowd.characters:
                        crowd.remove(chars[i])
                row = {c: i for i, c in chars.items()}
                for c, frames in crowd.tick().items():
                    parts[row[c]].append((frames.index, frames.features, frames.joints))
                for i, c in chars.items():
                    switch = CROWD[i][4]
                    if switch and c.count == switch[0] and c in crowd.characters:
                        c.set_prompt(switch[1])
            for i, p in parts.items():
                key = f"crowds/{variant}/{mode}/c{i}"
                out[key + "/index"] = np.array([index for index, _, _ in p], np.int64)
                out[key + "/features"] = np.concatenate([f for _, f, _ in p])
                out[key + "/joints"] = np.concatenate([j for _, _, j in p])
                out[key + "/restarts"] = np.array(chars[i].restarts)
        with tempfile.TemporaryDirectory() as tmp:
            from mogo_runtime.cli import main

            rc = main(["crowd", PROMPTS[0], PROMPTS[1], PROMPTS[5], "-n", "5", "--seconds", "4", "--seed", "3",
                       "--bundle", bundle, "--variant", variant, "-o", tmp])
            assert rc == 0, f"mogo crowd failed ({rc})"
            for f in sorted(Path(tmp).iterdir()):
                out[f"crowds/{variant}/cli/{f.name}"] = np.frombuffer(f.read_bytes(), np.uint8)


def _request(character, request, tick: int) -> None:
    name, args = request
    if name == "set_root":      # a game moving the capsule on a circle, placing it every tick
        a = 0.05 * tick
        character.set_root(2.0 * np.sin(a), 2.0 - 2.0 * np.cos(a), a + np.pi / 2)
    else:
        getattr(character, name)(*args)


def control(bundle: str, out: dict) -> None:
    """Steered characters in crowds (every fixed-capacity variant, chunk 4 and 1) and in streams (fp32, int8): paths,
    goals, a joystick with strafing, a game-owned root, a release, a prompt switch under control."""
    from mogo_runtime import MotionGenerator
    from mogo_runtime.crowd import Crowd

    for variant in ("fp32", "int8", *_fixed(bundle)):
        gen = MotionGenerator(bundle, variant=variant, threads=1)
        if gen.backend.control is None:
            return
        if variant in _fixed(bundle):
            for chunk in (4, 1):
                crowd = Crowd(gen, chunk=chunk)
                chars = [crowd.add(PROMPTS[0] if i % 3 else PROMPTS[9], seed=i) for i in range(len(CONTROL))]
                parts: dict[int, list] = {i: [] for i in range(len(chars))}
                for t in range(CONTROL_TICKS):
                    for c, (name, args, start) in zip(chars, CONTROL):
                        if t == start or (name == "set_root" and t > start):
                            _request(c, (name, args), t)
                    if t == 40:
                        chars[1].set_prompt(PROMPTS[1])
                        chars[2].release()
                    for c, frames in crowd.tick().items():
                        parts[chars.index(c)].append((frames.index, frames.features, frames.joints))
                for i, p in parts.items():
                    key = f"control/{variant}/crowd/c{chunk}/{i}"
                    out[key + "/index"] = np.array([index for index, _, _ in p], np.int64)
                    out[key + "/features"] = np.concatenate([f for _, f, _ in p])
                    out[key + "/joints"] = np.concatenate([j for _, _, j in p])
        for i, (name, args, _) in enumerate(CONTROL[:4]):
            stream = gen.stream(PROMPTS[0], seed=i)
            _request(stream, (name, args), 0)
            features, joints = [], []
            for frame in stream:
                features.append(frame.features)
                joints.append(frame.joints)
                if len(joints) == STREAM_FRAMES:
                    break
            stream.close()
            key = f"control/{variant}/stream/{i}"
            out[key + "/features"], out[key + "/joints"] = np.stack(features), np.stack(joints)


def files(bundle: str, out: dict) -> None:
    from mogo_runtime import MotionGenerator

    gen = MotionGenerator(bundle, variant="fp32", threads=1)
    motions = {"clip": gen.generate(PROMPTS[2], seed=1)}
    if gen.endless:
        motions["timeline"] = gen.generate(TIMELINE, seconds=30, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        for name, m in motions.items():
            written = [m.save(Path(tmp) / f"{name}{ext}") for ext in (".npy", ".json", ".bvh", ".gif", ".glb")]
            for rig in ("humanml3d", "mixamo", "ue5", "unity", "vrm"):
                for ext in (".glb", ".bvh"):
                    written.append(m.save(Path(tmp) / f"{name}_{rig}{ext}", rig=rig))
                written.append(m.save(Path(tmp) / f"{name}_{rig}_in_place.glb", rig=rig, in_place=True))
            for path in written:
                out[f"files/{path.name}"] = np.frombuffer(path.read_bytes(), np.uint8)


def snapshot(bundle: str, only=SECTIONS) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name in only:
        t0 = time.perf_counter()
        before = len(out)
        globals()[name](bundle, out)
        print(f"  {name}: {len(out) - before} arrays in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return out


def compare(before: dict[str, np.ndarray], after: dict[str, np.ndarray]) -> list[str]:
    problems = [f"{k}: missing after" for k in sorted(set(before) - set(after))]
    problems += [f"{k}: new after" for k in sorted(set(after) - set(before))]
    for k in sorted(set(before) & set(after)):
        a, b = before[k], after[k]
        if a.shape != b.shape or a.dtype != b.dtype:
            problems.append(f"{k}: {a.dtype}{a.shape} before, {b.dtype}{b.shape} after")
        elif a.tobytes() != b.tobytes():
            problems.append(f"{k}: values differ (max abs {np.abs(a.astype(np.float64) - b).max():.3g})")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["save", "compare"])
    ap.add_argument("bundle")
    ap.add_argument("file")
    ap.add_argument("--only", nargs="+", choices=SECTIONS, default=list(SECTIONS), help="sections to run")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    now = snapshot(args.bundle, args.only)
    return save_or_compare(args.mode, args.file, now, t0, lambda k: k.split("/")[0] in args.only or
                           ("clips" in args.only and k.split("/")[0] in ("fp32", "int8")))


def save_or_compare(mode: str, file: str, now: dict[str, np.ndarray], t0: float, keep=lambda key: True) -> int:
    """Save `now` to `file`, or compare it with the arrays `file` holds (those whose key `keep` accepts) and print
    what differs; the exit status (1: something differs). benchmarks/data_snapshot.py ends the same way."""
    if mode == "save":
        np.savez(file, **now)
        print(f"saved {len(now)} arrays to {file} in {time.perf_counter() - t0:.0f} s")
        return 0
    with np.load(file) as f:
        before = {k: f[k] for k in f.files if keep(k)}
    problems = compare(before, now)
    for p in problems[:40]:
        print(p)
    print(f"{len(now)} arrays compared in {time.perf_counter() - t0:.0f} s: "
          f"{'IDENTICAL' if not problems else f'{len(problems)} arrays differ'}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
