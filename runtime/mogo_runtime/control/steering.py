"""One stream's control: the game's request (a target from control/targets.py, or none), the root pose the stream's
frames have reached, and the control vector its next token is picked with.

    steering = Steering(spec, dims, context, legs)   # context: the stream's endless.StreamContext; legs: legs_of
    steering.request(lambda s: WalkTo((4.0, 2.0)))   # from any thread
    steering.update(next_index, frame_joints)    # after each token's frames: the pose read, the next token's
                                                 # control handed to the context
    joints = steering.place(index, joints)       # frames as shown: on the game's capsule when it owns the root

The pose is that of the next frame, which the frames so far fix, so the control of token j is read from the root at
frame j * downsample exactly as training read it from the data (control/vector.py). A stream steered this way makes
its frames every token (a chunk of 1): a pose a few tokens old would steer from where the character was.
"""
from __future__ import annotations

import threading
from contextlib import ExitStack
from typing import Callable

import numpy as np

from ..bundle.sections import ControlSpec, ModelDims
from ..kinematics.frames import FrameJoints
from .plant import FootPlant
from .targets import FollowPath, GameRoot, Steer, WalkTo
from .vector import control_dim, encode, encode_many
from .warp import RootWarp, wrap


class Steering:
    def __init__(self, spec: ControlSpec, dims: ModelDims, context, legs: tuple[tuple[int, ...], ...],
                 lock: threading.Lock | None = None):
        """`legs`: each leg's joints, hip to toe (plant.legs_of), to plant the feet of the frames moved. `lock`: the
        lock a request and an update take (default its own); a crowd's characters share one, so a tick's update
        takes one lock for all of them."""
        if spec.dim != control_dim(spec.horizon):
            raise ValueError(f"control dim {spec.dim} does not match a horizon of {spec.horizon} tokens")
        self.spec, self.fps, self.context = spec, dims.fps, context
        # a request from the game's thread and the stream's update never interleave
        self._lock = threading.Lock() if lock is None else lock
        self.times = np.arange(1, spec.horizon + 1) * dims.downsample / dims.fps    # seconds ahead
        self.downsample = dims.downsample
        self.warp = RootWarp(legs)
        self.target = None
        self.pose = np.zeros(3)            # the root of the next frame: frame 0 stands at the origin facing +z
        self.frame = 0                     # the next frame's index

    @property
    def game_owns_root(self) -> bool:
        """Whether the game owns the root (set_root has placed its capsule): frames go where the capsule is."""
        return isinstance(self.target, GameRoot) and self.target.pose is not None

    def vector(self) -> np.ndarray:
        """The control vector of the next token: zeros without a target."""
        return np.zeros(self.spec.dim, np.float32) if self.target is None else encode(self.pose, self._wanted())

    def _wanted(self) -> np.ndarray:
        """The target's wanted poses (horizon, 3) from the pose now."""
        if isinstance(self.target, GameRoot):
            return self.target.future(self.pose, self.times, self.fps, self.frame)
        return self.target.future(self.pose, self.times)

    def request(self, change: Callable[["Steering"], object]) -> None:
        """`change(self)` -> the new target (None: no control); the next token is picked with it."""
        with self._lock:
            self.target = change(self)
            self.context.steer(self.vector())

    def update(self, index: int, frames: FrameJoints) -> None:
        """After a stream's new frames, `index` the next frame's number and `frames` the FrameJoints that made them:
        read the next frame's pose (the capsule's, when the game owns the root), hand the next token's control to
        the stream's context, and plan the correction of the next token's frames (control/warp.py)."""
        Steering.update_many([self], [index], frames.next_pose()[None])

    @staticmethod
    def update_many(steerings: list["Steering"], index: list[int], model_pose: np.ndarray) -> None:
        """`update` for many streams at once (a crowd's), the same numbers: `model_pose` (B, 3) the next frame's pose
        of each stream's motion (FrameJoints.next_pose); their control vectors encoded together."""
        with ExitStack() as held:
            for lock in {id(s._lock): s._lock for s in steerings}.values():   # a request waits for the whole update
                held.enter_context(lock)
            # a lone stream's pose on Python floats (numpy's cost per call is ~5x the arithmetic of one pose)
            poses = steerings[0].warp.pose(model_pose[0], index[0])[None] if len(steerings) == 1 else \
                RootWarp.poses_many([s.warp for s in steerings], model_pose, index)
            rows = []
            for b, (s, i, pose) in enumerate(zip(steerings, index, poses)):
                if s.game_owns_root:
                    pose[:2] = s.target.at(i)[:2]
                s.pose, s.frame = pose, i
                if s.target is None:
                    s.context.steer(s.vector())
                else:
                    rows.append(b)
            if not rows:
                return
            steered = [steerings[b] for b in rows]
            if len(rows) < len(steerings):
                poses = poses[rows]
            paths = [b for b, s in enumerate(steered) if isinstance(s.target, FollowPath)]
            if len(paths) == len(steered):      # the most common request, searched for all at once
                wanted = FollowPath.future_many([s.target for s in steered], poses, steered[0].times)
            else:
                wanted = np.empty((len(steered), steered[0].spec.horizon, 3))
                if paths:
                    wanted[paths] = FollowPath.future_many([steered[b].target for b in paths], poses[paths],
                                                           steered[0].times)
                for b, s in enumerate(steered):
                    if not isinstance(s.target, FollowPath):
                        wanted[b] = s._wanted()
            turns = (wanted[:, 0, 2] - poses[:, 2]).tolist()
            for s, (x, z, _), turn, vector in zip(steered, poses.tolist(), turns, encode_many(poses, wanted)):
                s.context.steer(vector)
                if not isinstance(s.target, GameRoot):      # the next token's correction, toward where it should be
                    reference = s.target.reference()
                    s.warp.plan(s.frame, s.downsample, (x, z), wrap(turn),
                                (0.0, 0.0) if reference is None else (reference[0] - x, reference[1] - z))

    def place(self, index: int, joints: np.ndarray) -> np.ndarray:
        """Frames (n, J, 3) numbered index.. as shown: on the game's capsule when the game owns the root (the
        capsule where the game last placed it, moved on by its velocity), else with the correction planned for
        them; either way with the feet planted (control/plant.py). A stream places each frame as it hands it out,
        so a game that calls set_root before reading a frame gets that frame on that capsule."""
        return Steering.place_many([self], [index], [joints])[0]

    @staticmethod
    def place_many(steerings: list["Steering"], index: list[int], joints: list[np.ndarray]) -> list[np.ndarray]:
        """`place` for many streams at once (a crowd's), the same numbers: stream b's frames joints[b] (n_b, J, 3)
        numbered index[b].. -> each as shown. The streams with as many frames are placed together."""
        out: list[np.ndarray | None] = [None] * len(steerings)
        groups: dict[tuple[int, bool], list[int]] = {}
        for b, (s, frames) in enumerate(zip(steerings, joints)):
            groups.setdefault((len(frames), s.game_owns_root), []).append(b)
        for (n, owned), members in groups.items():
            frames = joints[members[0]][None] if len(members) == 1 else np.stack([joints[b] for b in members])
            if not owned:
                placed = RootWarp.joints_many([steerings[b].warp for b in members], [index[b] for b in members],
                                              frames)
            elif not n:
                placed = frames
            else:
                placed = frames.copy()
                for k, b in enumerate(members):
                    target = steerings[b].target
                    capsule = np.stack([target.at(f)[:2] for f in range(index[b], index[b] + n)])
                    offsets = (capsule - frames[k][:, 0, [0, 2]]).astype(frames.dtype)
                    placed[k, ..., 0] += offsets[:, None, 0]
                    placed[k, ..., 2] += offsets[:, None, 1]
                placed = FootPlant.apply_many([steerings[b].warp.plant for b in members], placed,
                                              np.ones((len(members), n), bool))
            for k, b in enumerate(members):
                out[b] = placed[k]
        return out


class Steerable:
    """Where a character goes, for a stream or a crowd's character: `steering` is its Steering, or None where its
    bundle's model has no control (`_why_not` then says why)."""

    steering: Steering | None

    def _steer(self, change: Callable[[Steering], object]) -> None:
        if self.steering is None:
            raise ValueError(self._why_not())
        self._check_open()
        self.steering.request(change)

    def _why_not(self) -> str:
        return ("this bundle's model was trained without control (its manifest has no 'control' section): its "
                "characters go where the model walks them")

    def _check_open(self) -> None:
        """Raise ValueError where the stream or character follows no more requests."""

    def _next_shown(self, s: Steering) -> int:
        """The number of the next frame the game will be handed (a stream hands out decoded frames one by one)."""
        return s.frame

    def walk_to(self, goal, speed: float = 1.3) -> None:
        """Walk to `goal` (world x, z in metres) at `speed` m/s, then stand there doing the prompt."""
        target = WalkTo(goal, speed)
        self._steer(lambda s: target)

    def follow_path(self, points, speed: float = 1.3) -> None:
        """Follow the polyline `points` ((x, z) in metres) at `speed` m/s, from the point nearest the character."""
        target = FollowPath(points, speed)
        self._steer(lambda s: target)

    def steer(self, velocity, facing=None) -> None:
        """A joystick: move at world `velocity` (vx, vz) m/s, facing `facing` (a world direction) if given."""
        target = Steer(velocity, facing)
        self._steer(lambda s: target)

    def set_root(self, x, z, heading) -> None:
        """The game owns the root: its capsule is at (x, z), facing `heading` (radians; 0 faces +z, pi/2 +x) at the
        next frame this character makes; its frames are put on the capsule, and it moves as the capsule moves."""
        probe = GameRoot()
        probe.place(x, z, heading, 0)               # checks the numbers before anything changes

        def change(s: Steering):
            target = s.target if isinstance(s.target, GameRoot) else GameRoot()
            target.place(x, z, heading, self._next_shown(s))
            return target
        self._steer(change)

    def release(self) -> None:
        """Back to text only: the character goes where the model walks it."""
        self._steer(lambda s: None)

    @property
    def arrived(self) -> bool:
        """Whether a walk_to goal or a path's end is reached (False with any other request, or none)."""
        target = self.steering.target if self.steering is not None else None
        return bool(target is not None and target.arrived)
