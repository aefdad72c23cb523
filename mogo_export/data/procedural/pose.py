"""Joint-angle tracks of one clip (`Pose`), the angle conventions they use, and the clip timeline.

Every action family builds a Pose by adding layers of local joint angles (`leg`, `arm`, `spine`, ...),
plus which frames are airborne, which feet may carry the body and, for actions that go down to the floor,
which other body parts may rest on it (`rest_on`, CONTACTS). No family ever places a joint in
space: turning angles into joint positions with the feet planted on the floor is done once for all of
them (kinematics.py, grounding.py), so a new family only has to speak this small vocabulary.

Angle conventions (degrees; the body faces +z, y is up, the person's left is +x):
  flex  > 0 swings a limb forward, knee/elbow > 0 bends them, dorsi > 0 lifts the toes,
  abd   > 0 moves a limb away from the body's midline, yaw > 0 turns left (counter-clockwise from above),
  pitch / bend > 0 leans forward, lean / roll > 0 leans to the body's left.
"""
from __future__ import annotations

import numpy as np

FPS = 20.0
NUM_JOINTS = 22
MIN_SECONDS, MAX_SECONDS = 2.05, 10.0    # 41..200 frames, so features (one frame fewer) keep T2M's 40..199
GRAVITY = 9.81

# HumanML3D joint indices
PELVIS, SPINE1, SPINE2, SPINE3, NECK = 0, 3, 6, 9, 12
SIDES = {  # per side: joint indices, and the sign that mirrors abduction / twist across the midline
    "left": dict(hip=1, knee=4, ankle=7, collar=13, shoulder=16, elbow=18, sign=1.0),
    "right": dict(hip=2, knee=5, ankle=8, collar=14, shoulder=17, elbow=19, sign=-1.0),
}
OTHER = {"left": "right", "right": "left"}

# Body parts besides the feet that an action may rest on the floor (kneeling, sitting, lying, on all fours):
# name -> (joint, metres from the joint down to the body's surface below it, the thickness of flesh
# and bone a joint of HumanML3D's skeleton is inside of).
CONTACTS = {
    "pelvis": (PELVIS, 0.09), "lower_back": (SPINE1, 0.10), "mid_back": (SPINE2, 0.10),
    "upper_back": (SPINE3, 0.10), "head": (15, 0.09),
    "left_hip": (1, 0.08), "right_hip": (2, 0.08), "left_knee": (4, 0.05), "right_knee": (5, 0.05),
    "left_shoulder": (16, 0.06), "right_shoulder": (17, 0.06), "left_elbow": (18, 0.04),
    "right_elbow": (19, 0.04), "left_hand": (20, 0.03), "right_hand": (21, 0.03),
}
_CONTACT_INDEX = {name: i for i, name in enumerate(CONTACTS)}


class Pose:
    """Joint-angle tracks of one clip, built by adding layers.

    angles[t, j] = (x, y, z) degrees. Joint j's local rotation is POSTURE[j] @ Rz(z) @ Rx(x) @ Ry(y): the
    twist (y) about the bone first, then flexion (x), then abduction (z). The root (joint 0) instead
    holds (pitch, yaw, roll) and rotates as Ry(yaw) @ Rx(pitch) @ Rz(-roll).
    """

    def __init__(self, num_frames: int):
        self.T = num_frames
        self.t = np.arange(num_frames) / FPS
        self.angles = np.zeros((num_frames, NUM_JOINTS, 3))
        self.flight = np.zeros(num_frames, dtype=bool)  # airborne frames: root follows a ballistic arc
        self.support = np.ones((num_frames, 2), dtype=bool)  # (left, right) feet allowed to carry the body
        # airborne frames of a jump off both feet: the toes land where they took off, moved by air_speed
        # along the heading over those frames (other flights, a running stride's, keep the velocity
        # they left the floor with)
        self.leap = np.zeros(num_frames, dtype=bool)
        self.air_speed = np.zeros(num_frames)           # m/s forward (body frame) while leaping
        # (T, len(CONTACTS)): which body parts besides the feet (CONTACTS order) may rest on the floor and
        # carry the body in each frame (`rest_on`); none by default, as in every original family
        self.resting = np.zeros((num_frames, len(CONTACTS)), dtype=bool)

    def rest_on(self, parts, on=True) -> None:
        """Let body `parts` (names in CONTACTS) rest on the floor, and carry the body, where `on` (a bool, or
        per frame: bools or 0..1, read as > 0.5) holds: grounding then puts the lowest of the feet and these
        parts on the floor, and pins each one that comes down there as it pins the feet. Parts not allowed
        are never floor contacts (the default, and the original families': no part but the feet ever is)."""
        on = np.broadcast_to(np.asarray(on, dtype=np.float64) > 0.5, (self.T,))
        for name in [parts] if isinstance(parts, str) else parts:
            self.resting[:, _CONTACT_INDEX[name]] = on

    def _add(self, j: int, axis: int, value) -> None:
        self.angles[:, j, axis] += np.broadcast_to(np.asarray(value, dtype=np.float64), (self.T,))

    def root(self, pitch=0.0, yaw=0.0, roll=0.0) -> None:
        self._add(PELVIS, 0, pitch)
        self._add(PELVIS, 1, yaw)
        self._add(PELVIS, 2, roll)

    def leg(self, side: str, flex=0.0, abd=0.0, yaw=0.0, knee=0.0, dorsi=0.0) -> None:
        """`yaw` turns the whole leg (foot included) about the vertical: > 0 points the toes left, either side."""
        s = SIDES[side]
        self._add(s["hip"], 0, -np.asarray(flex))
        self._add(s["hip"], 1, yaw)
        self._add(s["hip"], 2, s["sign"] * np.asarray(abd))
        self._add(s["knee"], 0, knee)
        self._add(s["ankle"], 0, -np.asarray(dorsi))

    def arm(self, side: str, flex=0.0, abd=0.0, twist=0.0, elbow=0.0, shrug=0.0, across=0.0) -> None:
        """twist > 0 rotates the upper arm outward, so a bent elbow lifts the forearm when abducted;
        across > 0 swings the whole arm about the (near vertical) collar -> shoulder bone toward the
        midline, the horizontal adduction of clapping and punching."""
        s = SIDES[side]
        self._add(s["collar"], 1, s["sign"] * np.asarray(across))
        self._add(s["collar"], 2, s["sign"] * np.asarray(shrug))
        self._add(s["shoulder"], 0, -np.asarray(flex))
        self._add(s["shoulder"], 1, s["sign"] * np.asarray(twist))
        self._add(s["shoulder"], 2, s["sign"] * np.asarray(abd))
        self._add(s["elbow"], 0, -np.asarray(elbow))

    def spine(self, bend=0.0, lean=0.0, twist=0.0) -> None:
        """Spread over the three spine joints; twist > 0 turns the shoulders to the left."""
        for j, w in ((SPINE1, 0.4), (SPINE2, 0.3), (SPINE3, 0.3)):
            self._add(j, 0, w * np.asarray(bend))
            self._add(j, 1, w * np.asarray(twist))
            self._add(j, 2, -w * np.asarray(lean))

    def head(self, nod=0.0, turn=0.0, tilt=0.0) -> None:
        self._add(NECK, 0, nod)
        self._add(NECK, 1, turn)
        self._add(NECK, 2, -np.asarray(tilt))

    def relaxed(self, arms: bool = True) -> None:
        """The neutral standing layer: arms hang slightly away from the body, elbows soft."""
        if arms:
            for side in SIDES:
                self.arm(side, abd=4.0, elbow=12.0, flex=3.0)
        self.spine(bend=2.0)


def flat_foot(pitch, flex, knee, lift=0.0):
    """Ankle dorsiflexion that keeps the foot at its standing pitch (minus `lift` degrees of heel raise).

    In the sagittal plane the foot's global pitch is the sum of the root, hip, knee and ankle rotations
    about x, so zeroing that sum keeps the sole parallel to the floor.
    """
    return np.asarray(pitch) - np.asarray(flex) + np.asarray(knee) - np.asarray(lift)


def seconds_to_frames(seconds: float) -> int:
    """Frames for a timeline of `seconds`, at least MIN_SECONDS (short actions end holding their pose)."""
    return int(round(max(seconds, MIN_SECONDS) * FPS))

