// The skeletons a bundle may name, as the manifest stores them (runtime/mogo_runtime/skeleton.py,
// Skeleton.to_dict) and the motion feature layout of each (features.py, FeatureLayout.to_dict).
//
// The joints code relies on these tables (the feature layout, the root), so a manifest must store a skeleton
// exactly as the runtime knows it: manifest.js compares field by field.

export const SKELETONS = {
  humanml3d: {
    name: 'humanml3d',
    joint_names: ['pelvis', 'left_hip', 'right_hip', 'spine1', 'left_knee', 'right_knee', 'spine2', 'left_ankle',
      'right_ankle', 'spine3', 'left_foot', 'right_foot', 'neck', 'left_collar', 'right_collar', 'head',
      'left_shoulder', 'right_shoulder', 'left_elbow', 'right_elbow', 'left_wrist', 'right_wrist'],
    parents: [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19],
    offsets: [[0, 0, 0], [0.103074, 0, 0], [-0.109883, 0, 0], [0, 0.131568, 0], [0, -0.393623, 0],
      [0, -0.390188, 0], [0, 0.14319, 0], [0, -0.432433, 0], [0, -0.425643, 0], [0, 0.057365, 0],
      [0, 0, 0.143382], [0, 0, 0.149419], [0, 0.21936, 0], [0.137487, 0, 0], [-0.143383, 0, 0], [0, 0, 0.103039],
      [0, -0.131614, 0], [0, -0.122984, 0], [0, -0.25684, 0], [0, -0.263092, 0], [0, -0.266012, 0],
      [0, -0.269876, 0]],
    fps: 20,
    up_axis: 'y',
    units: 'm',
  },
  kit: {
    name: 'kit',
    joint_names: ['root', 'bp', 'bt', 'bln', 'bun', 'ls', 'le', 'lw', 'rs', 're', 'rw', 'lh', 'lk', 'la', 'lmrot',
      'lf', 'rh', 'rk', 'ra', 'rmrot', 'rf'],
    parents: [-1, 0, 1, 2, 3, 3, 5, 6, 3, 8, 9, 0, 11, 12, 13, 14, 0, 16, 17, 18, 19],
    offsets: [[0, 0, 0], [0, 0.1, 0], [0, 0.12, 0], [0, 0.16, 0], [0, 0.2, 0], [0.18, 0, 0], [0, -0.28, 0],
      [0, -0.25, 0], [-0.18, 0, 0], [0, -0.28, 0], [0, -0.25, 0], [0.1, 0, 0], [0, -0.42, 0], [0, -0.4, 0],
      [0, 0, 0.06], [0, 0, 0.12], [-0.1, 0, 0], [0, -0.42, 0], [0, -0.4, 0], [0, 0, 0.06], [0, 0, 0.12]],
    fps: 12.5,
    up_axis: 'y',
    units: 'm',
  },
};

// (left toe, right toe) of each skeleton (skeleton.py foot_left[1], foot_right[1]): the joints the features' toe
// contact channels describe. Kept apart from SKELETONS, which must equal the manifest's skeleton field for field.
const TOES = { humanml3d: [10, 11], kit: [20, 15] };

/** The (left toe, right toe) joints of the known skeleton with numJoints joints (skeleton.py toes_of). */
export function toesOf(numJoints) {
  for (const [name, skeleton] of Object.entries(SKELETONS)) {
    if (skeleton.parents.length === numJoints) return TOES[name];
  }
  throw new RangeError(`no known skeleton has ${numJoints} joints`);
}

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
