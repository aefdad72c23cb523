// Joints frame by frame, as a stream's features arrive (runtime/mogo_runtime/kinematics/frames.py): the root
// integrated over time (RootIntegrator), and planted toes held (FootLock); FrameJoints does both.
// float64 inside, float32 in and out.

import { featureLayout } from './features.js';

/**
 * recoverFromRic one chunk of frames at a time, for streams: the same joints, frame for frame. A frame's root
 * heading and xz position integrate the *previous* frames' velocities, so they are all the state there is.
 */
export class RootIntegrator {
  constructor(skeleton) {
    this.numJoints = skeleton.parents.length;
    this.dim = featureLayout(this.numJoints).dim;
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
      const f = i * D, o = i * J * 3;
      const [rotVel, vx, vz] = this.previous;
      this.angle += rotVel;
      const c = Math.cos(this.angle), s = Math.sin(this.angle);
      // qrot(qinv(q(angle)), v) for v = (vx, 0, vz): a rotation by -2 * angle about y
      const cos2 = c * c - s * s, sin2 = 2 * c * s;
      this.x += cos2 * vx - sin2 * vz;
      this.z += sin2 * vx + cos2 * vz;
      joints.set([this.x, features[f + 3], this.z], o);
      for (let j = 1; j < J; j++) {
        const r = f + 4 + (j - 1) * 3;
        joints.set([cos2 * features[r] - sin2 * features[r + 2] + this.x, features[r + 1],
          sin2 * features[r] + cos2 * features[r + 2] + this.z], o + j * 3);
      }
      this.previous = [features[f], features[f + 1], features[f + 2]];
    }
    return joints;
  }

  /** The root pose [x, z, yaw] of the next frame, which the frames so far fix (the root faces (sin yaw, cos yaw)). */
  nextPose() {
    const [rotVel, vx, vz] = this.previous, angle = this.angle + rotVel;
    const cos2 = Math.cos(2 * angle), sin2 = Math.sin(2 * angle);
    return [this.x + (cos2 * vx - sin2 * vz), this.z + (sin2 * vx + cos2 * vz), -2.0 * angle];
  }
}

/**
 * Keeps a planted toe planted by moving the whole body (x, z) by what the toe slides: where a toe's contact
 * channel is above 0.5 on the previous frame and this one, the body's running offset takes away the mean of the
 * held toes' steps, offset_t = offset_{t-1} - mean_k (toe_k[t] - toe_k[t-1])[x, z]. Causal, so a stream and a
 * whole motion get the same joints (frames.py says why it is there).
 */
export class FootLock {
  constructor(skeleton) {
    this.numJoints = skeleton.parents.length;
    const layout = featureLayout(this.numJoints), start = layout.slices.foot_contact[0];
    this.dim = layout.dim;
    this.toes = [skeleton.footLeft[1], skeleton.footRight[1]];   // the joints of the toe contact channels
    this.channels = [start + 1, start + 3];                      // left toe, right toe
    this.x = 0;                                                  // the running offset
    this.z = 0;
    this.previous = null;                                        // the last frame's toe x, z and contact
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
        out.set([joints[o + j * 3] + this.x, joints[o + j * 3 + 1], joints[o + j * 3 + 2] + this.z], o + j * 3);
      }
    }
    return out;
  }
}

/** A stream's features -> its joints, chunk by chunk: the root integrated, then planted toes held. */
export class FrameJoints {
  constructor(skeleton) {
    this.root = new RootIntegrator(skeleton);
    this.lock = new FootLock(skeleton);
  }

  /** features (n, D) of the next n frames -> joints (n, J, 3) float32. */
  push(features) { return this.lock.push(this.root.push(features), features); }

  /** The root pose [x, z, yaw] of the next frame, where the frames so far put it (the lock's offset too). */
  nextPose() {
    const pose = this.root.nextPose();
    return [pose[0] + this.lock.x, pose[1] + this.lock.z, pose[2]];
  }
}
