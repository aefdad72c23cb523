"""Retargeting: a HumanML3D motion (joint positions) onto a game rig (rig.py), as rotations from the rig's rest pose.

    anim = retarget(motion.joints, load_rig("mixamo"), fps=motion.fps)          # or motion.save("x.glb", rig=...)
    anim.local_rotations, anim.local_translations                                # what a glTF or BVH file stores

How, per frame:
1. Inverse kinematics on the source (ik.local_rotations) gives each HumanML3D joint's turn from its rest pose (T-pose,
   facing +z), twist included: the same rotations the BVH writer stores.
2. Every rig bone that follows a joint takes that joint's turn, first corrected for how the two rest poses differ (an
   A-pose arm is swung up onto the T-pose arm), then swung the last bit so the rig's bone points exactly where the
   source bone points. A bone with several followed bones below it (hips, chest) takes the best-fit turn of all of
   them. Bones that follow nothing keep their rest pose relative to their parent. Limb lengths stay the rig's.
3. The hips follow the source's pelvis, scaled by the ratio of the two legs (thigh plus shin), so strides fit the
   rig's legs and a foot on the source's floor (y = 0) lands on the rig's floor; with
   `in_place` the horizontal path is dropped (turning stays). A rig with a root-motion bone carries the path on it.
4. A planted source toe is held on the rig (_plant_feet): the leg swings a little about the hip, and the hips move
   at most PLANT_MAX_HIPS_M off the scaled path; then the body rises or sinks so the lowest foot is on the floor.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics.quaternion import unit
from ..checks import check_fps
from ..kinematics.skeleton import HUMANML3D, Skeleton, is_ancestor, rest_positions
from .bvh import rotations_to_bvh_text
from .ik import axis_angle, kabsch, local_rotations, min_rotation, rest_offsets
from .rig import FOOT_SOURCES, Rig, load_rig

HEAD = HUMANML3D.joint_names.index("head")
CONTACT_HEIGHT = 0.05       # m: a source toe below this is on the ground (mogo_eval's skating measure too)
PLANT_MAX_DEG = 1.9         # the most a leg is swung to keep a planted foot in place (bone directions stay within it)
PLANT_MAX_HIPS_M = 0.009    # ... and the most the hips move off the source's path for it (scaled: within 1 cm)
PLANT_RELEASE_S = 0.25      # time constant of the swing fading out once the foot lifts


@dataclass
class RigMotion:
    """A motion on a rig: every bone's world orientation and position per frame (metres, y up)."""
    rig: Rig
    fps: float
    world_rotations: np.ndarray     # (T, B, 3, 3) each bone's axes in the world (its rest orientation included)
    positions: np.ndarray           # (T, B, 3) each bone's head in the world
    scale: float                    # rig hip height / source hip height: source path * scale = rig path
    in_place: bool = False

    @property
    def num_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def local_rotations(self) -> np.ndarray:
        """(T, B, 3, 3) each bone's rotation in its parent's axes (the root's in the world's): glTF node rotations."""
        out = self.world_rotations.copy()
        for b, p in enumerate(self.rig.parents):
            if p >= 0:
                out[:, b] = np.swapaxes(self.world_rotations[:, p], -1, -2) @ self.world_rotations[:, b]
        return out

    @property
    def local_translations(self) -> np.ndarray:
        """(T, B, 3) each bone's head in its parent's axes (the root's in the world): glTF node translations."""
        out = self.positions.copy()
        for b, p in enumerate(self.rig.parents):
            if p >= 0:
                out[:, b] = np.einsum("tji,tj->ti", self.world_rotations[:, p], self.positions[:, b] - self.positions[:, p])
        return out

    @property
    def moving_bones(self) -> list[int]:
        """Bones whose translation changes over the motion (the hips; the root-motion bone): the rest only turn."""
        rest_t, _ = self.rig.rest_local
        moved = np.abs(self.local_translations - rest_t[None]).max(axis=0).max(axis=-1) > 1e-7
        return [b for b in range(self.rig.num_bones) if moved[b] or b == self.rig.hips]

    def to_bvh_text(self, units: str = "cm") -> str:
        """BVH of the rig: its bone names and rest pose (BVH has no rest orientations, so every joint's channels
        are its turn from the rest pose, in its parent's turned axes). BVH moves only its root, so the hips are the
        root and bones above them (a root-motion bone) are left out."""
        rig = self.rig
        keep = [b for b in rig.order if is_ancestor(rig.parents, rig.hips, b)]
        index = {b: i for i, b in enumerate(keep)}
        parents = [index.get(rig.parents[b], -1) for b in keep]
        delta = self.world_rotations[:, keep] @ np.swapaxes(rig.rest_rotations[keep], -1, -2)[None]  # turn from rest
        local = delta.copy()
        for i, p in enumerate(parents):
            if p >= 0:
                local[:, i] = np.swapaxes(delta[:, p], -1, -2) @ delta[:, i]
        offsets = np.array([rig.heads[b] - rig.heads[keep[p]] if p >= 0 else np.zeros(3) for b, p in zip(keep, parents)])
        return rotations_to_bvh_text([rig.bone_names[b] for b in keep], parents, offsets, self.positions[:, rig.hips],
                                     local, self.fps, units, what=f"rig {rig.name!r}")


def retarget(joints, rig: "Rig | str", fps: float = 20.0, in_place: bool = False,
             skeleton: Skeleton = HUMANML3D) -> RigMotion:
    """`joints` (T, 22, 3) HumanML3D positions in metres -> the same motion on `rig` (a Rig, a shipped rig's name or
    a rig file). See the module docstring for what is kept."""
    rig = load_rig(rig)
    if skeleton.name != HUMANML3D.name:
        raise ValueError(f"retargeting reads HumanML3D's 22-joint skeleton; this motion is on {skeleton.name!r}")
    if not isinstance(in_place, bool):
        raise ValueError(f"in_place must be True or False, got {in_place!r}")
    fps = check_fps(fps)
    pos = skeleton.check_joints(joints, "joints")
    offsets = rest_offsets(pos, skeleton)
    src_turn = _world_turns(local_rotations(pos, skeleton, offsets, fps), skeleton.parents)    # (T, J, 3, 3)
    src_rest = rest_positions(offsets, skeleton.parents)                                      # pelvis at 0

    T, B = len(pos), rig.num_bones
    turn = np.zeros((T, B, 3, 3))
    for b in rig.order:
        s, p, spans = rig.sources[b], rig.parents[b], rig.spans[b]
        if s == HEAD and not spans:
            turn[:, b] = _upright_head(rig, turn, b)
        elif s < 0 or not spans:      # follows nothing, or ends a chain (hands, toes: the source's ends have no turn
            turn[:, b] = turn[:, p] if p >= 0 else np.eye(3)     # of their own): keeps its rest pose on its parent
        elif len(spans) == 1:
            c = spans[0]
            rest_rig = unit(rig.heads[c] - rig.heads[b])
            rest_src = unit(src_rest[rig.sources[c]] - src_rest[s])
            base = src_turn[:, s] @ min_rotation(rest_rig[None], rest_src[None])[0]
            seen = unit(pos[:, rig.sources[c]] - pos[:, s])
            turn[:, b] = min_rotation(base @ rest_rig, seen) @ base
        else:
            rest_rig = unit(rig.heads[spans] - rig.heads[b])                              # (k, 3)
            seen = unit(pos[:, [rig.sources[c] for c in spans]] - pos[:, None, s])         # (T, k, 3)
            turn[:, b] = kabsch(rest_rig[None], seen)

    legs = [[f"{side}_{j}" for j in ("hip", "knee", "ankle")] for side in ("left", "right")]
    scale = _leg_length(rig.heads, [[rig.bone(j) for j in leg] for leg in legs]) / \
        _leg_length(src_rest, [[skeleton.joint_names.index(j) for j in leg] for leg in legs])
    # HumanML3D's floor is y = 0, where the lowest foot joint touches it; the rig's lowest foot bone touches its floor
    # at its rest height.
    hips = scale * pos[:, skeleton.root] + [rig.heads[rig.hips, 0], rig.floor_height, rig.heads[rig.hips, 2]]
    if in_place:
        hips[:, [0, 2]] = rig.heads[rig.hips, [0, 2]]

    if not in_place:
        _plant_feet(rig, turn, hips, pos, scale, fps)
    # The lowest foot joint stands as high above the rig's floor as the source's above its own (scaled), so a foot
    # on the floor there is on the floor here: the hips rise or sink by the difference the rig's other proportions
    # make (a few centimetres at most).
    src_feet = [skeleton.joint_names.index(f) for f in FOOT_SOURCES]
    rig_feet = [rig.bone(f) for f in FOOT_SOURCES]
    hips[:, 1] += rig.floor_height + scale * pos[:, src_feet, 1].min(1) - _forward(rig, turn, hips)[:, rig_feet, 1].min(1)
    positions = _forward(rig, turn, hips)
    return RigMotion(rig=rig, fps=fps, world_rotations=turn @ rig.rest_rotations[None], positions=positions,
                     scale=float(scale), in_place=in_place)


def _upright_head(rig: Rig, turn: np.ndarray, head: int) -> np.ndarray:
    """The head bone's turn when it ends its chain. HumanML3D's head joint sits ahead of its neck (38 to 62 degrees
    from vertical on an upright person), so the rig's neck bone, which points where the source's neck points, leans
    forward that much even when the person stands straight; a head bone kept on it would look at the floor. The head
    keeps its rest pose on the chest instead, turned by the neck's bend from its mean over the motion: nods and head
    turns stay, the standing lean does not."""
    neck = rig.parents[head]
    while rig.sources[neck] < 0:
        neck = rig.parents[neck]
    chest = rig.parents[neck]
    while chest >= 0 and rig.sources[chest] < 0:
        chest = rig.parents[chest]
    base = turn[:, chest] if chest >= 0 else np.broadcast_to(np.eye(3), turn[:, neck].shape)
    bend = np.swapaxes(base, -1, -2) @ turn[:, neck]                                   # (T, 3, 3)
    u, _, vt = np.linalg.svd(bend.mean(0))                                              # the mean rotation
    mean = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return turn[:, neck] @ mean.T


def _plant_feet(rig: Rig, turn: np.ndarray, hips: np.ndarray, pos: np.ndarray, scale: float, fps: float) -> None:
    """While a source toe is on the ground, keep the rig's toe moving over the ground as the source's does (scaled):
    the rig's other proportions (hip width, foot length) would otherwise slide it a few millimetres a frame. Each leg
    swings about its hip (at most PLANT_MAX_DEG) and what that cannot reach moves the hips (at most PLANT_MAX_HIPS_M
    off the scaled path). Once a foot lifts, its swing fades out, and so does the hips' move when no foot is planted
    (PLANT_RELEASE_S). Changes `turn` and `hips` in place."""
    positions = _forward(rig, turn, hips)
    release = float(np.exp(-1.0 / (fps * PLANT_RELEASE_S)))
    limit = np.radians(PLANT_MAX_DEG)
    legs = [(rig.bone(f"{side}_hip"), rig.bone(f"{side}_foot"), pos[:, HUMANML3D.joint_names.index(f"{side}_foot")])
            for side in ("left", "right")]
    swing = np.zeros((len(legs), len(pos), 3))                   # rotation vectors, per leg and frame
    shift = np.zeros((len(pos), 3))                              # the hips' move off the scaled path
    current, moved = np.zeros((len(legs), 3)), np.zeros(3)
    anchors: list = [None] * len(legs)
    for t in range(len(pos)):
        current *= release
        moved *= release
        residual = []
        for i, (hip, toe, src_toe) in enumerate(legs):
            h, v = positions[t, hip] + moved, positions[t, toe] - positions[t, hip]
            if src_toe[t, 1] < CONTACT_HEIGHT:
                if anchors[i] is None:
                    anchors[i] = (h + _rotvec(current[i][None])[0] @ v, src_toe[t])
                goal = anchors[i][0] + scale * (src_toe[t] - anchors[i][1])
                goal[1] = h[1] + v[1]
                current[i] = _rotvec_between(v, goal - h, limit)
                residual.append((goal - h - _rotvec(current[i][None])[0] @ v) * [1.0, 0.0, 1.0])
            else:
                anchors[i] = None
            swing[i, t] = current[i]
        if residual:
            moved = moved + np.mean(residual, axis=0)
            norm = np.linalg.norm(moved)
            if norm > PLANT_MAX_HIPS_M * scale:          # the bound is on the path scaled back to the source's
                moved *= PLANT_MAX_HIPS_M * scale / norm
        shift[t] = moved
    for (hip, _, _), rotvecs in zip(legs, swing):
        rot = _rotvec(rotvecs)
        for b in range(rig.num_bones):
            if is_ancestor(rig.parents, hip, b):
                turn[:, b] = rot @ turn[:, b]
    hips += shift


def _rotvec_between(a: np.ndarray, b: np.ndarray, limit: float) -> np.ndarray:
    """The rotation vector of the smallest turn from direction a to direction b, at most `limit` radians."""
    axis = np.cross(a, b)
    sin, cos = np.linalg.norm(axis), float(a @ b)
    if sin < 1e-12:
        return np.zeros(3)
    return axis / sin * min(np.arctan2(sin, cos), limit)


def _rotvec(v: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors -> (N, 3, 3) matrices."""
    angle = np.linalg.norm(v, axis=-1)
    axis = np.where(angle[:, None] > 1e-12, v / np.maximum(angle, 1e-300)[:, None], [1.0, 0.0, 0.0])
    return axis_angle(axis, angle)


def _forward(rig: Rig, turn: np.ndarray, hips: np.ndarray) -> np.ndarray:
    """(T, B, 3) bone heads from each bone's turn from its rest pose and the hips' path."""
    positions = np.zeros(turn.shape[:2] + (3,))
    for b in rig.order:
        p = rig.parents[b]
        if b == rig.hips:
            positions[:, b] = hips
        elif b == rig.root_motion_bone:
            positions[:, b] = rig.heads[b]
            positions[:, b, [0, 2]] += hips[:, [0, 2]] - rig.heads[rig.hips, [0, 2]]
        elif p < 0:
            positions[:, b] = rig.heads[b]
        else:
            positions[:, b] = positions[:, p] + turn[:, p] @ (rig.heads[b] - rig.heads[p])
    return positions


def _world_turns(local: np.ndarray, parents) -> np.ndarray:
    out = local.copy()
    for j, p in enumerate(parents):   # HumanML3D lists parents before children
        if p >= 0:
            out[:, j] = out[:, p] @ local[:, j]
    return out


def _leg_length(heads: np.ndarray, legs: list[list[int]]) -> float:
    """Thigh plus shin, mean of the two legs: how far a stride reaches (the pelvis and the feet differ more between
    rigs than legs do, and a planted foot slides by the difference in leg length times the angle the leg sweeps)."""
    return float(np.mean([sum(np.linalg.norm(heads[b] - heads[a]) for a, b in zip(leg, leg[1:])) for leg in legs]))
