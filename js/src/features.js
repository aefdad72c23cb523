// HumanML3D features -> joint positions (runtime/mogo_runtime/features.py recover_from_ric, and motion.py
// RootIntegrator for streams and FootLock for both), in float64 with numpy's operation order, returned as float32.
//
// Feature 0 is the change of the root's facing (a half angle about y) to the next frame, features 1-2 the
// root's xz velocity in the facing frame, feature 3 the root height, features 4.. the joints relative to the
// root's xz in the facing frame. Frame 0 faces +z at the origin; a frame's heading and position integrate the
// previous frames' velocities (hence the shift by one frame).

import { featureLayout, toesOf } from './skeleton.js';

/** cross(a, b) for 3-vectors, as numpy computes it. */
function cross(a0, a1, a2, b0, b1, b2) {
  return [a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0];
}

/** qrot(q, v) = v + 2 (w uv + q_xyz x uv), uv = q_xyz x v (quaternion.py), for q = (w, 0, y, 0). */
function rotateAboutY(w, y, v0, v1, v2) {
  const uv = cross(0, y, 0, v0, v1, v2);
  const uuv = cross(0, y, 0, uv[0], uv[1], uv[2]);
  return [v0 + 2 * (w * uv[0] + uuv[0]), v1 + 2 * (w * uv[1] + uuv[1]), v2 + 2 * (w * uv[2] + uuv[2])];
}

/**
 * @param {Float32Array} features (T, D) de-normalised, D = 12 J - 1
 * @param {number} numJoints J
 * @returns {Float32Array} joints (T, J, 3), metres, y up
 */
export function recoverFromRic(features, numJoints) {
  const D = 12 * numJoints - 1, T = features.length / D;
  if (!Number.isInteger(T)) throw new RangeError(`features must be (T, ${D}) for ${numJoints} joints, got ${features.length} values`);
  const joints = new Float32Array(T * numJoints * 3);
  let angle = 0, x = 0, z = 0;
  for (let t = 0; t < T; t++) {
    const f = t * D;
    if (t > 0) {
      const p = f - D;
      angle += features[p];                                  // cumsum of the shifted half angles
      const [w, y] = [Math.cos(angle), Math.sin(angle)];
      const [dx, , dz] = rotateAboutY(w, -y, features[p + 1], 0, features[p + 2]);   // qinv: the conjugate
      x += dx;
      z += dz;
    }
    writeFrame(joints, t, numJoints, features, f, Math.cos(angle), -Math.sin(angle), x, z);
  }
  return joints;
}

/** One frame's joints from the running heading (conjugate quaternion w, y) and root xz. */
function writeFrame(joints, t, J, features, f, w, y, x, z) {
  const o = t * J * 3;
  joints[o] = x;
  joints[o + 1] = features[f + 3];
  joints[o + 2] = z;
  for (let j = 1; j < J; j++) {
    const r = f + 4 + (j - 1) * 3;
    const p = rotateAboutY(w, y, features[r], features[r + 1], features[r + 2]);
    joints[o + j * 3] = p[0] + x;
    joints[o + j * 3 + 1] = p[1];
    joints[o + j * 3 + 2] = p[2] + z;
  }
}

/**
 * recoverFromRic one chunk of frames at a time, for streams (motion.py RootIntegrator): the running heading
 * and root position are all the state there is.
 */
export class RootIntegrator {
  constructor(numJoints) {
    this.numJoints = numJoints;
    this.dim = 12 * numJoints - 1;
    this.angle = 0;                 // half-angle of the root's facing about y, as in the features
    this.x = 0;
    this.z = 0;
    this.previous = [0, 0, 0];      // (rot_vel, vel_x, vel_z) of the last frame seen: frame 0 stays put
  }

  /** features (n, D) of the next n frames -> joints (n, J, 3) float32. */
  push(features) {
    const J = this.numJoints, D = this.dim, n = features.length / D;
    if (!Number.isInteger(n)) throw new RangeError(`RootIntegrator.push wants (n, ${D}) features, got ${features.length} values`);
    const joints = new Float32Array(n * J * 3);
    for (let i = 0; i < n; i++) {
      const f = i * D;
      const [rotVel, vx, vz] = this.previous;
      this.angle += rotVel;
      const c = Math.cos(this.angle), s = Math.sin(this.angle);
      // qrot(qinv(q(angle)), v) for v = (vx, 0, vz): a rotation by -2 * angle about y
      const cos2 = c * c - s * s, sin2 = 2 * c * s;
      this.x += cos2 * vx - sin2 * vz;
      this.z += sin2 * vx + cos2 * vz;
      const o = i * J * 3;
      joints[o] = this.x;
      joints[o + 1] = features[f + 3];
      joints[o + 2] = this.z;
      for (let j = 1; j < J; j++) {
        const r = f + 4 + (j - 1) * 3;
        joints[o + j * 3] = cos2 * features[r] - sin2 * features[r + 2] + this.x;
        joints[o + j * 3 + 1] = features[r + 1];
        joints[o + j * 3 + 2] = sin2 * features[r] + cos2 * features[r + 2] + this.z;
      }
      this.previous = [features[f], features[f + 1], features[f + 2]];
    }
    return joints;
  }
}

/**
 * Keeps a planted toe planted by moving the whole body (x, z) by what the toe slides (motion.py FootLock):
 * where a toe's contact channel is above 0.5 on the previous frame and this one, the body's running offset
 * takes away the mean of the held toes' steps, offset_t = offset_{t-1} - mean_k (toe_k[t] - toe_k[t-1])[x, z].
 * Causal, so a stream and a whole motion get the same joints; float64 inside, float32 in and out.
 */
export class FootLock {
  constructor(numJoints) {
    this.numJoints = numJoints;
    this.dim = 12 * numJoints - 1;
    this.toes = toesOf(numJoints);
    const start = featureLayout(numJoints).slices.foot_contact[0];
    this.channels = [start + 1, start + 3];          // left toe, right toe
    this.x = 0;                                      // the running offset
    this.z = 0;
    this.previous = null;                            // the last frame's toe x, z and contact
  }

  /** joints (n, J, 3) float32 and their features (n, D) -> the locked joints (n, J, 3) float32. */
  push(joints, features) {
    const J = this.numJoints, D = this.dim, n = features.length / D;
    if (!Number.isInteger(n) || joints.length !== n * J * 3) {
      throw new RangeError(`FootLock.push wants (n, ${J}, 3) joints and (n, ${D}) features, got ${joints.length} and ${features.length} values`);
    }
    const out = new Float32Array(joints.length);
    for (let t = 0; t < n; t++) {
      const o = t * J * 3;
      const toe = this.toes.map((j) => [joints[o + j * 3], joints[o + j * 3 + 2]]);
      const contact = this.channels.map((c) => features[t * D + c] > 0.5);
      const prev = this.previous ?? { toe, contact: [false, false] };
      // numpy's order: each step times its 0/1 held flag, left + right, divided by the count held
      const held = [prev.contact[0] && contact[0], prev.contact[1] && contact[1]].map(Number);
      const count = held[0] + held[1];
      const slide = (axis) => ((toe[0][axis] - prev.toe[0][axis]) * held[0] + (toe[1][axis] - prev.toe[1][axis]) * held[1]) / count;
      this.x += -(count > 0 ? slide(0) : 0);
      this.z += -(count > 0 ? slide(1) : 0);
      this.previous = { toe, contact };
      for (let j = 0; j < J; j++) {
        out[o + j * 3] = joints[o + j * 3] + this.x;
        out[o + j * 3 + 1] = joints[o + j * 3 + 1];
        out[o + j * 3 + 2] = joints[o + j * 3 + 2] + this.z;
      }
    }
    return out;
  }
}
