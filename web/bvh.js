// BVH export in the browser: joint positions in metres -> the BVH text runtime/mogo_runtime/bvh.py writes for the
// same joints (same hierarchy, offsets, channel orders, Euler branches, number formatting). Read bvh.py's
// docstring for the why of each step; this is a line-by-line port with two differences, both below rounding:
// the best-fit rotation (Kabsch) is found with Horn's quaternion method instead of an SVD (the same unique
// optimum), and a joint's singular values come from its Gram matrix. web/test/bvh.test.mjs compares the text with
// Python's on a real HumanML3D clip and on generated motions.
//
//   import { jointsToBvhText } from './bvh.js';
//   const text = jointsToBvhText(motion.joints.data, motion.numFrames, manifest.skeleton, { fps: 20 });

const UNIT_SCALE = { cm: 100, m: 1 };
const ROOT_ORDER = 'YXZ';       // R = Ry @ Rx @ Rz: heading first
const JOINT_ORDER = 'ZYX';      // R = Rz @ Ry @ Rx
const TWIST_RELAX_S = 0.25;     // a carried-over twist relaxes back to the swing with this time constant
const DEG = 180 / Math.PI;      // numpy's rad2deg

/**
 * @param {ArrayLike<number>} joints (T, J, 3) flat, metres, y up
 * @param {number} T frames
 * @param {{joint_names: string[], parents: number[], offsets: number[][]}} skeleton as a manifest stores it
 * @param {{fps?: number, units?: 'cm'|'m'}} [options]
 * @returns {string} the BVH file's text
 */
export function jointsToBvhText(joints, T, skeleton, { fps = 20, units = 'cm' } = {}) {
  if (!Object.hasOwn(UNIT_SCALE, units)) throw new RangeError(`units must be one of cm, m, got ${JSON.stringify(units)}`);
  if (!(Number.isFinite(fps) && fps > 0)) throw new RangeError(`fps must be a positive number, got ${fps}`);
  const sk = describe(skeleton);
  const J = sk.parents.length;
  if (!Number.isInteger(T) || T < 1 || joints.length !== T * J * 3) {
    throw new RangeError(`joints must have shape (T, ${J}, 3) for skeleton ${JSON.stringify(sk.name)} (T >= 1 frames, `
      + `metres), got ${joints.length} values for ${T} frames`);
  }
  const pos = Float64Array.from(joints);
  for (let n = 0; n < pos.length; n++) {
    if (!Number.isFinite(pos[n])) {
      const t = Math.floor(n / (J * 3)), j = Math.floor(n / 3) % J;
      throw new RangeError(`joints contain NaN or inf, first at frame ${t} joint ${j} (${sk.names[j]})`);
    }
  }
  const offsets = restOffsets(pos, T, sk);
  const local = localRotations(pos, T, sk, offsets, fps);            // (T, J) of 3x3 row-major
  const euler = continuousEuler(local, T, J, JOINT_ORDER);           // (T, J, 3) radians, channel order
  const rootEuler = continuousEuler(local.map((row) => [row[sk.root]]), T, 1, ROOT_ORDER);
  for (let t = 0; t < T; t++) euler[t][sk.root] = rootEuler[t][0];
  return format(pos, T, offsets, euler, sk, fps, UNIT_SCALE[units]);
}

/** The skeleton's tree: names, parents, children, the root, unit rest directions, depth-first order. */
function describe(skeleton) {
  const names = skeleton.joint_names, parents = skeleton.parents;
  const J = parents.length;
  const children = Array.from({ length: J }, (_, i) => parents.flatMap((p, j) => (p === i ? [j] : [])));
  const roots = parents.flatMap((p, j) => (p < 0 ? [j] : []));
  if (roots.length !== 1) throw new RangeError(`skeleton ${skeleton.name} must have exactly one root, has ${roots.length}`);
  const root = roots[0];
  const order = [], stack = [root];
  while (stack.length) {
    order.push(stack.pop());
    stack.push(...children[order[order.length - 1]].slice().reverse());
  }
  // a manifest stores direction x length; every direction is along an axis, so dividing by the length gives the
  // skeleton's unit direction exactly
  const dirs = skeleton.offsets.map((o, j) => {
    if (parents[j] < 0) return [0, 0, 0];
    const n = norm(o);
    if (n === 0) throw new RangeError(`skeleton ${skeleton.name}: joint ${names[j]} has a zero rest direction`);
    return [o[0] / n, o[1] / n, o[2] / n];
  });
  return { name: skeleton.name, names, parents, children, root, order, dirs };
}

// ---- rest offsets ----------------------------------------------------------------------------------------

function restOffsets(pos, T, sk) {
  const J = sk.parents.length;
  const offsets = Array.from({ length: J }, () => [0, 0, 0]);
  sk.parents.forEach((p, j) => {
    if (p < 0) return;
    const lengths = new Float64Array(T);
    for (let t = 0; t < T; t++) lengths[t] = norm(sub(at(pos, J, t, j), at(pos, J, t, p)));
    const length = median(lengths);
    if (length < 1e-6) {
      throw new RangeError(`bone ${sk.names[p]} -> ${sk.names[j]} has zero length in the clip (median over frames); `
        + 'cannot build a skeleton');
    }
    offsets[j] = scale(sk.dirs[j], length);
  });
  sk.children.forEach((ch, j) => {
    if (ch.length < 2) return;
    const bones = [];   // (T, k, 3)
    for (let t = 0; t < T; t++) bones.push(ch.map((c) => sub(at(pos, J, t, c), at(pos, J, t, j))));
    let shape = ch.map((c) => offsets[c]);
    for (let pass = 0; pass < 3; pass++) {   // generalised Procrustes: the rigid shape that best fits every frame
      const sums = ch.map(() => [0, 0, 0]);
      for (let t = 0; t < T; t++) {
        const rot = kabsch(shape, bones[t]);
        bones[t].forEach((b, k) => {
          const back = mulTv(rot, b);
          for (let i = 0; i < 3; i++) sums[k][i] += back[i];
        });
      }
      shape = sums.map((s) => s.map((x) => x / T));
    }
    const turn = kabsch(shape, ch.map((c) => offsets[c]));   // onto the rest directions, as near as it goes
    ch.forEach((c, k) => { offsets[c] = mulMv(turn, shape[k]); });
  });
  return offsets;
}

function median(values) {
  const s = Float64Array.from(values).sort();
  const n = s.length, h = n >> 1;
  return n % 2 ? s[h] : (s[h - 1] + s[h]) / 2;
}

// ---- inverse kinematics ----------------------------------------------------------------------------------

function localRotations(pos, T, sk, offsets, fps) {
  const J = sk.parents.length;
  const glob = Array.from({ length: T }, () => new Array(J));
  const local = Array.from({ length: T }, () => new Array(J));
  const relax = Math.exp(-1 / (fps * TWIST_RELAX_S));
  for (const j of sk.order) {
    const p = sk.parents[j], ch = sk.children[j];
    const parentOf = (t) => (p >= 0 ? glob[t][p] : IDENTITY);
    if (ch.length >= 2 && !collinear(ch.map((c) => offsets[c]))) {
      for (let t = 0; t < T; t++) {
        glob[t][j] = kabsch(ch.map((c) => offsets[c]), ch.map((c) => sub(at(pos, J, t, c), at(pos, J, t, j))));
        local[t][j] = matmul(transpose(parentOf(t)), glob[t][j]);
      }
    } else if (ch.length) {   // one child, or children on one line: the first one sets the rotation
      const d = [];
      for (let t = 0; t < T; t++) d.push(mulTv(parentOf(t), sub(at(pos, J, t, ch[0]), at(pos, J, t, j))));
      const rots = swingWithContinuousTwist(offsets[ch[0]], d, relax);
      for (let t = 0; t < T; t++) {
        local[t][j] = rots[t];
        glob[t][j] = matmul(parentOf(t), rots[t]);
      }
    } else {
      for (let t = 0; t < T; t++) {
        local[t][j] = IDENTITY;
        glob[t][j] = parentOf(t);
      }
    }
  }
  return local;
}

/** Rotations taking direction u to each d[t]: the pure swing, with a twist about u carried where the swing jumps. */
function swingWithContinuousTwist(u0, dRaw, relax) {
  const u = scale(u0, 1 / norm(u0));
  const d = dRaw.map((v) => normalise(v, u));
  const T = d.length;
  const swing = d.map((v) => minRotation(u, v));
  const w = perpendicular(u);
  const theta = new Float64Array(T);
  for (let t = 1; t < T; t++) {
    const carry = minRotation(d[t - 1], d[t]);
    const tw = matmul(matmul(transpose(swing[t]), carry), swing[t - 1]);   // fixes u
    const twW = mulMv(tw, w);
    const delta = Math.atan2(dot(cross(w, twW), u), dot(twW, w));
    theta[t] = pyMod(theta[t - 1] + delta + Math.PI, 2 * Math.PI) - Math.PI;
    if (!(dot(d[t], u) < -0.7)) theta[t] *= relax;   // near the flip the swing is ill-conditioned: keep the twist
  }
  return swing.map((s, t) => matmul(s, axisAngle(u, theta[t])));
}

/** The rotation R minimising sum_k |R src_k - dst_k|^2 (Horn's unit-quaternion solution). */
function kabsch(src, dst) {
  const S = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];   // sum_k src_k dst_k^T
  src.forEach((a, k) => {
    const b = dst[k];
    for (let i = 0; i < 3; i++) for (let j = 0; j < 3; j++) S[i][j] += a[i] * b[j];
  });
  const [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = S;
  const N = [
    [xx + yy + zz, yz - zy, zx - xz, xy - yx],
    [yz - zy, xx - yy - zz, xy + yx, zx + xz],
    [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
    [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
  ];
  const { values, vectors } = jacobiEigen(N);
  let best = 0;
  for (let i = 1; i < 4; i++) if (values[i] > values[best]) best = i;
  return quaternionToMatrix(vectors.map((row) => row[best]));
}

function quaternionToMatrix([w, x, y, z]) {
  const n = Math.hypot(w, x, y, z);
  w /= n; x /= n; y /= n; z /= n;
  return [
    [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
  ];
}

/** Eigenvalues and eigenvectors (columns) of a small symmetric matrix, by cyclic Jacobi rotations. */
function jacobiEigen(matrix) {
  const n = matrix.length;
  const a = matrix.map((row) => row.slice());
  const v = Array.from({ length: n }, (_, i) => Array.from({ length: n }, (__, j) => (i === j ? 1 : 0)));
  for (let sweep = 0; sweep < 64; sweep++) {
    let off = 0, diag = 0;
    for (let i = 0; i < n; i++) {
      diag += a[i][i] * a[i][i];
      for (let j = i + 1; j < n; j++) off += a[i][j] * a[i][j];
    }
    if (off <= 1e-34 * diag || off === 0) break;
    for (let p = 0; p < n - 1; p++) {
      for (let q = p + 1; q < n; q++) {
        if (a[p][q] === 0) continue;
        const theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
        const t = Math.sign(theta || 1) / (Math.abs(theta) + Math.sqrt(theta * theta + 1));
        const c = 1 / Math.sqrt(t * t + 1), s = t * c;
        for (let k = 0; k < n; k++) {   // a <- a J (columns p, q)
          const akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (let k = 0; k < n; k++) {   // a <- J^T a (rows p, q)
          const apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (let k = 0; k < n; k++) {
          const vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
  return { values: a.map((row, i) => row[i]), vectors: v };
}

/** Smallest rotation taking unit a to unit b (any half-turn axis if b = -a). */
function minRotation(a, b) {
  const axis = cross(a, b);
  const sin = norm(axis), cos = dot(a, b);
  const unit = sin > 1e-12 ? scale(axis, 1 / Math.max(sin, 1e-300)) : perpendicular(a);
  return axisAngle(unit, Math.atan2(sin, cos));
}

/** Rodrigues: the rotation by `angle` about unit `axis`, as numpy builds it (I + s K + (1 - c) K K). */
function axisAngle([x, y, z], angle) {
  const K = [[0, -z, y], [z, 0, -x], [-y, x, 0]];
  const KK = matmul(K, K);
  const s = Math.sin(angle), c = Math.cos(angle);
  return K.map((row, i) => row.map((kij, j) => (i === j ? 1 : 0) + s * kij + (1 - c) * KK[i][j]));
}

function perpendicular(u) {
  const helper = Math.abs(u[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0];
  return normalise(cross(u, helper), [0, 0, 1]);
}

function normalise(v, fallback) {
  const n = norm(v);
  return n > 1e-12 ? scale(v, 1 / Math.max(n, 1e-300)) : fallback;
}

/** Whether the rows of `vectors` lie on one line (second singular value negligible against the first). */
function collinear(vectors) {
  const G = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
  for (const v of vectors) for (let i = 0; i < 3; i++) for (let j = 0; j < 3; j++) G[i][j] += v[i] * v[j];
  const s = jacobiEigen(G).values.map((e) => Math.sqrt(Math.max(e, 0))).sort((p, q) => q - p);
  return vectors.length < 2 || s[1] < 1e-6 * Math.max(s[0], 1e-12);
}

// ---- Euler angles ----------------------------------------------------------------------------------------

/** (T, N) rotations -> (T, N, 3) radians, intrinsic `order` (angles listed in that order), continuous in time. */
function continuousEuler(rot, T, N, order) {
  const [i, j, k] = [...order].map((a) => 'XYZ'.indexOf(a));
  const e = [[0, 1, 2], [1, 2, 0], [2, 0, 1]].some(([a, b, c]) => a === i && b === j && c === k) ? 1 : -1;
  const out = [];
  for (let t = 0; t < T; t++) {
    const prev = t ? out[t - 1] : Array.from({ length: N }, () => [0, 0, 0]);
    const row = [];
    for (let n = 0; n < N; n++) {
      const R = rot[t][n];
      const mid = Math.asin(Math.min(Math.max(e * R[i][k], -1), 1));
      let angles = [Math.atan2(-e * R[j][k], R[k][k]), mid, Math.atan2(-e * R[i][j], R[i][i])];
      if (Math.cos(mid) < 1e-7) {   // gimbal lock: keep the previous `last` angle, solve `first` from the rest
        const rest = matmul(R, transpose(axisAngle(unitAxis(k), prev[n][2])));
        angles = [Math.atan2(e * rest[k][j], rest[j][j]), mid, prev[n][2]];
      }
      if (t > 0) {
        const a = unwrap(angles, prev[n]);
        const b = unwrap([angles[0] + Math.PI, Math.PI - angles[1], angles[2] + Math.PI], prev[n]);   // the same rotation
        angles = squaredDistance(b, prev[n]) < squaredDistance(a, prev[n]) ? b : a;
      }
      row.push(angles);
    }
    out.push(row);
  }
  return out;
}

function unwrap(x, prev) {
  const twoPi = 2 * Math.PI;
  return x.map((v, i) => v + twoPi * roundHalfEven((prev[i] - v) / twoPi));
}

function squaredDistance(a, b) {
  const x = a[0] - b[0], y = a[1] - b[1], z = a[2] - b[2];
  return x * x + y * y + z * z;
}

function unitAxis(k) {
  return [0, 1, 2].map((i) => (i === k ? 1 : 0));
}

// ---- text ------------------------------------------------------------------------------------------------

function format(pos, T, offsets, euler, sk, fps, unitScale) {
  for (const n of sk.names) {
    if (!n || /\s/.test(n)) throw new RangeError(`skeleton ${sk.name}: joint name ${JSON.stringify(n)} cannot be written to BVH (empty or has spaces)`);
  }
  const J = sk.parents.length;
  const lines = ['HIERARCHY'];
  const vec = (v) => v.map(fixed6).join(' ');
  const joint = (j, depth) => {
    const ind = '\t'.repeat(depth);
    const root = sk.parents[j] < 0;
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
  for (let t = 0; t < T; t++) {
    const values = scale(at(pos, J, t, sk.root), unitScale);
    for (const j of sk.order) for (const a of euler[t][j]) values.push(a * DEG);
    lines.push(values.map(fixed6).join(' '));
  }
  return `${lines.join('\n')}\n`;
}

const fixed6 = (v) => fixed(v, 6);

/**
 * Python's f"{v:.{digits}f}": the exact binary value rounded half to even (toFixed rounds exact ties up), and
 * "-0.000000" for negative zero and small negatives alike.
 */
export function fixed(v, digits) {
  let s = Math.abs(v).toFixed(30);   // exact digits of a double this far (ties at `digits` need <= 8 of them)
  const point = s.indexOf('.');
  const keep = s.slice(0, point + 1 + digits), rest = s.slice(point + 1 + digits);
  const tie = rest[0] === '5' && /^50*$/.test(rest);
  if (tie) {
    const last = Number(keep[keep.length - 1]);
    s = last % 2 ? Math.abs(v).toFixed(digits) : keep;   // odd: up (what toFixed does), even: stay
  } else {
    s = Math.abs(v).toFixed(digits);
  }
  return (v < 0 || Object.is(v, -0) ? '-' : '') + s;
}

// ---- small linear algebra (row-major 3x3, vectors as arrays) --------------------------------------------

const IDENTITY = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];

function at(pos, J, t, j) {
  const o = (t * J + j) * 3;
  return [pos[o], pos[o + 1], pos[o + 2]];
}

function sub(a, b) {
  return [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
}

function scale(a, s) {
  return [a[0] * s, a[1] * s, a[2] * s];
}

function dot(a, b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

function norm(a) {
  return Math.sqrt(dot(a, a));
}

function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}

function transpose(m) {
  return [[m[0][0], m[1][0], m[2][0]], [m[0][1], m[1][1], m[2][1]], [m[0][2], m[1][2], m[2][2]]];
}

function matmul(a, b) {
  return a.map((row) => [0, 1, 2].map((j) => row[0] * b[0][j] + row[1] * b[1][j] + row[2] * b[2][j]));
}

function mulMv(m, v) {
  return m.map((row) => dot(row, v));
}

/** m^T v */
function mulTv(m, v) {
  return [0, 1, 2].map((i) => m[0][i] * v[0] + m[1][i] * v[1] + m[2][i] * v[2]);
}

/** Python's float % for a positive modulus: the result has the modulus's sign. */
function pyMod(x, m) {
  const r = x % m;
  return r !== 0 && r < 0 ? r + m : r === 0 ? 0 : r;
}

/** numpy's round: halves to even. */
function roundHalfEven(x) {
  const r = Math.round(x);
  return Math.abs(x % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
}
