// Inverse kinematics: joint positions -> joint rotations that reproduce them, ported from
// runtime/mogo_runtime/outputs/ik.py, whose docstring says why each step. Two differences, both below the BVH's
// rounding: the best-fit rotation (Kabsch) comes from Horn's quaternion method instead of an SVD (the same unique
// optimum), and a set of bones' singular values from their Gram matrix. Vectors are [x, y, z] arrays, rotations
// 3x3 row-major arrays of rows, float64 throughout.

const TWIST_RELAX_S = 0.25;   // a carried-over twist relaxes back to the swing with this time constant (seconds)
export const IDENTITY = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];

export const at = (pos, J, t, j) => Array.from(pos.subarray((t * J + j) * 3, (t * J + j + 1) * 3));
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const norm = (a) => Math.sqrt(dot(a, a));
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const transpose = (m) => [0, 1, 2].map((j) => [m[0][j], m[1][j], m[2][j]]);
export const matmul = (a, b) => a.map((row) => [0, 1, 2].map((j) => row[0] * b[0][j] + row[1] * b[1][j] + row[2] * b[2][j]));
const mulMv = (m, v) => m.map((row) => dot(row, v));
const mulTv = (m, v) => [0, 1, 2].map((i) => m[0][i] * v[0] + m[1][i] * v[1] + m[2][i] * v[2]);   // m^T v
const bones = (pos, J, t, j, children) => children.map((c) => sub(at(pos, J, t, c), at(pos, J, t, j)));

/**
 * (J, 3) rest bone vectors fitted to a clip: each bone the skeleton's rest direction (`sk.dirs`) times its median
 * length, and a joint with several children their rigid best-fit layout (generalised Procrustes), turned to lie
 * as near the rest directions as it can.
 */
export function restOffsets(pos, T, sk) {
  const J = sk.parents.length, offsets = sk.parents.map(() => [0, 0, 0]);
  sk.parents.forEach((p, j) => {
    if (p < 0) return;
    const length = median(Array.from({ length: T }, (_, t) => norm(sub(at(pos, J, t, j), at(pos, J, t, p)))));
    if (length < 1e-6) {
      throw new RangeError(`bone ${sk.names[p]} -> ${sk.names[j]} has zero length in the clip (median over frames); `
        + 'cannot build a skeleton');
    }
    offsets[j] = scale(sk.dirs[j], length);
  });
  sk.children.forEach((ch, j) => {
    if (ch.length < 2) return;
    const seen = Array.from({ length: T }, (_, t) => bones(pos, J, t, j, ch));   // (T, k, 3)
    let shape = ch.map((c) => offsets[c]);
    for (let pass = 0; pass < 3; pass++) {   // exact after one pass on rigid data; more passes for noisy clips
      const sums = ch.map(() => [0, 0, 0]);
      for (const frame of seen) {
        const rot = kabsch(shape, frame);
        frame.forEach((b, k) => mulTv(rot, b).forEach((x, i) => { sums[k][i] += x; }));
      }
      shape = sums.map((s) => s.map((x) => x / T));
    }
    const turn = kabsch(shape, ch.map((c) => offsets[c]));
    ch.forEach((c, k) => { offsets[c] = mulMv(turn, shape[k]); });
  });
  return offsets;
}

function median(values) {
  const s = Float64Array.from(values).sort(), h = s.length >> 1;
  return s.length % 2 ? s[h] : (s[h - 1] + s[h]) / 2;
}

/** (T, J) rotations, each relative to its parent's, both measured from the rest pose (joints depth first). */
export function localRotations(pos, T, sk, offsets, fps) {
  const J = sk.parents.length, relax = Math.exp(-1 / (fps * TWIST_RELAX_S));
  const glob = Array.from({ length: T }, () => new Array(J)), local = Array.from({ length: T }, () => new Array(J));
  for (const j of sk.order) {
    const p = sk.parents[j], ch = sk.children[j], parentOf = (t) => (p >= 0 ? glob[t][p] : IDENTITY);
    if (ch.length >= 2 && !collinear(ch.map((c) => offsets[c]))) {
      for (let t = 0; t < T; t++) {
        glob[t][j] = kabsch(ch.map((c) => offsets[c]), bones(pos, J, t, j, ch));
        local[t][j] = matmul(transpose(parentOf(t)), glob[t][j]);
      }
    } else if (ch.length) {   // one child, or children on one line: the first one sets the rotation
      const d = Array.from({ length: T }, (_, t) => mulTv(parentOf(t), bones(pos, J, t, j, [ch[0]])[0]));
      swingWithContinuousTwist(offsets[ch[0]], d, relax).forEach((rot, t) => {
        local[t][j] = rot;
        glob[t][j] = matmul(parentOf(t), rot);
      });
    } else {
      for (let t = 0; t < T; t++) [local[t][j], glob[t][j]] = [IDENTITY, parentOf(t)];
    }
  }
  return local;
}

/** Rotations taking direction u to each d[t]: the pure swing, with a twist about u carried where the swing jumps. */
function swingWithContinuousTwist(u0, dRaw, relax) {
  const u = scale(u0, 1 / norm(u0)), d = dRaw.map((v) => unit(v, u)), swing = d.map((v) => minRotation(u, v));
  const w = perpendicular(u), theta = new Float64Array(d.length);
  for (let t = 1; t < d.length; t++) {
    const tw = matmul(matmul(transpose(swing[t]), minRotation(d[t - 1], d[t])), swing[t - 1]);   // fixes u
    const twW = mulMv(tw, w);
    const delta = Math.atan2(dot(cross(w, twW), u), dot(twW, w));
    const r = (theta[t - 1] + delta + Math.PI) % (2 * Math.PI);   // Python's %: the result has the modulus's sign
    theta[t] = (r < 0 ? r + 2 * Math.PI : r === 0 ? 0 : r) - Math.PI;
    if (!(dot(d[t], u) < -0.7)) theta[t] *= relax;   // near the flip the swing is ill-conditioned: keep the twist
  }
  return swing.map((s, t) => matmul(s, axisAngle(u, theta[t])));
}

/** The rotation R minimising sum_k |R src_k - dst_k|^2 (Horn's unit-quaternion solution). */
function kabsch(src, dst) {
  const S = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];   // sum_k src_k dst_k^T
  src.forEach((a, k) => { for (let i = 0; i < 3; i++) for (let j = 0; j < 3; j++) S[i][j] += a[i] * dst[k][j]; });
  const [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = S;
  const { values, vectors } = jacobiEigen([
    [xx + yy + zz, yz - zy, zx - xz, xy - yx],
    [yz - zy, xx - yy - zz, xy + yx, zx + xz],
    [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
    [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
  ]);
  let best = 0;
  for (let i = 1; i < 4; i++) if (values[i] > values[best]) best = i;
  const q = vectors.map((row) => row[best]), n = Math.hypot(...q), [w, x, y, z] = q.map((c) => c / n);
  return [
    [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
  ];
}

/** Eigenvalues and eigenvectors (columns) of a small symmetric matrix, by cyclic Jacobi rotations. */
function jacobiEigen(matrix) {
  const n = matrix.length, a = matrix.map((row) => row.slice());
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
        rotate(a, p, q, c, s, false);   // a <- a J
        rotate(a, p, q, c, s, true);    // a <- J^T a
        rotate(v, p, q, c, s, false);
      }
    }
  }
  return { values: a.map((row, i) => row[i]), vectors: v };
}

/** The Jacobi rotation (c, s) applied to columns p, q of m, or to rows p, q. */
function rotate(m, p, q, c, s, rows) {
  for (let k = 0; k < m.length; k++) {
    const [i1, j1, i2, j2] = rows ? [p, k, q, k] : [k, p, k, q];
    const x = m[i1][j1], y = m[i2][j2];
    m[i1][j1] = c * x - s * y;
    m[i2][j2] = s * x + c * y;
  }
}

/** Smallest rotation taking unit a to unit b (any half-turn axis if b = -a). */
function minRotation(a, b) {
  const axis = cross(a, b), sin = norm(axis);
  return axisAngle(sin > 1e-12 ? scale(axis, 1 / Math.max(sin, 1e-300)) : perpendicular(a), Math.atan2(sin, dot(a, b)));
}

/** Rodrigues: the rotation by `angle` about unit `axis`, as numpy builds it (I + s K + (1 - c) K K). */
export function axisAngle([x, y, z], angle) {
  const K = [[0, -z, y], [z, 0, -x], [-y, x, 0]], KK = matmul(K, K), s = Math.sin(angle), c = Math.cos(angle);
  return K.map((row, i) => row.map((kij, j) => (i === j ? 1 : 0) + s * kij + (1 - c) * KK[i][j]));
}

const perpendicular = (u) => unit(cross(u, Math.abs(u[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0]), [0, 0, 1]);

function unit(v, fallback) {
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
