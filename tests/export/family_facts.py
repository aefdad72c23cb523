"""What a clip's body does, measured from its joints: shared by the tests that hold each action family to its
captions (test_procedural.py, test_families_*.py)."""
import re

import numpy as np

from mogo_export.data.humanml3d import extract_features
from mogo_export.data.procedural.grounding import pose_to_joints
from mogo_export.data.procedural.pose import Pose
from mogo_runtime.kinematics.features import recover_from_ric
from mogo_runtime.kinematics.skeleton import HUMANML3D

STAND_Y = pose_to_joints(Pose(2))[0, 0, 1]  # pelvis height of the neutral standing pose
# Families that spend much of their time off their feet (airborne, or on the knees, hands or back), or land hard:
# the generic tests (test_procedural.py) hold them to the looser bounds jumps and runs get; their own tests check
# their contacts.
OFF_FEET = re.compile(r"jump|run|skip|hop|jack|flip|cartwheel|fall|collapse|lie_down|push_up|stumble|dodge|"
                      r"hit_reaction|dance|roundhouse|kneel|sit_on_ground|crawl")
SIDE = {"left": dict(shoulder=16, wrist=20, ankle=7), "right": dict(shoulder=17, wrist=21, ankle=8)}
def through_features(joints):
    """The joints a model learns from: the writer's features, recovered (frame 0 faces +z)."""
    return recover_from_ric(extract_features(joints, HUMANML3D), 22)


def motion_facts(j):
    """What the body does over frames j (T, 22, 3): root displacement start -> end along the initial facing
    (`fwd`) and to its left (`left`), m; net heading change from the hips and shoulders, degrees (> 0 to the
    left); root path length; pelvis rise above / drop below standing height (and at the end); and what the
    hands, feet and head do."""
    across = (j[:, 2] - j[:, 1]) + (j[:, 17] - j[:, 16])  # right minus left hip, and shoulder
    heading = np.unwrap(np.arctan2(across[:, 2], -across[:, 0]))  # forward = up x across
    h0, h1 = heading[:3].mean(), heading[-3:].mean()
    d = j[-1, 0, [0, 2]] - j[0, 0, [0, 2]]
    fwd = np.stack([np.sin(heading), np.cos(heading)], -1)
    pelvis = j[:, 0, 1] - STAND_Y
    m = dict(fwd=d @ [np.sin(h0), np.cos(h0)], left=d @ [np.cos(h0), -np.sin(h0)], dist=np.linalg.norm(d),
             turn=np.degrees(h1 - h0), path=np.linalg.norm(np.diff(j[:, 0, [0, 2]], axis=0), axis=-1).sum(),
             rise=pelvis.max(), drop=-pelvis.min(), end_drop=-pelvis[-3:].mean(),
             airborne=j[:, [10, 11], 1].min(axis=1).max(),  # both toes off the floor
             clap=np.linalg.norm(j[:, 20] - j[:, 21], axis=-1).min(), head_dip=j[:3, 15, 1].mean() - j[:, 15, 1].min())
    for side, k in SIDE.items():
        m[f"hand_up_{side}"] = (j[:, k["wrist"], 1] - j[:, k["shoulder"], 1]).max()
        m[f"foot_up_{side}"] = j[:, k["ankle"], 1].max()
        reach = j[:, k["wrist"], [0, 2]] - j[:, k["shoulder"], [0, 2]]
        m[f"reach_{side}"] = (reach * fwd).sum(-1).max()
    return m


def rises(x, hi, lo):
    """How many times x rises above `hi`, counted again only after it falls below `lo` (hysteresis: sway about one
    level is not a repetition). A signal that starts above `hi` counts that as its first rise."""
    n, up = 0, False
    for v in x:
        if not up and v > hi:
            n, up = n + 1, True
        elif up and v < lo:
            up = False
    return n
