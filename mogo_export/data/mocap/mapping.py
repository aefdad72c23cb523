"""Which of a motion file's bones follows each of HumanML3D's 22 joints: by the names of a rig (a shipped one, or
the user's rig file; docs/rigs.md).

Only a rig's bone names, parents and sources are used here: the rest pose comes from the file itself, so one rig
file serves every character whose bones carry those names, whatever its proportions.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.outputs.rig import RIGS, Rig, RigError, load_rig

from . import MotionFileError, Take


def map_bones(take: Take, rig: "str | Path | Rig | None" = None) -> tuple[Rig, np.ndarray]:
    """The rig `take` is on (the one given, else the first shipped rig whose names it has) and, per HumanML3D
    joint, the index of the take's joint that follows it."""
    candidates = [load_rig(rig)] if rig is not None else _shipped_rigs()
    for cand in candidates:
        missing = [HUMANML3D.joint_names[j] for j in range(HUMANML3D.num_joints) if j not in cand.sources]
        if missing:
            raise RigError(f"{cand.where or cand.name}: no bone follows {', '.join(missing)}; importing needs a bone "
                           f"for each of HumanML3D's 22 joints")
    misses = []
    for loose in (False, True):     # exact names first: `unity` and `vrm` differ only in case
        for cand in candidates:
            found = [_find(take, cand.bone_names[cand.sources.index(j)], loose) for j in range(HUMANML3D.num_joints)]
            absent = [cand.bone_names[cand.sources.index(j)] for j, i in enumerate(found) if i is None]
            if not absent:
                index = np.array(found)
                _check_tree(take, index, cand)
                return cand, index
            misses.append((len(absent), cand.name, absent))
    n, name, absent = min(misses)
    if rig is not None:
        raise MotionFileError(f"{take.where}: has no bone named {', '.join(map(repr, absent[:6]))}"
                              f"{' ...' if n > 6 else ''} of rig {name!r}")
    raise MotionFileError(f"{take.where}: its bone names match none of the shipped rigs ({', '.join(RIGS)}; nearest "
                          f"{name!r}, missing {n} of 22: {', '.join(map(repr, absent[:4]))}{' ...' if n > 4 else ''}): "
                          f"write a rig file for its skeleton (docs/rigs.md) and pass --rig")


@lru_cache(maxsize=1)
def _shipped_rigs() -> list[Rig]:
    return [load_rig(r) for r in RIGS]


def _find(take: Take, name: str, loose: bool) -> int | None:
    """The take's joint called `name`: exactly, or with `loose` ignoring case and punctuation (exporters rewrite
    `mixamorig:Hips` as `mixamorig_Hips` or `mixamorigHips`)."""
    match = [i for i, n in enumerate(take.names) if (_loose(n) == _loose(name) if loose else n == name)]
    if len(match) > 1:
        raise MotionFileError(f"{take.where}: {len(match)} joints are named like {name!r}; which one follows it is "
                              f"not known")
    return match[0] if match else None


def _loose(name: str) -> str:
    return "".join(c for c in name.lower() if c.isalnum())


def _check_tree(take: Take, index: np.ndarray, rig: Rig) -> None:
    """The file's bones keep HumanML3D's tree: the nearest followed bone above each is its joint's parent's."""
    followed = {int(i): j for j, i in enumerate(index)}
    for j, p in enumerate(HUMANML3D.parents):
        a = take.parents[index[j]]
        while a >= 0 and a not in followed:
            a = take.parents[a]
        if p >= 0 and a != index[p]:
            above = f"under {take.names[a]!r}" if a >= 0 else "at the top of the hierarchy"
            raise MotionFileError(f"{take.where}: bone {take.names[index[j]]!r} ({HUMANML3D.joint_names[j]} in rig "
                                  f"{rig.name!r}) is {above}, not under {take.names[index[p]]!r} "
                                  f"({HUMANML3D.joint_names[p]})")
