"""What the Python runtime gives, for the web page's browser test (web/test/page.test.mjs); run with the venv's python.

    python web/test/reference.py clips --out ref.json toy=/tmp/toy [base=bundles/base ...]
        tokens of CLIPS (prompt, seed, seconds) on every variant of each bundle, the bundle defaults' sampling
    python web/test/reference.py timeline BUNDLE VARIANT SEED TOKENS PROMPT SWITCH_TOKEN PROMPT2 < /dev/null
        tokens and joints of a stream that switched prompt at SWITCH_TOKEN (a timeline), as JSON on stdout
    python web/test/reference.py control BUNDLE VARIANT SEED FRAMES PROMPT FRAME X Z < /dev/null
        tokens and joints of FRAMES frames of a stream (the bundle's sampling, chunk 4, as the page's worker streams)
        that was sent walking to (X, Z) before frame FRAME was read, with the token it landed at, as JSON on stdout
    python web/test/reference.py files FPS < joints.json
        for joints {"joints": flat (T, J, 3), "frames": T}: runtime/mogo_runtime/bvh.py's text and the frames of
        Motion.save's .json (rounded as it rounds), as JSON {"bvh": ..., "json_frames": ...} on stdout
    python web/test/reference.py fixture
        outputs/bvh.py's text for the real HumanML3D test clip (tests/conftest.py: FIXTURES) (cm, 20 fps) and for a noisy copy of it
        (metres, 30 fps: every bone's direction jitters, some frames near the twist and gimbal cases), as JSON
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from mogo_runtime import MotionGenerator
from mogo_runtime.bundle.sections import WEIGHT_INT8
from mogo_runtime.outputs.bvh import joints_to_bvh_text
from mogo_runtime.outputs.motion import JSON_DECIMALS

# (prompt, seed, seconds): the model ends the first two; the third has a fixed length
CLIPS = [("a person walks forward", 1, None), ("a person jumps twice", 2, None),
         ("a person turns left and then kicks", 3, 3.0)]


def clips(out: Path, bundles: dict[str, str]) -> None:
    result = {"clips": [{"text": t, "seed": s, "seconds": sec} for t, s, sec in CLIPS], "bundles": {}}
    for name, path in bundles.items():
        manifest = json.loads((Path(path) / "manifest.json").read_text())
        per_variant = {}
        for variant in manifest["variants"]:
            gen = MotionGenerator(path, variant=variant, threads=1)
            per_variant[variant] = [gen.generate(t, seed=s, seconds=sec).tokens.tolist() for t, s, sec in CLIPS]
        result["bundles"][name] = {"path": str(Path(path).resolve()), "endless": "streaming" in manifest,
                                   "variants": list(manifest["variants"]), "downsample": manifest["model"]["downsample"],
                                   # graphs whose activations are quantized (dynamic int8): not held to exactness
                                   # in wasm on a real model; int8-stored weights (compact) compute in float32
                                   "quantized": {v: {g: bool(e.get("quantization"))
                                                     and e["quantization"]["method"] != WEIGHT_INT8
                                                     for g, e in graphs.items()}
                                                 for v, graphs in manifest["variants"].items()},
                                   "tokens": per_variant}
    out.write_text(json.dumps(result))


def timeline(bundle: str, variant: str, seed: int, tokens: int, prompt: str, switch: int, prompt2: str) -> dict:
    gen = MotionGenerator(bundle, variant=variant, threads=1)
    per_token = gen.dims.downsample / gen.dims.fps
    motion = gen.generate([(prompt, 0.0), (prompt2, switch * per_token)], seconds=tokens * per_token, seed=seed)
    return {"tokens": motion.tokens.tolist(), "joints": np.asarray(motion.joints, np.float32).ravel().tolist()}


def control(bundle: str, variant: str, seed: int, frames: int, prompt: str, frame: int, x: float, z: float) -> dict:
    gen = MotionGenerator(bundle, variant=variant, threads=1)
    stream = gen.stream(prompt, seed=seed)
    context, tokens, joints, landed = stream.steering.context, [], [], None
    for i in range(frames):
        if i == frame:
            stream.walk_to((x, z))
            landed = stream.tokens
        joints.append(next(stream).joints)
        tokens += [context.history[t % context.span].tolist() for t in range(len(tokens), context.count)]
    stream.close()
    return {"tokens": tokens, "landed": landed, "joints": np.asarray(joints, np.float32).ravel().tolist()}


def fixture() -> dict:
    clip = Path(__file__).resolve().parents[3] / "shared" / "fixtures" / "humanml3d" / "new_joints" / "012314.npy"
    joints = np.load(clip).astype(np.float64)
    noisy = joints + np.random.default_rng(0).normal(0.0, 0.03, joints.shape)
    cases = [("humanml3d-012314", joints, 20.0, "cm"), ("noisy", noisy, 30.0, "m")]
    return {"clip": str(clip), "cases": [
        {"name": name, "joints": j.ravel().tolist(), "frames": len(j), "fps": fps, "units": units,
         "bvh": joints_to_bvh_text(j, fps=fps, units=units)} for name, j, fps, units in cases]}


def main(argv: list[str]) -> int:
    cmd, args = argv[0], argv[1:]
    if cmd == "clips":
        out = Path(args[args.index("--out") + 1])
        bundles = dict(a.split("=", 1) for a in args if "=" in a)
        clips(out, bundles)
    elif cmd == "timeline":
        bundle, variant, seed, tokens, prompt, switch, prompt2 = args
        print(json.dumps(timeline(bundle, variant, int(seed), int(tokens), prompt, int(switch), prompt2)))
    elif cmd == "control":
        bundle, variant, seed, frames, prompt, frame, x, z = args
        print(json.dumps(control(bundle, variant, int(seed), int(frames), prompt, int(frame), float(x), float(z))))
    elif cmd == "files":
        data = json.load(sys.stdin)
        joints = np.asarray(data["joints"], np.float64).reshape(data["frames"], -1, 3)
        print(json.dumps({"bvh": joints_to_bvh_text(joints, fps=float(args[0])),
                          "json_frames": np.round(joints, JSON_DECIMALS).tolist()}))
    elif cmd == "fixture":
        print(json.dumps(fixture()))
    else:
        raise SystemExit(f"unknown command {cmd!r}; see the docstring")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
