"""What a game asks of a character's root, turned into the wanted root poses of the next `horizon` tokens
(control/vector.py encodes them). One class per request; each is asked again at every token, from the root pose the
character has then, so the character is steered back whenever it drifts (closed loop, as motion matching's
trajectory is re-read every frame).

    WalkTo(goal, speed)         a straight line to a point on the floor, then stand there
    FollowPath(points, speed)   along a polyline (a navmesh path), facing the way it goes, standing at its end
    Steer(velocity, facing)     a joystick: a world velocity, and optionally a facing that differs (strafing)
    GameRoot()                  the game moves the capsule (`place`); the character is asked to move as it moves

Poses are (x, z, yaw) as in control/vector.py; speeds in m/s; `times` are the seconds of the horizon's steps.
"""
from __future__ import annotations

import math
import numbers
from bisect import bisect_right

import numpy as np

from ..checks import as_real, shown

ARRIVE = 0.3          # metres: a goal or a path's end this close is reached, and the character stands
MIN_SPEED = 0.05      # m/s: slower is standing (WalkTo and FollowPath would never arrive)
MAX_SPEED = 10.0      # m/s: more than any human runs
MAX_POINTS = 100_000  # path points
MAX_COORD = 1e6       # metres from the origin: beyond, float32 joints lose centimetres


def _coordinates(value) -> np.ndarray:
    """`value` as a float64 array if it holds only real numbers (a numpy array of numbers, or nested lists and
    tuples of them); else ValueError. Strings and booleans are refused, though numpy would convert them."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "fiu":
            raise ValueError(f"numbers, not an array of {value.dtype}")
        return value.astype(np.float64)
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, (list, tuple)):
            stack.extend(item)
        elif isinstance(item, (bool, np.bool_)) or not isinstance(item, numbers.Real):
            raise ValueError(f"numbers, not {type(item).__name__}")
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError("a regular array of numbers") from None


def _point(name: str, value) -> np.ndarray:
    try:
        p = _coordinates(value)
    except ValueError as e:
        raise ValueError(f"{name} must be (x, z) in metres ({e}), got {shown(value)}") from None
    if p.shape != (2,) or not np.all(np.isfinite(p)) or np.abs(p).max() > MAX_COORD:
        raise ValueError(f"{name} must be (x, z): two finite numbers within {MAX_COORD:g} m, got {shown(value)}")
    return p


def _speed(speed) -> float:
    return as_real("speed", speed, f"in m/s, from {MIN_SPEED:g} to {MAX_SPEED:g}", MIN_SPEED, MAX_SPEED)


def _yaw_of(direction: np.ndarray) -> float:
    return math.atan2(direction[0], direction[1])


def _stand(now: np.ndarray, steps: int) -> np.ndarray:
    return np.repeat(np.asarray(now, np.float64)[None], steps, axis=0)


class WalkTo:
    """Go to `goal` (x, z) at `speed`, facing it; within ARRIVE of it, stand (facing as it arrived) until given
    another request."""

    def reference(self) -> tuple[float, float] | None:
        """Where the root should be now (x, z), if the request says (once `future` has read the root): the goal once
        reached (the character stands there: the correction holds it), else None (the goal is ahead)."""
        return (float(self.goal[0]), float(self.goal[1])) if self.arrived else None

    def __init__(self, goal, speed: float = 1.3):
        self.goal, self.speed, self.arrived = _point("goal", goal), _speed(speed), False

    def future(self, now: np.ndarray, times: np.ndarray) -> np.ndarray:
        away = self.goal - now[:2]
        dist = float(np.hypot(*away))
        self.arrived = self.arrived or dist < ARRIVE
        if self.arrived:
            return _stand(now, len(times))
        direction = away / dist
        xz = now[:2] + direction * np.minimum(self.speed * times, dist)[:, None]
        return np.concatenate([xz, np.full((len(times), 1), _yaw_of(direction))], axis=1)


class FollowPath:
    """Along the polyline `points` ((n, 2), n >= 2) at `speed`, from the point nearest the character onward: the
    wanted poses lie ahead of that point on the path, so a character that drifts off is led back onto it. Faces the
    path's direction; stands at its end. Progress only moves forward (a path that crosses itself is followed in
    order), searching ahead a bounded stretch each token."""

    LOOKAHEAD = 4.0       # metres of path searched past the progress so far for the nearest point

    def __init__(self, points, speed: float = 1.3):
        if not isinstance(points, np.ndarray) and (not isinstance(points, (list, tuple)) or len(points) > MAX_POINTS):
            raise ValueError(f"path must be a list of 2 to {MAX_POINTS} (x, z) points in metres, got "
                             f"{shown(points) if not isinstance(points, (list, tuple)) else f'{len(points)} points'}")
        try:
            p = _coordinates(points)
        except ValueError as e:
            raise ValueError(f"path must be a list of (x, z) points in metres ({e})") from None
        if p.ndim != 2 or p.shape[1] != 2 or not 2 <= len(p) <= MAX_POINTS or not np.all(np.isfinite(p)) \
                or np.abs(p).max() > MAX_COORD:
            raise ValueError(f"path must be 2 to {MAX_POINTS} (x, z) points, finite and within {MAX_COORD:g} m, "
                             f"got {'shape ' + str(p.shape) if p.ndim != 2 or p.shape[-1:] != (2,) else len(p)}")
        seg = np.diff(p, axis=0)
        length = np.hypot(seg[:, 0], seg[:, 1])
        keep = np.concatenate([[True], length > 1e-6])           # repeated points add no direction
        self.points = p[keep]
        if len(self.points) < 2:
            raise ValueError("path must have two distinct points")
        seg = np.diff(self.points, axis=0)
        self.lengths = np.hypot(seg[:, 0], seg[:, 1])
        self.directions = seg / self.lengths[:, None]
        self.starts = np.concatenate([[0.0], np.cumsum(self.lengths)])   # arc length at each point
        # as lists for `at` and bisect: Python floats, without numpy's cost per call
        self._starts = self.starts.tolist()
        self._points, self._directions = self.points.tolist(), self.directions.tolist()
        self._yaws = np.arctan2(self.directions[:, 0], self.directions[:, 1]).tolist()     # each segment's
        self.total = float(self.starts[-1])
        self.speed, self.progress, self.arrived = _speed(speed), 0.0, False
        self._hints = (0, 0)      # the search's last bisections of `_starts` (the progress, and LOOKAHEAD past it)
        self._reference: tuple[float, tuple[float, float] | None] = (-1.0, None)   # a progress and its point
        # each segment's point, direction, length, start (arc length) and yaw as one row (columns X .. YAW below): a
        # crowd's search joins the rows of every path's look-ahead, one slice a path
        self._segments = np.column_stack([self.points[:-1], self.directions, self.lengths, self.starts[:-1],
                                          self._yaws])

    def at(self, s: float) -> tuple[float, float, float]:
        """An arc length (clipped to the path) -> the point there (x, z) and the path's yaw there (the segment's
        direction)."""
        return self._along([s])[0]

    def nearest(self, xz: np.ndarray) -> float:
        """Arc length of the point of the path nearest `xz`, searched from the progress so far to LOOKAHEAD on."""
        return FollowPath.nearest_many([self], np.asarray(xz, np.float64)[None])[0]

    @staticmethod
    def nearest_many(paths: list["FollowPath"], xz: np.ndarray) -> list[float]:
        """`nearest` for many paths at once (a crowd's), the same numbers: points (B, 2) -> B arc lengths."""
        return FollowPath._search(paths, xz)[0]

    @staticmethod
    def _search(paths: list["FollowPath"], xz: np.ndarray) -> tuple[list[float], np.ndarray, list[tuple[int, int]]]:
        """-> (nearest_many's arc lengths, the segments searched (`_segments` rows of every path's, path after path),
        each path's (first, stop) segments). The segments of every path are one array (elementwise arithmetic;
        numpy's hypot gives the same bits at any array length and offset)."""
        spans = []
        for p in paths:
            # the segment the progress is on (the last one once the progress is the path's whole length: an overshoot)
            p._hints = (_bisect(p._starts, p.progress, p._hints[0]),
                        _bisect(p._starts, p.progress + p.LOOKAHEAD, p._hints[1]))
            first, last = min(max(0, p._hints[0] - 1), len(p.lengths) - 1), p._hints[1]
            spans.append((first, min(last, len(p.lengths)) if last > first else first + 1))
        counts = [b - a for a, b in spans]
        if len(paths) == 1:
            rows, here = paths[0]._segments[spans[0][0]:spans[0][1]], xz
        else:
            rows = np.concatenate([p._segments[a:b] for p, (a, b) in zip(paths, spans)])
            here = np.repeat(xz, counts, axis=0)
        points, directions, lengths = rows[:, X:Z + 1], rows[:, DX:DZ + 1], rows[:, LENGTH]
        away = here - points
        along = np.minimum(np.maximum(away[:, 0] * directions[:, 0] + away[:, 1] * directions[:, 1], 0.0), lengths)
        foot = points + directions * along[:, None] - here
        distance = np.hypot(foot[:, 0], foot[:, 1])
        if len(paths) == 1:
            best = np.argmin(distance)
        else:       # each path's segments a row, padded with +inf: argmin per row, the first nearest as its own
            best = np.argmin(_rows_of(distance, counts, np.inf), axis=1) + (np.cumsum(counts) - counts)
        out = [max(p.progress, arc) for p, arc in zip(paths, np.atleast_1d(rows[best, START] + along[best]).tolist())]
        return out, rows, spans

    def reference(self) -> tuple[float, float]:
        """Where the root should be now (x, z): the point of the path nearest it (the progress `future` found)."""
        progress, point = self._reference
        return point if progress == self.progress else self.at(self.progress)[:2]

    def future(self, now: np.ndarray, times: np.ndarray) -> np.ndarray:
        return FollowPath.future_many([self], np.asarray(now)[None], times)[0]

    @staticmethod
    def future_many(paths: list["FollowPath"], now: np.ndarray, times: np.ndarray) -> np.ndarray:
        """`future` for many paths at once (a crowd's), the same numbers: poses now (B, 3) -> (B, horizon, 3). The
        wanted points of a crowd's paths are read from the segments their search joined (a path whose points lie
        past them, and a lone path, on Python floats: `_along`)."""
        progress, rows, spans = FollowPath._search(paths, now[:, :2])
        B = len(paths)
        out = np.empty((B, len(times), 3))
        if B > 1:       # the point at the progress (t = 0: `reference`'s), then the wanted ones
            arcs = np.array(progress)[:, None] + np.array([p.speed for p in paths])[:, None] * \
                np.concatenate([[0.0], times])
            arcs = np.minimum(np.maximum(arcs, 0.0), np.array([p.total for p in paths])[:, None])
            # the segment of each arc among its path's searched ones: those that start at or before it, less one
            counts = [b - a for a, b in spans]
            starts = _rows_of(rows[:, START], counts, np.inf)
            k = (starts[:, None, :] <= arcs[..., None]).sum(axis=2) - 1 + (np.cumsum(counts) - counts)[:, None]
            segment = rows[k]
            along = arcs - segment[..., START]
            x, z = segment[..., X] + segment[..., DX] * along, segment[..., Z] + segment[..., DZ] * along
            out[..., 0], out[..., 1], out[..., 2] = x[:, 1:], z[:, 1:], segment[:, 1:, YAW]
            last, nearest = arcs[:, -1].tolist(), np.stack([x[:, 0], z[:, 0]], axis=1).tolist()
        for b, (p, here, arc) in enumerate(zip(paths, now, progress)):
            p.progress = arc
            p.arrived = p.arrived or (p.total - arc < ARRIVE and float(np.hypot(*(p.points[-1] - here[:2]))) < ARRIVE)
            joined = B > 1 and (spans[b][1] == len(p.lengths) or last[b] < p._starts[spans[b][1]])
            if joined:
                p._reference = arc, tuple(nearest[b])
            if p.arrived:
                out[b] = here
            elif not joined:
                out[b] = p._along([arc + p.speed * t for t in times.tolist()])
        return out

    def _along(self, arcs: list[float]) -> list[tuple[float, float, float]]:
        """`at` of each of `arcs`. Python floats: a token asks for a few points, where numpy's calls cost more than the
        arithmetic."""
        out, starts, last = [], self._starts, len(self._yaws) - 1
        for s in arcs:
            s = min(max(s, 0.0), self.total)
            k = min(max(bisect_right(starts, s) - 1, 0), last)
            (px, pz), (dx, dz), along = self._points[k], self._directions[k], s - starts[k]
            out.append((px + dx * along, pz + dz * along, self._yaws[k]))
        return out


X, Z, DX, DZ, LENGTH, START, YAW = range(7)        # FollowPath._segments' columns


def _bisect(ordered: list[float], value: float, hint: int) -> int:
    """bisect_right(ordered, value), stepping on from `hint` (the answer for a value a little smaller: a path's
    progress moves a few centimetres a token) where that is a few steps; else bisected. A bisection of a long path
    reads points spread over memory that a crowd's step call has pushed out of the caches."""
    n = len(ordered)
    if 0 < hint <= n and ordered[hint - 1] <= value:
        for k in range(hint, min(hint + 4, n)):
            if ordered[k] > value:
                return k
        if hint + 4 >= n:
            return n
    return bisect_right(ordered, value)


def _rows_of(values: np.ndarray, counts: list[int], fill: float) -> np.ndarray:
    """`values` of consecutive groups of `counts` as the rows of a (groups, max count) array padded with `fill`."""
    row = np.repeat(np.arange(len(counts)), counts)
    out = np.full((len(counts), max(counts)), fill)
    out[row, np.arange(len(row)) - np.repeat(np.cumsum(counts) - counts, counts)] = values
    return out


class Steer:
    """Move at world `velocity` (vx, vz) m/s; face `facing` (a world direction) if given, else the way it moves
    (or as it faces now when standing)."""

    def __init__(self, velocity, facing=None):
        self.velocity = _point("velocity", velocity)
        if np.hypot(*self.velocity) > MAX_SPEED:
            raise ValueError(f"velocity must be at most {MAX_SPEED:g} m/s, got {np.hypot(*self.velocity):.3g}")
        self.facing = None if facing is None else _point("facing", facing)
        if self.facing is not None and np.hypot(*self.facing) < 1e-6:
            raise ValueError("facing must be a direction (x, z), not (0, 0)")
        self.arrived = False

    def reference(self) -> None:
        return None

    def future(self, now: np.ndarray, times: np.ndarray) -> np.ndarray:
        xz = now[:2] + self.velocity * times[:, None]
        moving = np.hypot(*self.velocity) > 0.2
        yaw = _yaw_of(self.facing) if self.facing is not None else _yaw_of(self.velocity) if moving else now[2]
        return np.concatenate([xz, np.full((len(times), 1), yaw)], axis=1)


class GameRoot:
    """The game owns the root (a capsule it moves itself): `place(x, z, yaw, frame)` says where the capsule is at
    frame `frame`; the character is asked to move as the capsule's last two placements extrapolate, and its frames
    are put where the capsule is (Steering.place)."""

    def __init__(self):
        self.pose: np.ndarray | None = None          # the capsule at frame `frame`
        self.velocity = np.zeros(3)                  # per frame: dx, dz, dyaw
        self.frame = 0
        self.arrived = False

    def place(self, x, z, yaw, frame: int) -> None:
        pose = np.array([*_point("root", (x, z)), as_real("heading", yaw, "in radians, finite", -1e6, 1e6)])
        if self.pose is not None and frame > self.frame:
            step = pose - self.pose
            step[2] = math.remainder(step[2], 2 * math.pi)
            self.velocity = step / (frame - self.frame)
        self.pose, self.frame = pose, frame

    def at(self, frame: int) -> np.ndarray:
        """The capsule's pose at `frame`, extrapolated from its last placement."""
        return self.pose + self.velocity * (frame - self.frame)

    def future(self, now: np.ndarray, times: np.ndarray, fps: float, frame: int) -> np.ndarray:
        """The capsule's poses `times` seconds after frame `frame` (the character's next frame), as extrapolated."""
        if self.pose is None:
            return _stand(now, len(times))
        return np.stack([self.at(frame + t * fps) for t in times])
