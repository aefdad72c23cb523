// A bounded correction of where a steered character's motion stands on the floor (runtime/mogo_runtime/control/
// warp.py, which says why): a rigid turn and shift of the whole motion about the vertical axis, eased in over each
// token's frames, at most MAX_TURN and MAX_SHIFT a frame. The same scalar float64 operations in the same order as
// Python's, so the pose read through it (and the control vector made from it) is the same to the bit.
//
// A point (x, z) of the model's motion stands at M(phi) (x, z) + t, M(a) = [[cos a, sin a], [-sin a, cos a]].

import { FootPlant } from './plant.js';

export const MAX_TURN = 4.5 * (Math.PI / 180);   // per frame: 90 degrees a second (as CPython's math.radians)
export const MAX_SHIFT = 0.01;                    // m per frame
export const GAIN = 0.5;                          // of the error corrected over one token
const TAU = 2 * Math.PI;
const KEEP = 3;                                   // eases kept: frames are shown at most a token after they are made

/** An angle into [-pi, pi], by whole turns (subtraction only). */
export function wrap(a) {
  while (a > Math.PI) a -= TAU;
  while (a < -Math.PI) a += TAU;
  return a;
}

/** [x, z] turned by a: M(a) (x, z). */
export function turned(a, x, z) {
  const c = Math.cos(a), s = Math.sin(a);
  return [c * x + s * z, -s * x + c * z];
}

/** From frame `start` on: the warp (phi, tx, tz), then a turn about (px, pz) and a shift eased in over `frames`. */
function easeAt(e, k) {
  const f = e.frames ? Math.min(k, e.frames) / e.frames : 0.0;
  const a = e.turn * f;
  const [x, z] = turned(a, e.tx - e.px, e.tz - e.pz);
  return [e.phi + a, x + e.px + e.sx * f, z + e.pz + e.sz * f];
}

export class RootWarp {
  /**
   * `legs`: [hip, knee, ankle, toe] of each leg (plant.js legsOf): the feet the warp moves are planted again; null:
   * the whole frame moves, feet and all.
   */
  constructor(legs = null) {
    this.plant = legs ? new FootPlant(legs) : null;
    this.eases = [{ start: 0, phi: 0, tx: 0, tz: 0, turn: 0, sx: 0, sz: 0, px: 0, pz: 0, frames: 0 }];
    this.active = false;   // no correction yet: frames pass through untouched
  }

  warpAt(frame) {
    for (let i = this.eases.length - 1; i >= 0; i--) {
      const e = this.eases[i];
      if (frame >= e.start) return easeAt(e, frame - e.start + 1);
    }
    const first = this.eases[0];
    return [first.phi, first.tx, first.tz];
  }

  /** The pose [x, z, yaw] of the model's motion at `frame` -> where it stands. */
  pose(modelPose, frame) {
    let [x, z, yaw] = modelPose;
    if (this.active) {
      const [phi, tx, tz] = this.warpAt(frame);
      [x, z] = turned(phi, x, z);
      [x, z, yaw] = [x + tx, z + tz, yaw + phi];
    }
    return [x, z, yaw];
  }

  /** From frame `start`: ease in GAIN * `turn` about `pose` and GAIN * `shift` over `frames`, bounded per frame. */
  plan(start, frames, pose, turn, shift) {
    turn = Math.min(Math.max(GAIN * turn, -MAX_TURN * frames), MAX_TURN * frames);
    let sx = GAIN * shift[0], sz = GAIN * shift[1];
    const norm = Math.sqrt(sx * sx + sz * sz);
    if (norm > MAX_SHIFT * frames) {
      const scale = (MAX_SHIFT * frames) / norm;
      sx *= scale;
      sz *= scale;
    }
    const [phi, tx, tz] = this.warpAt(start - 1);
    this.eases.push({ start, phi, tx, tz, turn, sx, sz, px: pose[0], pz: pose[1], frames });
    if (this.eases.length > KEEP) this.eases.shift();
    this.active = this.active || turn !== 0 || norm > 0;
  }

  /** Frames (flat Float32Array, `frameSize` values each) numbered index.. -> where they stand. */
  joints(index, joints, frameSize) {
    if (!this.active) return this.plant ? this.plant.apply(joints, frameSize, false) : joints;
    const out = new Float32Array(joints.length);
    const moved = [];   // a frame the warp leaves where it was (the eases before the first correction) is not moved
    for (let o = 0, i = 0; o < joints.length; o += frameSize, i++) {
      const [phi, tx, tz] = this.warpAt(index + i);
      moved.push(phi !== 0 || tx !== 0 || tz !== 0);
      const c = Math.cos(phi), s = Math.sin(phi);
      for (let j = o; j < o + frameSize; j += 3) {
        const x = joints[j], z = joints[j + 2];   // float32 values, read as float64 as numpy's astype does
        out[j] = c * x + s * z + tx;
        out[j + 1] = joints[j + 1];
        out[j + 2] = -s * x + c * z + tz;
      }
    }
    return this.plant ? this.plant.apply(out, frameSize, moved) : out;
  }
}
