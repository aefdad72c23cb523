"""The HumanML3D motion feature vector: its layout, and features -> joints (a dataset's Mean/Std, which the exported
decoder applies itself, are read by mogo_export.data.dataset)."""
from __future__ import annotations

from dataclasses import dataclass
from itertools import accumulate

import numpy as np

from .quaternion import qinv, qrot

_FIELDS = ("root_rot_vel", "root_lin_vel", "root_y", "ric", "rot6d", "local_vel", "foot_contact")


@dataclass(frozen=True)
class FeatureLayout:
    """Where each field sits in a frame's feature vector, for a skeleton of J joints (D = 12J - 1).

      root_rot_vel  1        change of the root's y-axis facing to the next frame, as a HALF angle (radians)
      root_lin_vel  2        root xz velocity to the next frame, in the next frame's facing frame
      root_y        1        root height
      ric           (J-1)*3  joint positions relative to the root's xz, in the root's facing frame
      rot6d         (J-1)*6  local joint rotations (first two rotation-matrix columns)
      local_vel     J*3      joint velocities to the next frame, in the facing frame
      foot_contact  4        left ankle, left toe, right ankle, right toe (1 = in contact)
    D is 263 for HumanML3D (22 joints) and 251 for KIT-ML (21). The joints -> features direction is
    mogo_export.data.humanml3d.extract_features.
    """

    num_joints: int

    def __post_init__(self):
        if not isinstance(self.num_joints, (int, np.integer)) or self.num_joints < 2:
            raise ValueError(f"FeatureLayout.num_joints must be an int >= 2, got {self.num_joints!r}")

    @classmethod
    def for_skeleton(cls, skeleton) -> "FeatureLayout":
        return cls(skeleton.num_joints)

    def _sizes(self) -> tuple[int, ...]:
        j = self.num_joints
        return (1, 2, 1, (j - 1) * 3, (j - 1) * 6, j * 3, 4)

    @property
    def dim(self) -> int:
        return sum(self._sizes())

    def slices(self) -> dict[str, slice]:
        """Field name -> slice of the feature vector, in storage order."""
        bounds = list(accumulate(self._sizes(), initial=0))
        return {name: slice(a, b) for name, a, b in zip(_FIELDS, bounds, bounds[1:])}

    root_rot_vel = property(lambda self: self.slices()["root_rot_vel"])
    root_lin_vel = property(lambda self: self.slices()["root_lin_vel"])
    root_y = property(lambda self: self.slices()["root_y"])
    ric = property(lambda self: self.slices()["ric"])
    rot6d = property(lambda self: self.slices()["rot6d"])
    local_vel = property(lambda self: self.slices()["local_vel"])
    foot_contact = property(lambda self: self.slices()["foot_contact"])

    def to_dict(self) -> dict:
        """JSON-friendly form for manifests: {"num_joints", "dim", "slices": {name: [start, stop]}}."""
        return {"num_joints": int(self.num_joints), "dim": self.dim,
                "slices": {k: [s.start, s.stop] for k, s in self.slices().items()}}


def recover_root_rot_pos(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root facing quaternions (..., T, 4) and root positions (..., T, 3) from the first four features.

    As HumanML3D's `recover_root_rot_pos`: frame 0 faces +z at the origin; the facing angle and the
    root xz position integrate the previous frame's velocities (hence the shift by one).
    """
    x = np.asarray(features, dtype=np.float64)
    rot_vel = x[..., 0]                                            # (..., T)
    ang = np.zeros_like(rot_vel)
    ang[..., 1:] = rot_vel[..., :-1]
    ang = np.cumsum(ang, axis=-1)                                  # half-angles, as in the features
    r_quat = np.zeros(x.shape[:-1] + (4,))
    r_quat[..., 0] = np.cos(ang)
    r_quat[..., 2] = np.sin(ang)                                   # (..., T, 4) rotation about y

    r_pos = np.zeros(x.shape[:-1] + (3,))
    r_pos[..., 1:, 0] = x[..., :-1, 1]
    r_pos[..., 1:, 2] = x[..., :-1, 2]
    r_pos = np.cumsum(qrot(qinv(r_quat), r_pos), axis=-2)          # velocities back to world frame
    r_pos[..., 1] = x[..., 3]
    return r_quat, r_pos


def recover_from_ric(features: np.ndarray, num_joints: int) -> np.ndarray:
    """(..., T, D) features -> (..., T, J, 3) joint positions, as HumanML3D's `recover_from_ric`.

    Computed in float64; returns the input's float dtype (float32 for anything not floating).
    """
    x = np.asarray(features)
    dim = FeatureLayout(num_joints).dim
    if x.ndim < 2 or x.shape[-1] != dim:
        raise ValueError(f"features must be (..., T, {dim}) for {num_joints} joints, got {x.shape}")
    out_dtype = x.dtype if x.dtype.kind == "f" else np.float32
    r_quat, r_pos = recover_root_rot_pos(x)
    ric = np.asarray(x[..., 4:4 + (num_joints - 1) * 3], dtype=np.float64)
    ric = ric.reshape(ric.shape[:-1] + (num_joints - 1, 3))       # (..., T, J-1, 3)
    pos = qrot(qinv(r_quat)[..., None, :], ric)                    # undo the facing rotation
    pos[..., 0] += r_pos[..., None, 0]
    pos[..., 2] += r_pos[..., None, 2]
    joints = np.concatenate([r_pos[..., None, :], pos], axis=-2)  # (..., T, J, 3)
    return joints.astype(out_dtype)
