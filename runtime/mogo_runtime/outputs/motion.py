"""A generated motion and its files: `Motion.save(path)` by extension, and joints integrated frame by frame.

    motion = generator.generate("a person walks forward", seconds=4, seed=1)
    motion.save("walk.bvh")      # also .npy (joints), .json (joint positions), .gif / .mp4 (previews)
    motion.save("walk.glb", rig="mixamo")   # on a game rig (rig.py): .glb and .bvh; in_place=True drops the path

Every file appears whole or not at all (files.py): a reader (a game watching a folder, a crashed run) never sees
half a file, a process killed mid-write leaves no stray file, and a failed write (a full disk) raises OutputError
naming the file.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..checks import NAME_MAX, shown
from ..kinematics.skeleton import Skeleton
from .extras import require
from .files import OutputError, write_atomic

SAVE_FORMATS = (".npy", ".json", ".bvh", ".glb", ".gif", ".mp4")
RIG_FORMATS = (".bvh", ".glb")     # the formats a motion can be written to on another rig
JSON_DECIMALS = 4   # metres: 0.1 mm, far below what a viewer or a game can show, and keeps files small


@dataclass
class Motion:
    text: str
    features: np.ndarray          # (T, D) de-normalised HumanML3D-style features
    joints: np.ndarray            # (T, J, 3) metres, y up
    fps: float
    tokens: np.ndarray            # (T / downsample, L) the motion tokens of every quantizer level
    skeleton: Skeleton
    seed: int
    aligned_text: str | None = None   # the prompt after test-time text alignment (the paper's TCA), if any
    # a prompt of several actions (plan.py): each action's text and the frame it starts at, in order
    actions: list[tuple[str, int]] | None = None

    @property
    def num_frames(self) -> int:
        return int(self.joints.shape[0])

    @property
    def seconds(self) -> float:
        return self.num_frames / self.fps

    def to_dict(self) -> dict:
        """The `.json` file's content: fps, skeleton, joint positions per frame (metres, 0.1 mm)."""
        return {"text": self.text, "aligned_text": self.aligned_text, "seed": int(self.seed), "fps": float(self.fps),
                "num_frames": self.num_frames, "skeleton": self.skeleton.to_dict(),
                "frames": np.round(np.asarray(self.joints, np.float64), JSON_DECIMALS).tolist()}

    def save(self, path: str | Path, rig=None, in_place: bool = False) -> Path:
        """Write the motion in the format its extension names (see SAVE_FORMATS); returns the path.

        `rig` (a shipped rig's name, a rig file, or a Rig; see rig.py) retargets a .glb or .bvh onto that rig; a .glb
        without one is on the `humanml3d` rig. `in_place=True` keeps the hips over the origin (turning stays)."""
        path = Path(path)
        suffix = check_output_path(path)
        if (rig is not None or in_place) and suffix not in RIG_FORMATS:
            raise ValueError(f"{path}: a rig and in_place apply to {' and '.join(RIG_FORMATS)} files, not {suffix}")
        if suffix == ".npy":
            write_atomic(path, lambda f: np.save(f, np.asarray(self.joints, np.float32), allow_pickle=False))
        elif suffix == ".json":
            data = json.dumps(self.to_dict(), separators=(",", ":")).encode()
            write_atomic(path, lambda f: f.write(data))
        elif suffix == ".glb" or rig is not None or in_place:
            from .retarget import retarget
            from .rig import DEFAULT_RIG
            anim = retarget(self.joints, DEFAULT_RIG if rig is None else rig, fps=self.fps, in_place=in_place,
                            skeleton=self.skeleton)
            if suffix == ".glb":
                from .gltf import glb_bytes
                data = glb_bytes(anim, name=self.text, extras={"text": self.text, "seed": int(self.seed)})
            else:
                data = anim.to_bvh_text().encode("ascii")
            write_atomic(path, lambda f: f.write(data))
        elif suffix == ".bvh":   # the writers below go through write_atomic themselves
            from .bvh import write_bvh
            write_bvh(path, self.joints, self.skeleton, fps=self.fps)
        else:  # .gif, .mp4
            from .preview import render_gif, render_mp4
            render = render_gif if suffix == ".gif" else render_mp4
            render(path, self.joints, self.skeleton, fps=self.fps, title=self.text)
        return path


def check_output_path(path: str | Path) -> str:
    """Fail before any work is done: unknown extension (ValueError), a format whose optional packages this install
    lacks (extras.MissingExtra), or a file that cannot be written here (OutputError: unwritable folder, a folder in
    the way).

    Returns the lower-case extension. Creates missing parent folders, as `save` would.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if len(path.name.encode("utf-8", "surrogateescape")) > NAME_MAX:
        raise OutputError(f"{shown(str(path), 120)}: a file name of more than {NAME_MAX} bytes (no file system takes "
                          f"it)")
    if suffix not in SAVE_FORMATS:
        raise ValueError(f"{path}: unknown output format {path.suffix or '(no extension)'!r}; "
                         f"supported: {', '.join(SAVE_FORMATS)}")
    require(suffix)      # the format's optional packages (extras.py)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give a file name ending in {suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{path}: cannot create its folder {path.parent} ({e.strerror or e})") from None
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: folder {path.parent} is not writable")
    return suffix
