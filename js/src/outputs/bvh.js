// BVH export, in Node and the browser: joint positions in metres -> the BVH text runtime/mogo_runtime/outputs/bvh.py
// writes for the same joints (same hierarchy, offsets, channel orders, Euler branches, number formatting); bvh.py's
// docstring says why each step. The rotations are ik.js's. web/test/bvh.test.mjs compares the text with Python's
// on a real HumanML3D clip and on generated motions.
//
//   import { jointsToBvhText } from 'mogo-runtime';
//   const text = jointsToBvhText(motion.joints.data, motion.numFrames, manifest.skeleton, { fps: 20 });

import { shown } from '../checks.js';
import { childrenOf, depthFirst } from '../kinematics/skeleton.js';
import { IDENTITY, at, axisAngle, localRotations, matmul, norm, restOffsets, scale, transpose } from './ik.js';

const UNIT_SCALE = { cm: 100, m: 1 };
const ROOT_ORDER = 'YXZ';       // R = Ry @ Rx @ Rz: heading first
const JOINT_ORDER = 'ZYX';      // R = Rz @ Ry @ Rx
const DEG = 180 / Math.PI;      // numpy's rad2deg

/**
 * @param {ArrayLike<number>} joints (T, J, 3) flat, metres, y up
 * @param {number} T frames
 * @param {{joint_names: string[], parents: number[], offsets: number[][]}} skeleton as a manifest stores it
 * @param {{fps?: number, units?: 'cm'|'m'}} [options]
 * @returns {string} the BVH file's text
 */
export function jointsToBvhText(joints, T, skeleton, { fps = 20, units = 'cm' } = {}) {
  if (!Object.hasOwn(UNIT_SCALE, units)) throw new RangeError(`units must be one of cm, m, got ${shown(units)}`);
  if (!(Number.isFinite(fps) && fps > 0)) throw new RangeError(`fps must be > 0 (frames per second), got ${fps}`);
  const sk = describe(skeleton), J = sk.parents.length;
  if (!Number.isInteger(T) || T < 1 || joints.length !== T * J * 3) {
    throw new RangeError(`joints must have shape (T, ${J}, 3) for skeleton ${JSON.stringify(sk.name)} (T >= 1 frames, `
      + `metres), got ${joints.length} values for ${T} frames`);
  }
  const pos = Float64Array.from(joints), bad = pos.findIndex((x) => !Number.isFinite(x));
  if (bad >= 0) {
    const j = Math.floor(bad / 3) % J;
    throw new RangeError(`joints contain NaN or inf, first at frame ${Math.floor(bad / (J * 3))} joint ${j} (${sk.names[j]})`);
  }
  const offsets = restOffsets(pos, T, sk);
  const local = localRotations(pos, T, sk, offsets, fps);            // (T, J) of 3x3
  const euler = continuousEuler(local, JOINT_ORDER);                  // (T, J, 3) radians, channel order
  const rootEuler = continuousEuler(local.map((row) => [row[sk.root]]), ROOT_ORDER);
  for (let t = 0; t < T; t++) euler[t][sk.root] = rootEuler[t][0];
  return format(pos, T, offsets, euler, sk, fps, UNIT_SCALE[units]);
}

/** The skeleton's tree: names, parents, children, the root, depth-first order, unit rest directions. */
function describe(skeleton) {
  const { name, joint_names: names, parents } = skeleton, roots = parents.filter((p) => p < 0).length;
  if (roots !== 1) throw new RangeError(`skeleton ${name} must have exactly one root, has ${roots}`);
  // a manifest stores direction x length; every direction is along an axis, so dividing by the length gives the
  // skeleton's unit direction exactly
  const dirs = skeleton.offsets.map((o, j) => {
    const n = norm(o);
    if (parents[j] >= 0 && n === 0) throw new RangeError(`skeleton ${name}: joint ${names[j]} has a zero rest direction`);
    return parents[j] < 0 ? [0, 0, 0] : o.map((x) => x / n);
  });
  return { name, names, parents, children: childrenOf(parents), root: parents.indexOf(-1), order: depthFirst(parents), dirs };
}

/** (T, N) rotations -> (T, N, 3) radians, intrinsic `order` (angles listed in that order), continuous in time. */
function continuousEuler(rot, order) {
  const [i, j, k] = [...order].map((a) => 'XYZ'.indexOf(a));
  const e = ['XYZ', 'YZX', 'ZXY'].includes(order) ? 1 : -1;   // the parity of the axis order
  const out = [];
  rot.forEach((rotations, t) => out.push(rotations.map((R, n) => {
    const prev = t ? out[t - 1][n] : [0, 0, 0], mid = Math.asin(Math.min(Math.max(e * R[i][k], -1), 1));
    let angles = [Math.atan2(-e * R[j][k], R[k][k]), mid, Math.atan2(-e * R[i][j], R[i][i])];
    if (Math.cos(mid) < 1e-7) {   // gimbal lock: keep the previous `last` angle, solve `first` from the rest
      const rest = matmul(R, transpose(axisAngle(IDENTITY[k], prev[2])));
      angles = [Math.atan2(e * rest[k][j], rest[j][j]), mid, prev[2]];
    }
    if (t === 0) return angles;
    // of the two triples of the rotation, unwrapped to near the last frame, the nearer
    const [a, b] = [angles, [angles[0] + Math.PI, Math.PI - angles[1], angles[2] + Math.PI]].map(
      (x) => x.map((v, c) => v + 2 * Math.PI * roundHalfEven((prev[c] - v) / (2 * Math.PI))));
    return squaredDistance(b, prev) < squaredDistance(a, prev) ? b : a;
  })));
  return out;
}

const squaredDistance = (a, b) => [0, 1, 2].reduce((sum, i) => sum + (a[i] - b[i]) * (a[i] - b[i]), 0);

/** numpy's round: halves to even. */
function roundHalfEven(x) {
  const r = Math.round(x);
  return Math.abs(x % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

function format(pos, T, offsets, euler, sk, fps, unitScale) {
  for (const n of sk.names) {
    if (!n || /\s/.test(n)) throw new RangeError(`skeleton ${sk.name}: joint name ${shown(n)} cannot be written to BVH (empty or has spaces)`);
  }
  const lines = ['HIERARCHY'], vec = (v) => v.map(fixed6).join(' ');
  const joint = (j, depth) => {
    const ind = '\t'.repeat(depth), root = sk.parents[j] < 0;
    const chans = root ? 'CHANNELS 6 Xposition Yposition Zposition ' : 'CHANNELS 3 ';
    const rots = [...(root ? ROOT_ORDER : JOINT_ORDER)].map((a) => `${a}rotation`).join(' ');
    lines.push(`${ind}${root ? 'ROOT' : 'JOINT'} ${sk.names[j]}`, `${ind}{`,
      `${ind}\tOFFSET ${vec(root ? [0, 0, 0] : scale(offsets[j], unitScale))}`, `${ind}\t${chans}${rots}`);
    for (const c of sk.children[j]) joint(c, depth + 1);
    if (!sk.children[j].length) {   // half the incoming bone, along it: a visible leaf in viewers
      lines.push(`${ind}\tEnd Site`, `${ind}\t{`, `${ind}\t\tOFFSET ${vec(scale(scale(offsets[j], 0.5), unitScale))}`, `${ind}\t}`);
    }
    lines.push(`${ind}}`);
  };
  joint(sk.root, 0);
  lines.push('MOTION', `Frames: ${T}`, `Frame Time: ${fixed(1 / fps, 8)}`);
  for (let t = 0; t < T; t++) {   // channels in the hierarchy's order, depth first from the root
    const values = scale(at(pos, sk.parents.length, t, sk.root), unitScale);
    for (const j of sk.order) values.push(...euler[t][j].map((a) => a * DEG));
    lines.push(vec(values));
  }
  return `${lines.join('\n')}\n`;
}

const fixed6 = (v) => fixed(v, 6);

/**
 * Python's f"{v:.{digits}f}": the exact binary value rounded half to even (toFixed rounds exact ties up), and
 * "-0.000000" for negative zero and small negatives alike.
 */
export function fixed(v, digits) {
  const exact = Math.abs(v).toFixed(30);   // exact digits of a double this far (ties at `digits` need <= 8 of them)
  const point = exact.indexOf('.'), keep = exact.slice(0, point + 1 + digits);
  // an exact tie with an even last digit stays; anything else rounds as toFixed does
  const evenTie = /^50*$/.test(exact.slice(point + 1 + digits)) && Number(keep[keep.length - 1]) % 2 === 0;
  return (v < 0 || Object.is(v, -0) ? '-' : '') + (evenTie ? keep : Math.abs(v).toFixed(digits));
}
