"""Retargeting onto game rigs: rig files checked field by field, bone directions and root path kept, feet on the
floor, and the .glb / .bvh files read back by independent code (pygltflib + our own FK from the file's numbers;
bvhio) give the same bone positions. Real Blender and three.js read the same files in tests/tools."""
import copy
import json

import bvhio
import numpy as np
import pygltflib
import pytest

from mogo_runtime import Motion
from mogo_runtime.kinematics.quaternion import quaternion_to_matrix
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.outputs.gltf import glb_bytes
from mogo_runtime.outputs.retarget import CONTACT_HEIGHT, PLANT_MAX_DEG, PLANT_MAX_HIPS_M, retarget
from mogo_runtime.outputs.rig import RIGS, RigError, load_rig, rig_from_dict

GAME_RIGS = [r for r in RIGS if r != "humanml3d"]
DIRECTION_TOL_DEG = 2.0
ROOT_TOL_M = 0.01


@pytest.fixture(scope="module")
def clip(humanml3d_fixture):
    return np.load(humanml3d_fixture / "new_joints" / "012314.npy").astype(np.float64)


def chain_direction_errors(anim, joints) -> np.ndarray:
    """Degrees between each rig span (a followed bone to the next followed bone, on a chain) and the source bone it
    follows, per frame: (T, spans)."""
    rig, out = anim.rig, []
    for b, spans in enumerate(rig.spans):
        if len(spans) == 1:
            c = spans[0]
            u = anim.positions[:, c] - anim.positions[:, b]
            v = joints[:, rig.sources[c]] - joints[:, rig.sources[b]]
            cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
            out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.stack(out, -1)


# ------------------------------------------------------------------------------------------------ rig files

def test_every_shipped_rig_loads_and_round_trips_through_its_json():
    for name in RIGS:
        rig = load_rig(name)
        again = rig_from_dict(json.loads(json.dumps(rig.to_dict())), name)
        assert again.bone_names == rig.bone_names and again.parents == rig.parents
        assert np.allclose(again.heads, rig.heads) and again.sources == rig.sources
        # the rest rotations are rotations, and put the bone axis along the bone where the rig says so
        r = rig.rest_rotations
        assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-12)
        assert np.allclose(np.linalg.det(r), 1.0)
    ue5 = load_rig("ue5")
    b = ue5.bone("left_knee")
    along = ue5.heads[ue5.children[b][0]] - ue5.heads[b]
    assert np.allclose(ue5.rest_rotations[b] @ [1, 0, 0], along / np.linalg.norm(along))


def _mixamo() -> dict:
    return copy.deepcopy(load_rig("mixamo").to_dict())


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.update(format="mogo-rig/0"), "field format: expected 'mogo-rig/1'"),
    (lambda d: d.update(bone_axis="w"), "field bone_axis"),
    (lambda d: d["bones"][1].update(name=d["bones"][0]["name"]), "is used twice"),
    (lambda d: d["bones"][1].update(parent="nobody"), "bones[1].parent: 'nobody' is not a bone listed before"),
    (lambda d: d["bones"][1].update(parent=None), "a rig has one root"),
    (lambda d: d["bones"][1].update(head=[0, 1]), "bones[1].head: expected [x, y, z]"),
    (lambda d: d["bones"][1].update(head=[0, float("nan"), 0]), "bones[1].head"),
    (lambda d: d["bones"][1].update(source="tail"), "'tail' is not a HumanML3D joint"),
    (lambda d: d["bones"][1].update(source="pelvis"), "is followed by bone"),
    (lambda d: [b.pop("source", None) for b in d["bones"] if b.get("source") == "left_knee"], "follows left_knee"),
    (lambda d: d.update(root_motion_bone="mixamorig:Spine"), "must be above the hips bone"),
    (lambda d: d.update(bones=[]), "expected 1 to 1024 bones"),
    (lambda d: d.update(bones="x"), "field bones: expected a list"),
])
def test_a_bad_rig_file_is_refused_naming_the_field(tmp_path, edit, message):
    data = _mixamo()
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(RigError, match=message.replace("[", r"\[").replace("]", r"\]")) as e:
        load_rig(str(path))
    assert str(path) in str(e.value)


def test_a_rig_that_tears_the_body_apart_is_refused(tmp_path):
    data = _mixamo()
    for b in data["bones"]:   # the left hand under the right forearm
        if b["name"] == "mixamorig:LeftHand":
            b["parent"] = "mixamorig:RightForeArm"
    data["bones"].sort(key=lambda b: b["name"].startswith("mixamorig:LeftHand"))   # parents still first
    with pytest.raises(RigError, match="not below 'right_elbow'"):
        rig_from_dict(data, "torn.json")


def test_unreadable_rig_files_say_why(tmp_path):
    with pytest.raises(RigError, match="unknown rig 'fbx'"):
        load_rig("fbx")
    with pytest.raises(RigError, match="missing.json: cannot read it"):
        load_rig(str(tmp_path / "missing.json"))
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(RigError, match="not a JSON rig file"):
        load_rig(str(tmp_path / "junk.json"))
    (tmp_path / "big.json").write_bytes(b" " * (2 << 20))
    with pytest.raises(RigError, match="big.json: more than 1,048,576 bytes"):
        load_rig(str(tmp_path / "big.json"))


def test_a_users_own_rig_file_drives_the_retarget(tmp_path, clip):
    data = _mixamo()
    data["name"] = "my_hero"
    for b in data["bones"]:   # another naming scheme, longer legs
        b["name"] = b["name"].replace("mixamorig:", "hero_")
        b["parent"] = b["parent"] and b["parent"].replace("mixamorig:", "hero_")
        b["head"] = [1.1 * v for v in b["head"]]
    path = tmp_path / "hero.json"
    path.write_text(json.dumps(data))
    anim = retarget(clip, str(path))
    assert anim.rig.bone_names[0] == "hero_Hips"
    assert anim.scale == pytest.approx(1.1 * retarget(clip, "mixamo").scale, rel=1e-9)
    assert chain_direction_errors(anim, clip).max() < DIRECTION_TOL_DEG


# ------------------------------------------------------------------------------------------------ retargeting

@pytest.mark.parametrize("rig", RIGS)
def test_bones_follow_the_source_and_the_root_path_is_scaled(clip, rig):
    anim = retarget(clip, rig)
    err = chain_direction_errors(anim, clip)
    hips = anim.positions[:, anim.rig.hips]
    path = (hips[:, [0, 2]] - anim.rig.heads[anim.rig.hips, [0, 2]]) / anim.scale
    root_err = np.abs(path - clip[:, 0, [0, 2]]).max()
    print(f"{rig}: scale {anim.scale:.3f}, worst bone direction {err.max():.3f} deg, ground path {root_err * 100:.2e} cm")
    assert err.max() < min(DIRECTION_TOL_DEG, PLANT_MAX_DEG + 0.1)
    assert root_err <= PLANT_MAX_HIPS_M + 1e-9 < ROOT_TOL_M       # planted feet may move the hips this much
    # limb lengths are the rig's, on every frame (the hips move freely under a root-motion bone)
    for b, p in enumerate(anim.rig.parents):
        if p >= 0 and b != anim.rig.hips:
            length = np.linalg.norm(anim.positions[:, b] - anim.positions[:, p], axis=-1)
            assert np.allclose(length, np.linalg.norm(anim.rig.heads[b] - anim.rig.heads[p]), atol=1e-9)


@pytest.mark.parametrize("rig", GAME_RIGS)
def test_feet_stay_on_the_floor_and_slide_no_more_than_the_source(clip, rig):
    anim = retarget(clip, rig)
    r, k = anim.rig, anim.scale
    feet = [r.bone(f) for f in ("left_ankle", "right_ankle", "left_foot", "right_foot")]
    lowest = anim.positions[:, feet, 1].min(1)
    assert np.allclose(lowest - r.floor_height, k * clip[:, [7, 8, 10, 11], 1].min(1), atol=1e-9)
    src_toes, rig_toes = clip[:, [10, 11]], anim.positions[:, [r.bone("left_foot"), r.bone("right_foot")]]
    src, rig_ = skating_frames(src_toes, src_toes, 1.0), skating_frames(rig_toes, src_toes, k)
    print(f"{rig}: frames where a planted toe slides: source {src}, rig {rig_} (of {len(clip) - 1})")
    assert rig_ <= src


def skating_frames(toes, source_toes, scale) -> int:
    """mogo_eval's skating measure (a toe below CONTACT_HEIGHT at both frames moving more than 2.5 cm), on the
    source's contact frames, distances divided by the rig's scale."""
    planted = (source_toes[:-1, :, 1] < CONTACT_HEIGHT) & (source_toes[1:, :, 1] < CONTACT_HEIGHT)
    step = np.linalg.norm(np.diff(toes[..., [0, 2]], axis=0), axis=-1) / scale
    return int((planted & (step > 0.025)).any(-1).sum())


def test_in_place_drops_the_ground_path_and_keeps_the_turning(clip):
    anim, moving = retarget(clip, "vrm", in_place=True), retarget(clip, "vrm")
    hips = anim.positions[:, anim.rig.hips]
    assert np.abs(hips[:, [0, 2]] - anim.rig.heads[anim.rig.hips, [0, 2]]).max() < 1e-12
    assert np.allclose(anim.world_rotations[:, anim.rig.hips], moving.world_rotations[:, anim.rig.hips])
    assert np.ptp(moving.positions[:, moving.rig.hips, 2]) > 0.3      # the clip does travel


def test_root_motion_rides_on_the_unreal_root_bone(clip):
    anim = retarget(clip, "ue5")
    root, hips = anim.rig.root_motion_bone, anim.rig.hips
    assert anim.rig.bone_names[root] == "root"
    assert np.allclose(anim.positions[:, root, 1], 0.0)
    assert np.allclose(anim.positions[:, root, [0, 2]], anim.positions[:, hips, [0, 2]] - anim.rig.heads[hips, [0, 2]])
    assert sorted(anim.moving_bones) == sorted([root, hips])
    still = retarget(clip, "ue5", in_place=True)
    assert np.allclose(still.positions[:, root], 0.0)


def test_retarget_refuses_what_it_cannot_do(clip):
    from mogo_runtime.kinematics.skeleton import KIT
    with pytest.raises(ValueError, match="HumanML3D's 22-joint skeleton"):
        retarget(np.zeros((4, 21, 3)), "mixamo", skeleton=KIT)
    with pytest.raises(ValueError, match=r"shape \(T, 22, 3\)"):
        retarget(clip[:, :20], "mixamo")
    bad = clip.copy()
    bad[3, 5, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        retarget(bad, "mixamo")
    with pytest.raises(ValueError, match="in_place must be True or False"):
        retarget(clip, "mixamo", in_place="yes")


# ------------------------------------------------------------------------------------------------ files

def glb_positions(data: bytes) -> tuple[list[str], np.ndarray]:
    """Every joint node's world position per animation key, by forward kinematics from the file's own numbers."""
    doc = pygltflib.GLTF2.load_from_bytes(data)
    blob = doc.binary_blob()

    def read(i):
        a = doc.accessors[i]
        view = doc.bufferViews[a.bufferView]
        n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
        return np.frombuffer(blob, np.float32, a.count * n, view.byteOffset + (a.byteOffset or 0)).reshape(a.count, n)

    joints = doc.skins[0].joints
    anim = doc.animations[0]
    T = doc.accessors[anim.samplers[0].input].count
    rot = {j: np.tile(doc.nodes[j].rotation or [0, 0, 0, 1], (T, 1)) for j in joints}
    trans = {j: np.tile(doc.nodes[j].translation or [0, 0, 0], (T, 1)) for j in joints}
    for ch in anim.channels:
        (rot if ch.target.path == "rotation" else trans)[ch.target.node] = read(anim.samplers[ch.sampler].output)
    parent = {c: i for i, n in enumerate(doc.nodes) for c in n.children}
    world_r, world_t = {}, {}

    def solve(j):
        if j in world_r:
            return
        q = rot[j].astype(np.float64)
        r = quaternion_to_matrix(q[:, [3, 0, 1, 2]])
        p = parent.get(j)
        if p in rot:
            solve(p)
            world_r[j] = world_r[p] @ r
            world_t[j] = world_t[p] + np.einsum("tij,tj->ti", world_r[p], trans[j])
        else:
            assert p is None or not (doc.nodes[p].rotation or doc.nodes[p].translation)   # the Armature: identity
            world_r[j], world_t[j] = r, trans[j].astype(np.float64)

    for j in joints:
        solve(j)
    return [doc.nodes[j].name for j in joints], np.stack([world_t[j] for j in joints], 1)


@pytest.mark.parametrize("rig", RIGS)
def test_glb_file_reproduces_the_retarget(clip, rig):
    anim = retarget(clip, rig)
    names, pos = glb_positions(glb_bytes(anim, "fixture"))
    assert names == list(anim.rig.bone_names)
    err = np.abs(pos - anim.positions).max()
    print(f"{rig}: .glb forward kinematics vs the retarget: {err * 1000:.4f} mm")
    assert err < 1e-4     # float32 in the file


@pytest.mark.parametrize("rig", ["mixamo", "ue5"])
def test_rig_bvh_read_by_bvhio_reproduces_the_retarget(tmp_path, clip, rig):
    anim = retarget(clip, rig)
    path = tmp_path / f"{rig}.bvh"
    path.write_text(anim.to_bvh_text())
    root = bvhio.readAsHierarchy(str(path))
    layout = {j.Name: j for j, _, _ in root.layout()}
    written = [n for b, n in enumerate(anim.rig.bone_names) if b != anim.rig.root_motion_bone]   # BVH moves its root only
    assert sorted(layout) == sorted(written)
    worst = 0.0
    for f in range(anim.num_frames):
        root.loadPose(f)
        for b, name in enumerate(anim.rig.bone_names):
            if name not in layout:
                continue
            v = layout[name].PositionWorld
            worst = max(worst, float(np.abs(np.array([v.x, v.y, v.z]) / 100.0 - anim.positions[f, b]).max()))
    print(f"{rig}: .bvh read by bvhio vs the retarget: {worst * 1000:.4f} mm")
    assert worst < 1e-4


def test_motion_save_writes_rigs_and_refuses_a_rig_where_none_applies(tmp_path, clip):
    m = Motion("a person walks", np.zeros((len(clip), 263)), clip, 20.0, np.zeros((len(clip) // 4, 6)), HUMANML3D, 3)
    glb = m.save(tmp_path / "walk.glb", rig="unity", in_place=True)
    doc = pygltflib.GLTF2.load_from_bytes(glb.read_bytes())
    assert doc.extras["rig"] == "unity" and doc.extras["in_place"] is True and doc.extras["text"] == "a person walks"
    assert [n.name for n in doc.nodes][:2] == ["Hips", "Spine"]
    default = pygltflib.GLTF2.load_from_bytes(m.save(tmp_path / "plain.glb").read_bytes())
    assert default.extras["rig"] == "humanml3d"
    text = m.save(tmp_path / "walk.bvh", rig="ue5").read_text()
    assert "ROOT pelvis" in text and "JOINT spine_01" in text and " root" not in text
    for bad in ("walk.gif", "walk.npy", "walk.json"):
        with pytest.raises(ValueError, match="apply to .bvh and .glb files"):
            m.save(tmp_path / bad, rig="mixamo")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.glb", "walk.bvh", "walk.glb"]


@pytest.mark.parametrize("rig", ["mixamo", "ue5"])
def test_chain_ends_keep_their_rest_pose_on_their_parent(clip, rig):
    """A hand follows nothing in the source (HumanML3D's wrists end their chains), so it stays as it is at rest
    relative to the bone above it: a hand in line with its forearm stays in line."""
    anim = retarget(clip, rig)
    r = anim.rig
    end = r.bone("left_wrist")
    assert not r.spans[end]
    p = r.parents[end]
    rest = r.rest_rotations[p].T @ r.rest_rotations[end]
    local = np.swapaxes(anim.world_rotations[:, p], -1, -2) @ anim.world_rotations[:, end]
    assert np.abs(local - rest).max() < 1e-9


@pytest.mark.parametrize("rig", ["mixamo", "ue5", "vrm"])
def test_the_head_stays_in_line_with_the_chest(clip, rig):
    """HumanML3D's head joint sits ahead of its neck, so the rig's neck leans forward as the source's does; the head
    bone is kept upright with the chest (plus the neck's bend from its mean), not tipped by that lean."""
    anim = retarget(clip, rig)
    r = anim.rig
    head = r.bone("head")
    top = r.children[head][0] if r.children[head] else None
    up = (anim.world_rotations[:, head] @ np.linalg.inv(r.rest_rotations[head]))   # the head's turn from rest
    rest_dir = (r.heads[top] - r.heads[head]) if top is not None else np.array([0.0, 1.0, 0.0])
    d = up @ (rest_dir / np.linalg.norm(rest_dir))
    lean = np.degrees(np.arccos(np.clip(d[:, 1], -1, 1)))
    def lean_of(a, b):
        v = anim.positions[:, b] - anim.positions[:, a]
        return np.degrees(np.arccos(v[:, 1] / np.linalg.norm(v, axis=-1)))

    chest, neck = r.bone("spine3"), r.bone("neck")
    body, neck_lean = lean_of(chest, neck), lean_of(neck, head)
    print(f"{rig}: from vertical, median: head {np.median(lean):.1f} deg, chest {np.median(body):.1f}, "
          f"neck bone {np.median(neck_lean):.1f}")
    assert np.median(np.abs(lean - body)) < 10 and np.median(neck_lean - body) > 25
