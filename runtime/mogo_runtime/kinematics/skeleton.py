"""The skeletons that motion features describe: HumanML3D (22 joints) and KIT-ML (21 joints).

A `Skeleton` is a tree of joints with a rest-pose offset per bone. Every HumanML3D clip is retargeted to
one skeleton, so its bone lengths are facts of the dataset: the numbers below were measured on the real
clip `012314` (spread over its 170 frames < 3e-7 m) and a test re-measures them from the fixture.
Directions follow HumanML3D's `t2m_raw_offsets` (y up, the body faces +z in the rest pose).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Skeleton:
    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]            # parent index per joint, -1 for the root
    kinematic_chain: tuple[tuple[int, ...], ...]  # HumanML3D-style chains, root first
    raw_offsets: np.ndarray             # (J, 3) unit direction of each bone in the rest pose
    bone_lengths: np.ndarray            # (J, 3) metres, 0 for the root
    foot_right: tuple[int, int]         # (ankle, toe) joints used for foot contact
    foot_left: tuple[int, int]
    face_joints: tuple[int, int, int, int]  # right hip, left hip, right shoulder, left shoulder
    fps: float = 20.0

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def offsets(self) -> np.ndarray:
        """(J, 3) rest-pose bone vectors: direction times length."""
        return self.raw_offsets * self.bone_lengths[:, None]

    @property
    def children(self) -> list[list[int]]:
        return children_of(self.parents)

    @property
    def root(self) -> int:
        roots = [j for j, p in enumerate(self.parents) if p < 0]
        if len(roots) != 1:
            raise ValueError(f"skeleton {self.name!r} must have exactly one root, has {len(roots)}")
        return roots[0]

    def depth_first(self) -> list[int]:
        """Every joint, parents before children: depth first from the root, children in joint order."""
        return depth_first(self.parents)

    def check_joints(self, joints, what: str = "joints", count: bool = False) -> np.ndarray:
        """`joints` (T, J, 3) in metres as float64, or a ValueError naming the problem (with `count`: how many
        joint positions are not finite)."""
        try:
            pos = np.asarray(joints, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise ValueError(f"{what} must be a numeric array of shape (T, J, 3): {e}") from None
        J = self.num_joints
        if pos.ndim != 3 or pos.shape[1:] != (J, 3) or pos.shape[0] < 1:
            raise ValueError(f"{what} must have shape (T, {J}, 3) for skeleton {self.name!r} "
                             f"(T >= 1 frames, metres), got {pos.shape}")
        bad = ~np.isfinite(pos)
        if bad.any():
            t, j, _ = np.argwhere(bad)[0]
            n = f" ({int(bad.any(-1).sum())} joint positions)" if count else ""
            raise ValueError(f"{what} contain NaN or inf{n}, first at frame {t} joint {j} ({self.joint_names[j]})")
        return pos

    def to_dict(self) -> dict:
        """JSON-friendly description, as stored in bundle manifests and motion files."""
        return {"name": self.name, "joint_names": list(self.joint_names), "parents": list(self.parents),
                "offsets": np.round(self.offsets, 6).tolist(), "fps": self.fps, "up_axis": "y", "units": "m"}


def children_of(parents) -> list[list[int]]:
    """Each joint's children, in joint order, from the parent index of every joint (-1 for the root)."""
    return [[j for j, p in enumerate(parents) if p == i] for i in range(len(parents))]


def depth_first(parents) -> list[int]:
    """Every joint reachable from the (first) root, parents before children, children in joint order."""
    children, order, stack = children_of(parents), [], [list(parents).index(-1)]
    while stack:
        order.append(stack.pop())
        stack.extend(reversed(children[order[-1]]))
    return order


def rest_positions(offsets: np.ndarray, parents) -> np.ndarray:
    """(J, 3) joint positions of a rest pose from each joint's offset to its parent (J, 3), the root at the origin."""
    out = np.zeros_like(offsets)
    for j in depth_first(parents)[1:]:
        out[j] = out[parents[j]] + offsets[j]
    return out


def is_ancestor(parents, a: int, b: int) -> bool:
    """Joint a is joint b or above it, in a tree given by each joint's parent index (-1 for the root)."""
    while b >= 0:
        if b == a:
            return True
        b = parents[b]
    return False


def _parents_from_chains(num_joints: int, chains) -> tuple[int, ...]:
    parents = [-1] * num_joints
    for chain in chains:
        for a, b in zip(chain[:-1], chain[1:]):
            parents[b] = a
    return tuple(parents)


_T2M_CHAIN = ((0, 2, 5, 8, 11), (0, 1, 4, 7, 10), (0, 3, 6, 9, 12, 15), (9, 14, 17, 19, 21), (9, 13, 16, 18, 20))
_T2M_RAW = np.array([
    [0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, -1, 0], [0, 1, 0], [0, -1, 0],
    [0, -1, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, 1],
    [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0]], dtype=np.float64)
# Measured on HumanML3D clip 012314 (see module docstring).
_T2M_LENGTHS = np.array([
    0.0, 0.103074, 0.109883, 0.131568, 0.393623, 0.390188, 0.14319, 0.432433, 0.425643, 0.057365,
    0.143382, 0.149419, 0.21936, 0.137487, 0.143383, 0.103039, 0.131614, 0.122984, 0.25684, 0.263092,
    0.266012, 0.269876])

HUMANML3D = Skeleton(
    name="humanml3d",
    joint_names=("pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
                 "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
                 "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist"),
    parents=_parents_from_chains(22, _T2M_CHAIN), kinematic_chain=_T2M_CHAIN, raw_offsets=_T2M_RAW,
    bone_lengths=_T2M_LENGTHS, foot_right=(8, 11), foot_left=(7, 10), face_joints=(2, 1, 17, 16))

_KIT_CHAIN = ((0, 11, 12, 13, 14, 15), (0, 16, 17, 18, 19, 20), (0, 1, 2, 3, 4), (3, 5, 6, 7), (3, 8, 9, 10))
_KIT_RAW = np.array([
    [0, 0, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, -1, 0], [0, -1, 0],
    [-1, 0, 0], [0, -1, 0], [0, -1, 0], [1, 0, 0], [0, -1, 0], [0, -1, 0], [0, 0, 1], [0, 0, 1],
    [-1, 0, 0], [0, -1, 0], [0, -1, 0], [0, 0, 1], [0, 0, 1]], dtype=np.float64)
# KIT-ML clips are not available here, so these lengths (metres) are anthropometric estimates for the
# KIT layout, not measurements; a user with the dataset should re-measure them as the HumanML3D test does.
_KIT_LENGTHS = np.array([
    0.0, 0.10, 0.12, 0.16, 0.20, 0.18, 0.28, 0.25, 0.18, 0.28, 0.25, 0.10, 0.42, 0.40, 0.06, 0.12,
    0.10, 0.42, 0.40, 0.06, 0.12])

KIT = Skeleton(
    name="kit", joint_names=("root", "bp", "bt", "bln", "bun", "ls", "le", "lw", "rs", "re", "rw", "lh", "lk", "la",
                             "lmrot", "lf", "rh", "rk", "ra", "rmrot", "rf"),
    parents=_parents_from_chains(21, _KIT_CHAIN), kinematic_chain=_KIT_CHAIN, raw_offsets=_KIT_RAW,
    bone_lengths=_KIT_LENGTHS, foot_right=(14, 15), foot_left=(19, 20), face_joints=(11, 16, 5, 8), fps=12.5)

SKELETONS = {s.name: s for s in (HUMANML3D, KIT)}


def get_skeleton(name: str) -> Skeleton:
    try:
        return SKELETONS[name]
    except KeyError:
        raise ValueError(f"unknown skeleton {name!r}; known: {sorted(SKELETONS)}") from None
