// Planted feet for a steered character (runtime/mogo_runtime/control/plant.py, where the why is): a toe on the
// floor stays where it touched down while the steering moves the body under it, and the leg reaches it (two-bone
// IK, bone lengths kept); a lifted foot goes back to the motion's path; a foot out of reach slides only as far as
// it must. The same float64 arithmetic on the float32 joints as Python's, then float32 again: the same bits.

export const PLANT_HEIGHT = 0.05;   // m: a toe below this is on the floor
export const RELEASE = 0.7;         // of a lifted foot's offset kept a frame
export const REACH = 0.995;         // of the leg's length (thigh + shin): the farthest the ankle goes from the hip
export const STATE_FLOATS = 8;      // state()'s floats for two legs

/** Each leg (left, right) as [hip, knee, ankle, ..., toe]: the chain from the root's child down to the toe. */
export function legsOf(skeleton) {
  const p = skeleton.parents, root = p.indexOf(-1);
  return [skeleton.footLeft[1], skeleton.footRight[1]].map((toe) => {
    const chain = [toe];
    while (p[chain[chain.length - 1]] !== root) chain.push(p[chain[chain.length - 1]]);
    if (chain.length < 4) {
      throw new RangeError(`skeleton ${skeleton.name}: a leg of hip, knee, ankle and toe is needed to plant feet`);
    }
    return chain.reverse();
  });
}

export class FootPlant {
  constructor(legs) {
    this.legs = legs;
    this.pins = legs.map(() => null);          // a planted toe's [x, z]
    this.offsets = legs.map(() => [0, 0]);     // the foot's shift on the last frame
  }

  /**
   * Frames (n, J, 3) flat Float32Array of `frameSize` values each, in order after the last ones applied -> the same
   * with planted feet. `moved`: whether the steering moved them (one boolean, or one per frame).
   */
  apply(joints, frameSize, moved) {
    const n = joints.length / frameSize;
    const flags = typeof moved === 'boolean' ? new Array(n).fill(moved) : moved;
    if (!flags.some(Boolean) && !this.pins.some((p) => p !== null)
      && !this.offsets.some(([dx, dz]) => dx !== 0 || dz !== 0)) return joints;
    const out = joints.slice();
    const v = new Float64Array(frameSize);
    for (let f = 0; f < n; f++) {
      const o = f * frameSize;
      for (let j = 0; j < frameSize; j++) v[j] = out[o + j];   // float64 values of the float32 joints
      for (let i = 0; i < this.legs.length; i++) this.#leg(i, this.legs[i], v, flags[f]);
      out.set(v, o);   // float32 again
    }
    return out;
  }

  #leg(i, leg, v, moved) {
    const h = 3 * leg[0], k = 3 * leg[1], a = 3 * leg[2], t = 3 * leg[leg.length - 1];
    let pin = this.pins[i];
    let dx, dz;
    if (moved && v[t + 1] < PLANT_HEIGHT) {
      if (pin === null) pin = [v[t] + this.offsets[i][0], v[t + 2] + this.offsets[i][1]];
      dx = pin[0] - v[t];
      dz = pin[1] - v[t + 2];
    } else {
      pin = null;
      dx = this.offsets[i][0] * RELEASE;
      dz = this.offsets[i][1] * RELEASE;
    }
    const l1 = distance(v, h, k), l2 = distance(v, k, a);
    const reach = REACH * (l1 + l2);
    const bx = v[a] - v[h], by = v[a + 1] - v[h + 1], bz = v[a + 2] - v[h + 2];
    const ex = bx + dx, ez = bz + dz;
    if (ex * ex + by * by + ez * ez > reach * reach) {
      const qa = dx * dx + dz * dz;
      const qb = 2.0 * (bx * dx + bz * dz);
      const qc = bx * bx + by * by + bz * bz - reach * reach;
      const s = qc >= 0.0 ? 0.0 : (-qb + Math.sqrt(qb * qb - 4.0 * qa * qc)) / (2.0 * qa);
      dx *= s;
      dz *= s;
      if (pin !== null) pin = [v[t] + dx, v[t + 2] + dz];
    }
    this.pins[i] = pin;
    this.offsets[i] = [dx, dz];
    if (dx === 0.0 && dz === 0.0) return;
    for (let j = 2; j < leg.length; j++) {   // the foot, ankle to toe
      v[3 * leg[j]] += dx;
      v[3 * leg[j] + 2] += dz;
    }
    placeKnee(v, h, k, a, l1, l2);
  }

  /** [pinned per leg, [pin x, z, offset x, z] per leg]: all a stream's later joints depend on. */
  state() {
    const floats = [];
    for (let i = 0; i < this.legs.length; i++) floats.push(...(this.pins[i] ?? [0, 0]), ...this.offsets[i]);
    return [this.pins.map((p) => p !== null), floats];
  }

  /** state()'s values back. */
  load(pinned, floats) {
    for (let i = 0; i < this.legs.length; i++) {
      const [x, z, dx, dz] = Array.from(floats.slice(4 * i, 4 * i + 4), Number);
      this.pins[i] = pinned[i] ? [x, z] : null;
      this.offsets[i] = [dx, dz];
    }
  }
}

function distance(v, p, q) {
  const x = v[q] - v[p], y = v[q + 1] - v[p + 1], z = v[q + 2] - v[p + 2];
  return Math.sqrt(x * x + y * y + z * z);
}

/** The knee of the leg from hip to ankle with thigh l1 and shin l2, bent the way the motion's knee is (in place). */
function placeKnee(v, h, k, a, l1, l2) {
  const vx = v[a] - v[h], vy = v[a + 1] - v[h + 1], vz = v[a + 2] - v[h + 2];
  const d = Math.sqrt(vx * vx + vy * vy + vz * vz);
  if (d === 0.0) return;
  const ux = vx / d, uy = vy / d, uz = vz / d;
  const along = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d);
  let side = Math.sqrt(Math.max(l1 * l1 - along * along, 0.0));
  const kx = v[k] - v[h], ky = v[k + 1] - v[h + 1], kz = v[k + 2] - v[h + 2];
  const dot = kx * ux + ky * uy + kz * uz;
  const px = kx - dot * ux, py = ky - dot * uy, pz = kz - dot * uz;
  let n = Math.sqrt(px * px + py * py + pz * pz);
  if (n === 0.0) {
    side = 0.0;
    n = 1.0;
  }
  const x = v[h] + along * ux + side * (px / n);
  const y = v[h + 1] + along * uy + side * (py / n);
  const z = v[h + 2] + along * uz + side * (pz / n);
  v[k] = x;
  v[k + 1] = y;
  v[k + 2] = z;
}
