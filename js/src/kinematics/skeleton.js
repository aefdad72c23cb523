// The skeletons a bundle may name (runtime/mogo_runtime/kinematics/skeleton.py). The stored fields are what a
// manifest holds (Skeleton.to_dict), and bundle/manifest.js compares them field by field: the joints code relies on
// these tables. The feet (ankle, toe) are the runtime's own, the joints the features' contact channels describe.

const STORED = ['name', 'joint_names', 'parents', 'offsets', 'fps', 'up_axis', 'units'];

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
    fps: 20, up_axis: 'y', units: 'm',
    footLeft: [7, 10], footRight: [8, 11],
  },
  kit: {
    name: 'kit',
    joint_names: ['root', 'bp', 'bt', 'bln', 'bun', 'ls', 'le', 'lw', 'rs', 're', 'rw', 'lh', 'lk', 'la', 'lmrot',
      'lf', 'rh', 'rk', 'ra', 'rmrot', 'rf'],
    parents: [-1, 0, 1, 2, 3, 3, 5, 6, 3, 8, 9, 0, 11, 12, 13, 14, 0, 16, 17, 18, 19],
    offsets: [[0, 0, 0], [0, 0.1, 0], [0, 0.12, 0], [0, 0.16, 0], [0, 0.2, 0], [0.18, 0, 0], [0, -0.28, 0],
      [0, -0.25, 0], [-0.18, 0, 0], [0, -0.28, 0], [0, -0.25, 0], [0.1, 0, 0], [0, -0.42, 0], [0, -0.4, 0],
      [0, 0, 0.06], [0, 0, 0.12], [-0.1, 0, 0], [0, -0.42, 0], [0, -0.4, 0], [0, 0, 0.06], [0, 0, 0.12]],
    fps: 12.5, up_axis: 'y', units: 'm',
    footLeft: [19, 20], footRight: [14, 15],
  },
};

/** The fields a manifest stores for `skeleton` (Skeleton.to_dict). */
export const storedSkeleton = (skeleton) => Object.fromEntries(STORED.map((key) => [key, skeleton[key]]));

/** Each joint's children, in joint order, from the parent of every joint (-1 for the root). */
export const childrenOf = (parents) => parents.map((_, i) => parents.flatMap((p, j) => (p === i ? [j] : [])));

/** Every joint reachable from the root, parents before children, children in joint order. */
export function depthFirst(parents) {
  const children = childrenOf(parents), order = [], stack = [parents.indexOf(-1)];
  while (stack.length) {
    order.push(stack.pop());
    stack.push(...children[order[order.length - 1]].slice().reverse());
  }
  return order;
}
