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

from .features import FeatureLayout
from .files import OutputError, write_atomic
from .skeleton import Skeleton, toes_of

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
    """Fail before any work is done: unknown extension (ValueError) or a file that cannot be written here
    (OutputError: unwritable folder, a folder in the way).

    Returns the lower-case extension. Creates missing parent folders, as `save` would.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SAVE_FORMATS:
        raise ValueError(f"{path}: unknown output format {path.suffix or '(no extension)'!r}; "
                         f"supported: {', '.join(SAVE_FORMATS)}")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give a file name ending in {suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{path}: cannot create its folder {path.parent} ({e.strerror or e})") from None
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: folder {path.parent} is not writable")
    return suffix


class RootIntegrator:
    """`features.recover_from_ric` one frame at a time, for streaming: the same joints, frame for frame.

    A frame's root heading and xz position integrate the *previous* frames' velocities (features 0-2),
    so the running heading and position are all the state there is. float64 throughout, as recover_from_ric.
    """

    def __init__(self, num_joints: int):
        self.layout = FeatureLayout(num_joints)
        self.num_joints = num_joints
        self.angle = 0.0                      # half-angle of the root's facing about y, as in the features
        self.position = np.zeros(2)           # root x, z
        self.previous = np.zeros(3)           # (rot_vel, vel_x, vel_z) of the last frame seen: frame 0 stays put

    def push(self, features: np.ndarray) -> np.ndarray:
        """features (n, D) of the next n frames -> joints (n, J, 3), in the features' float dtype."""
        x = np.asarray(features)
        if x.ndim != 2 or x.shape[1] != self.layout.dim:
            raise ValueError(f"RootIntegrator.push wants (n, {self.layout.dim}) features, got {x.shape}")
        out_dtype = x.dtype if x.dtype.kind == "f" else np.float32
        x64 = x.astype(np.float64)
        J = self.num_joints
        joints = np.empty((len(x), J, 3))
        for i, frame in enumerate(x64):
            rot_vel, vx, vz = self.previous
            self.angle += rot_vel
            c, s = np.cos(self.angle), np.sin(self.angle)
            # qrot(qinv(q(angle)), v) for v = (vx, 0, vz): a rotation by -2*angle about y
            cos2, sin2 = c * c - s * s, 2 * c * s
            self.position += (cos2 * vx - sin2 * vz, sin2 * vx + cos2 * vz)
            ric = frame[4:4 + (J - 1) * 3].reshape(J - 1, 3)
            joints[i, 0] = (self.position[0], frame[3], self.position[1])
            joints[i, 1:, 0] = cos2 * ric[:, 0] - sin2 * ric[:, 2] + self.position[0]
            joints[i, 1:, 1] = ric[:, 1]
            joints[i, 1:, 2] = sin2 * ric[:, 0] + cos2 * ric[:, 2] + self.position[1]
            self.previous = frame[:3].copy()
        return joints.astype(out_dtype)


class FootLock:
    """Keeps a planted toe planted by moving the whole body (x, z) by what the toe slides.

    The decoder predicts each frame's foot contacts (features `foot_contact`: left ankle, left toe, right ankle,
    right toe). Where a toe's contact channel is above CONTACT on the previous frame and on this one, its
    horizontal step between them (in the unlocked joints) is a slide; the body's running offset takes away the
    mean slide of the toes so held, and every later frame carries the offset:

        offset_0 = 0,  offset_t = offset_{t-1} - mean over held toes k of (toe_k[t] - toe_k[t-1])[x, z]

    Causal, with the offset and the last frame's toes as its state, so a stream and a whole motion get the same
    joints. It is there for the frames after a prompt switch, where the decoder joins two motions: on the base
    model's 10-minute streams it took foot skating (a toe below 5 cm moving over 2.5 cm a frame) within 1 s of a
    switch from 9.1% to 5.3% of frames (the data's own transitions: 6.1%), keeping the displacement of segments
    that travel over 1 m (median ratio 0.994-1.008). HumanML3D marks a foot in contact when it moves under
    ~4.5 cm a frame, so on real data the body also moves a little (at most 18 cm over 8.5 s of the test clip).
    Features stay the model's: `recover_from_ric(features)` is the unlocked motion.
    float64 inside; joints in and out float32.
    """

    CONTACT = 0.5

    def __init__(self, num_joints: int):
        self.toes = list(toes_of(num_joints))
        start = FeatureLayout(num_joints).foot_contact.start
        self.channels = [start + 1, start + 3]          # left toe, right toe
        self.offset = np.zeros(2)                       # x, z
        self.previous: tuple[np.ndarray, np.ndarray] | None = None   # last frame's toe (x, z) and contact

    def push(self, joints: np.ndarray, features: np.ndarray) -> np.ndarray:
        """joints (n, J, 3) float32 and their features (n, D) -> the locked joints (n, J, 3) float32."""
        if not len(joints):
            return np.asarray(joints, np.float32)
        j = np.asarray(joints, np.float64)
        toe = j[:, self.toes][..., [0, 2]]                                      # (n, 2 toes, xz)
        contact = np.asarray(features)[:, self.channels] > self.CONTACT         # (n, 2)
        prev_toe, prev_contact = self.previous if self.previous is not None else (toe[0], np.zeros(2, bool))
        slide = np.diff(np.concatenate([prev_toe[None], toe]), axis=0)          # (n, 2, 2)
        held = np.concatenate([prev_contact[None], contact])[:-1] & contact     # (n, 2)
        count = held.sum(1, keepdims=True)
        shift = np.where(count > 0, (slide * held[..., None]).sum(1) / np.maximum(count, 1), 0.0)   # (n, 2)
        # a running subtraction from the carried offset (cumsum is sequential), so chunking changes nothing
        offsets = np.cumsum(np.concatenate([self.offset[None], -shift]), axis=0)[1:]
        self.offset, self.previous = offsets[-1].copy(), (toe[-1].copy(), contact[-1].copy())
        j[..., 0] += offsets[:, None, 0]
        j[..., 2] += offsets[:, None, 1]
        return j.astype(np.float32)
