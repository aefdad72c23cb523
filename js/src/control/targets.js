// What a game asks of a character's root, turned into the wanted root poses of the next `horizon` tokens
// (vector.js encodes them): runtime/mogo_runtime/control/targets.py, the same checks and messages, the same float64
// operations in the same order. Each is asked again at every token, from the root pose the character has then, so
// the character is steered back whenever it drifts.
//
//   new WalkTo(goal, speed)         a straight line to a point on the floor, then stand there
//   new FollowPath(points, speed)   along a polyline (a navmesh path), facing the way it goes, standing at its end
//   new Steer(velocity, facing)     a joystick: a world velocity, and optionally a facing that differs (strafing)
//   new GameRoot()                  the game moves the capsule (`place`); the character is asked to move as it moves
//
// Poses are [x, z, yaw]; points [x, z] in metres; speeds in m/s; `times` are the seconds of the horizon's steps.

import { asReal, shown } from '../checks.js';

export const ARRIVE = 0.3;          // metres: a goal or a path's end this close is reached, and the character stands
export const MIN_SPEED = 0.05;      // m/s: slower is standing (WalkTo and FollowPath would never arrive)
export const MAX_SPEED = 10.0;      // m/s: more than any human runs
export const MAX_POINTS = 100_000;  // path points
export const MAX_COORD = 1e6;       // metres from the origin: beyond, float32 joints lose centimetres
const MAX_COORD_TEXT = '1e+06';     // as Python's f"{MAX_COORD:g}"

/** `value` as nested arrays of numbers (arrays or typed arrays of numbers only), else a TypeError saying what. */
function coordinates(value) {
  if (ArrayBuffer.isView(value)) return Array.from(value);
  if (Array.isArray(value)) return value.map(coordinates);
  if (typeof value !== 'number') {
    throw new TypeError(`numbers, not ${value === null ? 'null' : typeof value}`);
  }
  return value;
}

function point(name, value) {
  let p;
  try {
    p = coordinates(value);
  } catch (e) {
    throw new TypeError(`${name} must be (x, z) in metres (${e.message}), got ${shown(value)}`);
  }
  if (!Array.isArray(p) || p.length !== 2 || !p.every((x) => typeof x === 'number' && Number.isFinite(x))
    || Math.max(Math.abs(p[0]), Math.abs(p[1])) > MAX_COORD) {
    throw new RangeError(`${name} must be (x, z): two finite numbers within ${MAX_COORD_TEXT} m, got ${shown(value)}`);
  }
  return p;
}

const checkSpeed = (speed) => asReal('speed', speed, `in m/s, from ${MIN_SPEED} to ${MAX_SPEED}`, MIN_SPEED, MAX_SPEED);

const yawOf = ([x, z]) => Math.atan2(x, z);

const stand = (now, steps) => Array.from({ length: steps }, () => [now[0], now[1], now[2]]);

/** Go to `goal` [x, z] at `speed`, facing it; within ARRIVE of it, stand (facing as it arrived). */
export class WalkTo {
  constructor(goal, speed = 1.3) {
    this.goal = point('goal', goal);
    this.speed = checkSpeed(speed);
    this.arrived = false;
  }

  /** Where the root should be now: the goal once reached (the correction holds it there), else null. */
  reference() { return this.arrived ? [this.goal[0], this.goal[1]] : null; }

  future(now, times) {
    const away = [this.goal[0] - now[0], this.goal[1] - now[1]], dist = Math.hypot(away[0], away[1]);
    this.arrived ||= dist < ARRIVE;
    if (this.arrived) return stand(now, times.length);
    const direction = [away[0] / dist, away[1] / dist], yaw = yawOf(direction);
    return times.map((t) => {
      const along = Math.min(this.speed * t, dist);
      return [now[0] + direction[0] * along, now[1] + direction[1] * along, yaw];
    });
  }
}

/**
 * Along the polyline `points` (n >= 2 of [x, z]) at `speed`, from the point nearest the character onward; faces the
 * path's direction; stands at its end. Progress only moves forward, searching ahead LOOKAHEAD metres each token.
 */
export class FollowPath {
  static LOOKAHEAD = 4.0;   // metres of path searched past the progress so far for the nearest point

  constructor(points, speed = 1.3) {
    if (!Array.isArray(points) || points.length > MAX_POINTS) {
      throw new TypeError(`path must be a list of 2 to ${MAX_POINTS} (x, z) points in metres, got `
        + `${Array.isArray(points) ? `${points.length} points` : shown(points)}`);
    }
    let p;
    try {
      p = coordinates(points);
    } catch (e) {
      throw new TypeError(`path must be a list of (x, z) points in metres (${e.message})`);
    }
    const pairs = p.every((q) => Array.isArray(q) && q.length === 2 && q.every((x) => typeof x === 'number'));
    if (!pairs || p.length < 2 || !p.every((q) => q.every((x) => Number.isFinite(x) && Math.abs(x) <= MAX_COORD))) {
      throw new RangeError(`path must be 2 to ${MAX_POINTS} (x, z) points, finite and within ${MAX_COORD_TEXT} m, `
        + `got ${pairs ? p.length : 'another shape'}`);
    }
    // repeated points add no direction
    this.points = p.filter((q, i) => i === 0 || Math.hypot(q[0] - p[i - 1][0], q[1] - p[i - 1][1]) > 1e-6);
    if (this.points.length < 2) throw new RangeError('path must have two distinct points');
    const seg = this.points.slice(1).map((q, i) => [q[0] - this.points[i][0], q[1] - this.points[i][1]]);
    this.lengths = seg.map(([x, z]) => Math.hypot(x, z));
    this.directions = seg.map(([x, z], i) => [x / this.lengths[i], z / this.lengths[i]]);
    this.starts = [0];                                           // arc length at each point (a sequential sum)
    for (const length of this.lengths) this.starts.push(this.starts[this.starts.length - 1] + length);
    this.total = this.starts[this.starts.length - 1];
    this.speed = checkSpeed(speed);
    this.progress = 0;
    this.arrived = false;
  }

  /** The segment of arc length s (clipped to the path): numpy's searchsorted(starts, s, side="right") - 1. */
  #segment(s) {
    return Math.min(Math.max(searchRight(this.starts, s) - 1, 0), this.lengths.length - 1);
  }

  /** An arc length -> the point there and the path's yaw there (the segment's direction). */
  at(s) {
    s = Math.min(Math.max(s, 0), this.total);
    const k = this.#segment(s), d = this.directions[k], along = s - this.starts[k];
    return [this.points[k][0] + d[0] * along, this.points[k][1] + d[1] * along, Math.atan2(d[0], d[1])];
  }

  /** Arc length of the point of the path nearest `xz`, searched from the progress so far to LOOKAHEAD on. */
  nearest([x, z]) {
    const n = this.lengths.length;
    const first = Math.min(Math.max(0, searchRight(this.starts, this.progress) - 1), n - 1);
    const last = searchRight(this.starts, this.progress + FollowPath.LOOKAHEAD);
    const end = last > first ? Math.min(last, n) : first + 1;
    let best = null, bestDistance = Infinity, bestAlong = 0;
    for (let k = first; k < end; k++) {
      const [px, pz] = this.points[k], [dx, dz] = this.directions[k];
      const along = Math.min(Math.max((x - px) * dx + (z - pz) * dz, 0), this.lengths[k]);
      const distance = Math.hypot(px + dx * along - x, pz + dz * along - z);
      if (distance < bestDistance || best === null) [best, bestDistance, bestAlong] = [k, distance, along];
    }
    return Math.max(this.progress, this.starts[best] + bestAlong);
  }

  /** Where the root should be now: the point of the path nearest it (the progress `future` found). */
  reference() {
    const [x, z] = this.at(this.progress);
    return [x, z];
  }

  future(now, times) {
    this.progress = this.nearest(now);
    const end = this.points[this.points.length - 1];
    this.arrived ||= this.total - this.progress < ARRIVE && Math.hypot(end[0] - now[0], end[1] - now[1]) < ARRIVE;
    if (this.arrived) return stand(now, times.length);
    return times.map((t) => this.at(this.progress + this.speed * t));
  }
}

/** Index of the first element of sorted `a` greater than `v` (numpy's searchsorted side="right"). */
function searchRight(a, v) {
  let lo = 0, hi = a.length;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (a[mid] <= v) lo = mid + 1;
    else hi = mid;
  }
  return lo;
}

/** Move at world `velocity` [vx, vz] m/s; face `facing` if given, else the way it moves (or as it faces, standing). */
export class Steer {
  constructor(velocity, facing = null) {
    this.velocity = point('velocity', velocity);
    const speed = Math.hypot(...this.velocity);
    if (speed > MAX_SPEED) {
      throw new RangeError(`velocity must be at most ${MAX_SPEED} m/s, got ${Number(speed.toPrecision(3))}`);
    }
    this.facing = facing === null || facing === undefined ? null : point('facing', facing);
    if (this.facing !== null && Math.hypot(...this.facing) < 1e-6) {
      throw new RangeError('facing must be a direction (x, z), not (0, 0)');
    }
    this.arrived = false;
  }

  /** Where the root should be now, if the request says (a path does): null. */
  reference() { return null; }

  future(now, times) {
    const moving = Math.hypot(...this.velocity) > 0.2;
    const yaw = this.facing !== null ? yawOf(this.facing) : moving ? yawOf(this.velocity) : now[2];
    return times.map((t) => [now[0] + this.velocity[0] * t, now[1] + this.velocity[1] * t, yaw]);
  }
}

/**
 * The game owns the root (a capsule it moves itself): `place(x, z, yaw, frame)` says where the capsule is at frame
 * `frame`; the character is asked to move as the capsule's last two placements extrapolate, and its frames are put
 * where the capsule is (Steering.place).
 */
export class GameRoot {
  constructor() {
    this.pose = null;            // the capsule at frame `frame`
    this.velocity = [0, 0, 0];   // per frame: dx, dz, dyaw
    this.frame = 0;
    this.arrived = false;
  }

  place(x, z, yaw, frame) {
    const pose = [...point('root', [x, z]), asReal('heading', yaw, 'in radians, finite', -1e6, 1e6)];
    if (this.pose !== null && frame > this.frame) {
      const step = pose.map((v, i) => v - this.pose[i]);
      step[2] = remainder(step[2], 2 * Math.PI);
      this.velocity = step.map((v) => v / (frame - this.frame));
    }
    this.pose = pose;
    this.frame = frame;
  }

  /** The capsule's pose at `frame`, extrapolated from its last placement. */
  at(frame) { return this.pose.map((v, i) => v + this.velocity[i] * (frame - this.frame)); }

  /** The capsule's poses `times` seconds after frame `frame` (the character's next frame), as extrapolated. */
  future(now, times, fps, frame) {
    if (this.pose === null) return stand(now, times.length);
    return times.map((t) => this.at(frame + t * fps));
  }
}

/** IEEE 754 remainder (Python's math.remainder), y > 0: x - n * y with n the nearest integer to x / y, ties even. */
function remainder(x, y) {
  const r = x % y, half = y / 2;   // % is exact (C's fmod); subtracting y from |r| in [y/2, y] is exact too
  if (Math.abs(r) > half || (Math.abs(r) === half && ((x - r) / y) % 2 !== 0)) return r - Math.sign(r) * y;
  return r;
}
