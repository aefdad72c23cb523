"""The rigs' files in the tools people use: every .glb through Khronos's glTF validator and three.js's GLTFLoader
(Node), every .glb and a .bvh per rig through real Blender's importers (bpy). In each, every bone that follows the
motion points where the source bone points (within 2 degrees, every frame) and the hips' ground path is the source's
scaled (within 1 cm), on the real HumanML3D clip, a procedural clip of every family, and a motion generated from
each of those clips' captions by a trained bundle. Feet: no more sliding or floor penetration than the source. `make test-tools` runs this (run.sh
installs Blender and the npm packages); Blender's import is timed and printed.
"""
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from mogo_export.data.procedural.clips import generate_clip
from mogo_export.data.procedural.families import FAMILIES
from mogo_runtime import MotionGenerator
from mogo_runtime.outputs.gltf import write_glb
from mogo_runtime.outputs.retarget import CONTACT_HEIGHT, retarget
from mogo_runtime.outputs.rig import RIGS, load_rig

HERE = Path(__file__).resolve().parent
DIRECTION_TOL_DEG = 2.0
ROOT_TOL_M = 0.01
BVH_CLIPS = ("fixture", "walk_forward", "turn_left", "jump_forward")
TARGET_RIGS = ("mixamo", "ue5", "unity", "vrm")


@pytest.fixture(scope="session")
def clips(humanml3d_fixture, tiny_bundle) -> dict:
    """The real clip; per family, a procedural clip and a motion generated from its caption by a trained bundle
    ($MOGO_TOOLS_BUNDLE, e.g. bundles/base; default the tiny test bundle)."""
    out = {"fixture": np.load(humanml3d_fixture / "new_joints" / "012314.npy").astype(np.float64)}
    gen = MotionGenerator(os.environ.get("MOGO_TOOLS_BUNDLE") or tiny_bundle)
    for i, family in enumerate(FAMILIES):
        clip = generate_clip((family,), np.random.default_rng(1000 + i))
        out[family] = clip.joints.astype(np.float64)
        out[f"generated: {clip.captions[0]}"] = gen.generate(clip.captions[0], seed=i).joints.astype(np.float64)
    return out


@pytest.fixture(scope="session")
def written(tmp_path_factory, clips) -> dict:
    """{(rig, clip, ext): (path, RigMotion)}: a .glb of every clip on every rig, a .bvh of a few."""
    folder = tmp_path_factory.mktemp("rigs")
    out = {}
    for rig in RIGS:
        for n, (name, joints) in enumerate(clips.items()):
            anim = retarget(joints, rig)
            path = write_glb(folder / f"{rig}_{n:02d}.glb", anim, name=name)
            out[rig, name, ".glb"] = (path, anim)
            if name in BVH_CLIPS:
                path = folder / f"{rig}_{n:02d}.bvh"
                path.write_text(anim.to_bvh_text())
                out[rig, name, ".bvh"] = (path, anim)
    return out


RENDER = ("mixamo", "walk_forward", ".glb")     # Blender renders one frame of this one (test_blender_renders_...)


def _jobs(written, exts, folder: Path) -> Path:
    jobs = [{"file": str(p), "frames": a.num_frames, "fps": a.fps} for (_, _, e), (p, a) in written.items() if e in exts]
    for job in jobs:
        if job["file"] == str(written[RENDER][0]):
            job["render"] = {"frame": written[RENDER][1].num_frames // 2, "png": str(folder / "render.png")}
    path = folder / f"jobs{'_'.join(exts)}.json"
    path.write_text(json.dumps(jobs))
    return path


@pytest.fixture(scope="session")
def three_js(written, tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("three")
    out = folder / "out.json"
    subprocess.run(["node", str(HERE / "read_glb.mjs"), str(_jobs(written, (".glb",), folder)), str(out)],
                   check=True, cwd=HERE, timeout=600)
    return json.loads(out.read_text())


@pytest.fixture(scope="session")
def blender(written, tmp_path_factory) -> dict:
    python = os.environ.get("MOGO_BLENDER_PYTHON")
    if not python:
        raise RuntimeError("MOGO_BLENDER_PYTHON is not set: run these tests with `make test-tools`, which installs "
                           "Blender (bpy) into .venv-blender and sets it")
    folder = tmp_path_factory.mktemp("blender")
    out = folder / "out.json"
    subprocess.run([python, str(HERE / "blender_read.py"), str(_jobs(written, (".glb", ".bvh"), folder)), str(out)],
                   check=True, timeout=900, stdout=subprocess.DEVNULL)
    return {**json.loads(out.read_text()), "render.png": folder / "render.png"}


def _errors(read: dict, anim, joints, sanitise=lambda n: n) -> tuple[float, float]:
    """(worst bone direction error in degrees, worst ground-path error in metres) of an importer's bone positions."""
    rig = anim.rig
    index = {n: i for i, n in enumerate(read["names"])}
    # every bone is in the file, but a BVH (whose root is the hips) leaves a root-motion bone out
    assert sorted(index) == sorted(sanitise(n) for b, n in enumerate(rig.bone_names)
                                   if b != rig.root_motion_bone or not read.get("bvh"))
    read_pos = np.asarray(read["frames"], np.float64)
    pos = np.full(anim.positions.shape, np.nan)
    for b, n in enumerate(rig.bone_names):
        if sanitise(n) in index:
            pos[:, b] = read_pos[:, index[sanitise(n)]]
    worst = 0.0
    for b, spans in enumerate(rig.spans):
        if len(spans) == 1:
            c = spans[0]
            u, v = pos[:, c] - pos[:, b], joints[:, rig.sources[c]] - joints[:, rig.sources[b]]
            cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
            worst = max(worst, float(np.degrees(np.arccos(np.clip(cos, -1, 1))).max()))
    path = (pos[:, rig.hips, [0, 2]] - rig.heads[rig.hips, [0, 2]]) / anim.scale
    return worst, float(np.abs(path - joints[:, 0, [0, 2]]).max())


def _check(reader: str, reads: dict, written, clips, ext: str, sanitise=lambda n: n) -> None:
    rows = {}
    for (rig, name, e), (path, anim) in written.items():
        if e != ext:
            continue
        d, r = _errors({**reads[str(path)], "bvh": ext == ".bvh"}, anim, clips[name], sanitise)
        rows.setdefault(rig, []).append((d, r, name))
    for rig, errs in rows.items():
        d, r = max(errs)[0], max(e[1] for e in errs)
        print(f"{reader} {ext} {rig:9s}: {len(errs)} motions, worst bone direction {d:.3f} deg, worst ground path "
              f"{r * 100:.4f} cm")
        assert d < DIRECTION_TOL_DEG, max(errs)
        assert r < ROOT_TOL_M


def test_every_glb_is_valid_for_the_khronos_validator(three_js, written):
    for (rig, name, ext), (path, _) in written.items():
        if ext == ".glb":
            report = three_js[str(path)]["validator"]
            assert (report["errors"], report["warnings"]) == (0, 0), (rig, name, report["messages"])
    print(f"gltf-validator: {sum(e == '.glb' for _, _, e in written)} files, 0 errors, 0 warnings")


def test_three_js_plays_the_glb_as_retargeted(three_js, written, clips):
    # three.js strips ':' and other reserved characters from node names (mixamorig:Hips -> mixamorigHips)
    _check("three.js", three_js, written, clips, ".glb", lambda n: n.replace(":", ""))
    assert all(three_js[str(p)]["skinnedMeshes"] == 1 for (_, _, e), (p, _) in written.items() if e == ".glb")


def test_blender_imports_the_glb_as_retargeted(blender, written, clips):
    _check("Blender", blender, written, clips, ".glb")
    took = [blender[str(p)]["import_s"] for (_, _, e), (p, _) in written.items() if e == ".glb"]
    print(f"Blender glTF import: median {np.median(took) * 1000:.0f} ms per file")


def test_blender_imports_the_rig_bvh_as_retargeted(blender, written, clips):
    _check("Blender", blender, written, clips, ".bvh")


def test_blender_renders_the_figure(blender):
    """Blender's renderer (Workbench) draws the .glb's skinned figure: a Mixamo rig walking, one frame, 480x480."""
    from PIL import Image

    image = np.asarray(Image.open(blender["render.png"]).convert("L"), np.int16)
    background = np.median(np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]]))
    figure = np.abs(image - background) > 40
    rows, cols = np.flatnonzero(figure.any(1)), np.flatnonzero(figure.any(0))
    print(f"render: {figure.mean():.1%} of the pixels differ from the background, spanning {np.ptp(rows)} x "
          f"{np.ptp(cols)} px ({blender['render.png']})")
    assert figure.mean() > 0.005 and np.ptp(rows) > 150


def test_feet_slide_and_sink_no_more_than_the_source(clips):
    """Foot skating as mogo_eval measures it (a toe below 5 cm at both frames moving more than 2.5 cm), on the
    source's contact frames, with distances divided by the rig's scale (how far those low toes travel in all is
    printed too); and floor penetration (the lowest foot joint more than 1 cm below the floor). Pooled over every
    motion, per rig: no worse than the source's on the four game rigs. (The humanml3d rig, the default of a .glb
    without --rig, is printed too: on the CI motions it slides 1 frame more, at one lift-off of the real clip.)"""
    def slides(toes, planted_toes, scale) -> tuple[int, float]:
        planted = (planted_toes[:-1, :, 1] < CONTACT_HEIGHT) & (planted_toes[1:, :, 1] < CONTACT_HEIGHT)
        step = np.linalg.norm(np.diff(toes[..., [0, 2]], axis=0), axis=-1) / scale
        return int((planted & (step > 0.025)).any(-1).sum()), float(step[planted].sum())

    worse = []
    for rig_name in RIGS:
        rig = load_rig(rig_name)
        feet = [rig.bone(f) for f in ("left_ankle", "right_ankle", "left_foot", "right_foot")]
        totals = np.zeros(6)
        for name, joints in clips.items():
            anim = retarget(joints, rig)
            src_toes = joints[:, [10, 11]]
            p_src = int((joints[:, [7, 8, 10, 11], 1].min(1) < -0.01).sum())
            p_rig = int(((anim.positions[:, feet, 1].min(1) - rig.floor_height) / anim.scale < -0.01).sum())
            totals += (*slides(src_toes, src_toes, 1.0), *slides(anim.positions[:, feet[2:]], src_toes, anim.scale),
                       p_src, p_rig)
        n_src, d_src, n_rig, d_rig, p_src, p_rig = totals
        print(f"{rig_name:9s}: sliding frames source {n_src:.0f}, rig {n_rig:.0f}; toes below 5 cm travel {d_src:.2f} m, "
              f"rig {d_rig:.2f} m (scaled); frames below the floor source {p_src:.0f}, rig {p_rig:.0f} "
              f"({len(clips)} motions)")
        if not (n_rig <= n_src and p_rig <= p_src) and rig_name in TARGET_RIGS:
            worse.append(rig_name)
    assert not worse, f"the feet slide or sink more than the source's on {worse}"
