"""Target rigs: the skeletons game characters are animated on, as data (a JSON file per rig).

    rig = load_rig("mixamo")              # one of RIGS, shipped in mogo_runtime/rigs/
    rig = load_rig("my_character.json")   # or a file of your own, same format (docs/rigs.md)

A rig file lists bones, parents first: a name, the parent's name (null for the one root), the bone's head in the
rest pose (world metres, y up, the character faces +z and its left is +x, the soles on y = 0) and, for the bones that
follow the motion, `source`: the HumanML3D joint at the same place on the body. Bones without a source (a UE5 `root`,
extra spine bones, end bones) keep their rest pose relative to their parent. `bone_axis` says how each bone's own
axes sit in the rest pose, as the rig ships: "none" = aligned with the world (VRM 1.0, Unity Humanoid), "y" = local +y
along the bone (Mixamo, Blender), "x" = local +x along the bone (Unreal); each bone's roll is the smallest turn from
its parent's axes. `root_motion_bone` names a bone above the hips that carries the ground path (Unreal's root motion).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from ..checks import Fields, kind, read_file, shown
from ..kinematics.quaternion import unit
from ..kinematics.skeleton import HUMANML3D, children_of, depth_first, is_ancestor, rest_positions
from .ik import min_rotation

RIG_FORMAT = "mogo-rig/1"
RIGS_DIR = Path(__file__).parent / "rigs"     # the game rigs' files; humanml3d is built from its skeleton
RIGS = ("humanml3d", "mixamo", "ue5", "unity", "vrm")
DEFAULT_RIG = "humanml3d"   # what a .glb gets when no rig is named
BONE_AXES = {"none": None, "x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
MAX_BONES = 1024
MAX_FILE_BYTES = 1 << 20
FOOT_HEIGHT = 0.05   # metres from the floor to HumanML3D's ankle and toe joints at rest
FOOT_SOURCES = ("left_ankle", "right_ankle", "left_foot", "right_foot")
# The bones a retarget cannot do without: the root (hips), both legs (the target's leg length scales the path) and
# both feet (ankles and toes: the lowest stands on the floor, a planted toe is held).
REQUIRED_SOURCES = ("pelvis", "left_hip", "right_hip", "left_knee", "right_knee", *FOOT_SOURCES)


class RigError(ValueError):
    """A rig file that cannot be used: the message names the file and the field."""


@dataclass(frozen=True)
class Rig:
    name: str
    description: str
    rest_pose: str                      # "T" or "A", as the rig ships (for people; the heads say it exactly)
    bone_names: tuple[str, ...]
    parents: tuple[int, ...]            # parent index per bone, -1 for the root
    heads: np.ndarray                   # (B, 3) rest-pose head of each bone, world metres
    sources: tuple[int, ...]            # HumanML3D joint index each bone follows, -1 for none
    bone_axis: str = "none"
    root_motion_bone: int = -1          # -1: the hips carry the whole path
    where: str = field(default="", compare=False)

    @property
    def num_bones(self) -> int:
        return len(self.parents)

    @cached_property
    def children(self) -> list[list[int]]:
        return children_of(self.parents)

    @cached_property
    def order(self) -> list[int]:
        return depth_first(self.parents)

    @cached_property
    def hips(self) -> int:
        return self.sources.index(HUMANML3D.root)

    def bone(self, source_joint: str) -> int:
        """The bone that follows HumanML3D joint `source_joint`."""
        return self.sources.index(HUMANML3D.joint_names.index(source_joint))

    @cached_property
    def spans(self) -> list[list[int]]:
        """For each bone that follows a joint, the nearest bones below it that follow joints too (one per branch,
        children in file order): the rest vectors the retarget turns onto the source's bones."""
        out = [[] for _ in self.parents]
        for b in range(self.num_bones):
            if self.sources[b] < 0:
                continue
            stack = list(reversed(self.children[b]))
            while stack:
                c = stack.pop()
                if self.sources[c] >= 0:
                    out[b].append(c)
                else:
                    stack.extend(reversed(self.children[c]))
        return out

    @cached_property
    def rest_rotations(self) -> np.ndarray:
        """(B, 3, 3) world orientation of each bone's axes in the rest pose (see `bone_axis`)."""
        rot = np.tile(np.eye(3), (self.num_bones, 1, 1))
        axis = BONE_AXES[self.bone_axis]
        if axis is None:
            return rot
        for b in self.order:
            p = self.parents[b]
            parent = rot[p] if p >= 0 else np.eye(3)
            along = self.heads[self.children[b][0]] - self.heads[b] if self.children[b] else \
                self.heads[b] - self.heads[p] if p >= 0 else parent @ axis
            rot[b] = min_rotation((parent @ axis)[None], unit(along, fallback=np.array([0.0, 1.0, 0.0]))[None])[0] @ parent
        return rot

    @cached_property
    def rest_local(self) -> tuple[np.ndarray, np.ndarray]:
        """(translations (B, 3), rotations (B, 3, 3)) of each bone relative to its parent's axes, at rest."""
        t, r = self.heads.copy(), self.rest_rotations.copy()
        for b, p in enumerate(self.parents):
            if p >= 0:
                t[b] = self.rest_rotations[p].T @ (self.heads[b] - self.heads[p])
                r[b] = self.rest_rotations[p].T @ self.rest_rotations[b]
        return t, r

    @cached_property
    def tails(self) -> np.ndarray:
        """(B, 3) where each bone ends at rest, for drawing: its first child's head; a leaf continues its parent's
        direction for half the parent's length."""
        tails = self.heads.copy()
        for b, p in enumerate(self.parents):
            if self.children[b]:
                tails[b] = self.heads[self.children[b][0]]
            elif p >= 0:
                tails[b] = self.heads[b] + 0.5 * (self.heads[b] - self.heads[p])
        return tails

    @cached_property
    def floor_height(self) -> float:
        """Rest height of the lowest foot bone (ankle or toe): where it sits when a foot stands on the floor."""
        return float(min(self.heads[self.bone(s), 1] for s in FOOT_SOURCES))

    def to_dict(self) -> dict:
        return {"format": RIG_FORMAT, "name": self.name, "description": self.description, "rest_pose": self.rest_pose,
                "bone_axis": self.bone_axis,
                "root_motion_bone": self.bone_names[self.root_motion_bone] if self.root_motion_bone >= 0 else None,
                "bones": [{"name": n, "parent": self.bone_names[p] if p >= 0 else None,
                           "head": [round(float(v), 6) for v in h],
                           **({"source": HUMANML3D.joint_names[s]} if s >= 0 else {})}
                          for n, p, h, s in zip(self.bone_names, self.parents, self.heads, self.sources)]}


def load_rig(rig: "str | Path | Rig") -> Rig:
    """A shipped rig by name (RIGS), or a rig file (a path ending in .json). Raises RigError naming the problem."""
    if isinstance(rig, Rig):
        return rig
    text = str(rig)
    if text == HUMANML3D.name:
        return rig_from_dict(humanml3d_rig(), text)
    if text in RIGS:
        path = RIGS_DIR / f"{text}.json"
    elif text.lower().endswith(".json"):
        path = Path(text)
    else:
        raise RigError(f"unknown rig {text!r}: give one of {', '.join(RIGS)} or a rig file ending in .json")
    try:        # a rig file is a user's: a link to it is fine, a device, a pipe or a huge file is not
        data = json.loads(read_file(path, MAX_FILE_BYTES, error=RigError))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise RigError(f"{path}: not a JSON rig file ({type(e).__name__}: {shown(str(e), 200)})") from None
    return rig_from_dict(data, str(path))


def humanml3d_rig() -> dict:
    """HumanML3D's own skeleton (kinematics.skeleton.HUMANML3D, the one description of that body) as a rig file:
    every joint a bone, heads at its rest pose with the lowest joints FOOT_HEIGHT above the floor, to 0.1 mm."""
    s = HUMANML3D
    rest = rest_positions(s.offsets, s.parents)
    heads = np.round(rest + [0.0, FOOT_HEIGHT - rest[:, 1].min(), 0.0], 4) + 0.0      # + 0.0: no -0.0 in files
    return {"format": RIG_FORMAT, "name": s.name, "rest_pose": "T", "bone_axis": "none", "root_motion_bone": None,
            "description": "HumanML3D's own 22-joint skeleton (SMPL joint names), T-pose, bone lengths of the dataset's "
                           "skeleton: the default rig of .glb files, for viewers and for engines that retarget "
                           "themselves.",
            "bones": [{"name": n, "parent": s.joint_names[p] if p >= 0 else None, "head": h.tolist(), "source": n}
                      for n, p, h in zip(s.joint_names, s.parents, heads)]}


def rig_from_dict(data, where: str = "rig") -> Rig:
    """Check a rig description (the JSON file's content) and build the Rig; RigError names the field."""
    f = Fields(data, where, error=RigError)
    if f.get("format") != RIG_FORMAT:
        f.fail("format", f"expected {RIG_FORMAT!r}, got {f.get('format')!r}")
    bone_axis = f.get("bone_axis", "none")
    if not isinstance(bone_axis, str) or bone_axis not in BONE_AXES:
        f.fail("bone_axis", f"expected one of {', '.join(map(repr, BONE_AXES))}, got {bone_axis!r}")
    rest_pose = f.str("rest_pose", "T")
    bones = f.list("bones")
    if not 1 <= len(bones) <= MAX_BONES:
        f.fail("bones", f"expected 1 to {MAX_BONES} bones, got {len(bones)}")
    names, parents, heads, sources = [], [], [], []
    joint_index = {n: j for j, n in enumerate(HUMANML3D.joint_names)}
    for i, b in enumerate(bones):
        bf = Fields(b, where, f"bones[{i}]", RigError)
        name = bf.str("name")
        if name in names:
            bf.fail("name", f"{name!r} is used twice")
        parent = bf.get("parent", None)
        if parent is None:
            if -1 in parents:
                bf.fail("parent", f"null, but {names[parents.index(-1)]!r} is already the root; a rig has one root")
            parents.append(-1)
        elif not isinstance(parent, str) or parent not in names:
            bf.fail("parent", f"{parent!r} is not a bone listed before this one (parents come first)")
        else:
            parents.append(names.index(parent))
        head = bf.get("head")
        if not (isinstance(head, list) and len(head) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= 100 for v in head)):
            bf.fail("head", f"expected [x, y, z] in metres (|v| <= 100), got {head!r}")
        source = bf.get("source", None)
        if source is not None and (not isinstance(source, str) or source not in joint_index):
            bf.fail("source", f"{source!r} is not a HumanML3D joint; known: {', '.join(HUMANML3D.joint_names)}")
        if source is not None and joint_index[source] in sources:
            bf.fail("source", f"{source!r} is followed by bone {names[sources.index(joint_index[source])]!r} too")
        names.append(name)
        heads.append([float(v) for v in head])
        sources.append(joint_index[source] if source is not None else -1)
    if -1 not in parents:
        f.fail("bones", "no root: exactly one bone must have parent null")
    missing = [s for s in REQUIRED_SOURCES if joint_index[s] not in sources]
    if missing:
        f.fail("bones", f"no bone follows {', '.join(missing)}: a rig needs the hips, both legs and both feet "
                        f"(ankles and toes)")
    root_motion = f.get("root_motion_bone", None)
    description = f.get("description", "")
    if not isinstance(description, str):
        f.fail("description", f"expected a string, got {kind(description)}")
    rig = Rig(name=f.str("name"), description=description, rest_pose=rest_pose, bone_names=tuple(names),
              parents=tuple(parents), heads=np.array(heads), sources=tuple(sources), bone_axis=bone_axis, where=where)
    if root_motion is not None:
        if root_motion not in names:
            f.fail("root_motion_bone", f"{root_motion!r} is not a bone of this rig")
        r = names.index(root_motion)
        if not is_ancestor(rig.parents, r, rig.hips):
            f.fail("root_motion_bone", f"{root_motion!r} must be above the hips bone "
                                       f"{names[rig.hips]!r} in the hierarchy")
        rig = replace(rig, root_motion_bone=r)
    _check_tree(rig, f)
    return rig


def _check_tree(rig: Rig, f: Fields) -> None:
    """The bones that follow joints keep HumanML3D's tree: a followed bone's nearest followed ancestor follows an
    ancestor of its joint (a left hand under a right shoulder would tear the body apart)."""
    src_parents = HUMANML3D.parents
    for b in range(rig.num_bones):
        s = rig.sources[b]
        if s < 0:
            continue
        a = rig.parents[b]
        while a >= 0 and rig.sources[a] < 0:
            a = rig.parents[a]
        if a < 0 and s != HUMANML3D.root:
            f.fail(f"bones[{b}].source", f"bone {rig.bone_names[b]!r} follows {HUMANML3D.joint_names[s]!r} but no bone "
                                         f"above it follows a joint (only the hips bone may)")
        if a >= 0 and not is_ancestor(src_parents, rig.sources[a], s):
            f.fail(f"bones[{b}].source", f"bone {rig.bone_names[b]!r} follows {HUMANML3D.joint_names[s]!r}, which is "
                                         f"not below {HUMANML3D.joint_names[rig.sources[a]]!r} (followed by "
                                         f"{rig.bone_names[a]!r}, the bone above it)")
        if a >= 0 and np.linalg.norm(rig.heads[b] - rig.heads[a]) < 1e-4:
            f.fail(f"bones[{b}].head", f"bone {rig.bone_names[b]!r} sits on {rig.bone_names[a]!r}: the bone between "
                                       f"them has no length, so it has no direction to follow")
