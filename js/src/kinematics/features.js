// The HumanML3D motion feature vector: its layout and features -> joints (runtime/mogo_runtime/kinematics/
// features.py), in float64 with numpy's operation order, returned as float32.
//
// Feature 0 is the change of the root's facing (a half angle about y) to the next frame, features 1-2 the
// root's xz velocity in the facing frame, feature 3 the root height, features 4.. the joints relative to the
// root's xz in the facing frame. Frame 0 faces +z at the origin; a frame's heading and position integrate the
// previous frames' velocities (hence the shift by one frame).

/**
 * Where each field sits in a frame's feature vector, for J joints (D = 12J - 1), as FeatureLayout.to_dict:
 * root_rot_vel 1, root_lin_vel 2, root_y 1, ric (J-1)*3, rot6d (J-1)*6, local_vel J*3, foot_contact 4.
 */
export function featureLayout(numJoints) {
  const sizes = [['root_rot_vel', 1], ['root_lin_vel', 2], ['root_y', 1], ['ric', (numJoints - 1) * 3],
    ['rot6d', (numJoints - 1) * 6], ['local_vel', numJoints * 3], ['foot_contact', 4]];
  const slices = {};
  let at = 0;
  for (const [name, size] of sizes) {
    slices[name] = [at, at + size];
    at += size;
  }
  return { num_joints: numJoints, dim: at, slices };
}

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
 * @returns {Float32Array} joints (T, J, 3), metres, y up
 */
export function recoverFromRic(features, numJoints) {
  const D = 12 * numJoints - 1, T = features.length / D, J = numJoints;
  if (!Number.isInteger(T)) throw new RangeError(`features must be (T, ${D}) for ${J} joints, got ${features.length} values`);
  const joints = new Float32Array(T * J * 3);
  let angle = 0, x = 0, z = 0;
  for (let t = 0; t < T; t++) {
    const f = t * D, o = t * J * 3;
    if (t > 0) {
      angle += features[f - D];                              // cumsum of the shifted half angles
      const [dx, , dz] = rotateAboutY(Math.cos(angle), -Math.sin(angle), features[f - D + 1], 0, features[f - D + 2]);
      x += dx;                                               // qinv: the conjugate
      z += dz;
    }
    const w = Math.cos(angle), y = -Math.sin(angle);
    joints.set([x, features[f + 3], z], o);
    for (let j = 1; j < J; j++) {
      const r = f + 4 + (j - 1) * 3;
      const p = rotateAboutY(w, y, features[r], features[r + 1], features[r + 2]);
      joints.set([p[0] + x, p[1], p[2] + z], o + j * 3);
    }
  }
  return joints;
}
