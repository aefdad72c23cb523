// The control vector: where the game wants the character's root over the next `horizon` tokens, as the step graph
// reads it (docs/bundle.md, "Control"; runtime/mogo_runtime/control/vector.py, which this mirrors operation for
// operation in float64, so that the float32 vector, and with it the picked tokens, match Python's).
//
// A root pose is [x, z, yaw]: metres on the floor, y up, facing the world direction (sin yaw, cos yaw), so yaw 0
// faces +z. The control of the step that picks token j is read in the frame of the root at frame j * downsample:
//
//     [present, then for k = 1 .. horizon: x_k, z_k, sin(yaw_k - yaw_0), cos(yaw_k - yaw_0)]
//
// present = 0 and all zeros: no control.

export const FIELDS = 4;   // per horizon step: x, z, sin, cos

export function controlDim(horizon) { return 1 + FIELDS * horizon; }

/** A world point [x, z] -> the same in the frame of root pose `now` [x, z, yaw]. */
export function toLocal(now, [x, z]) {
  const dx = x - now[0], dz = z - now[1], c = Math.cos(now[2]), s = Math.sin(now[2]);
  return [dx * c - dz * s, dx * s + dz * c];
}

/** Inverse of `toLocal`: a point [x, z] in the frame of `now` -> world [x, z]. */
export function toWorld(now, [x, z]) {
  const c = Math.cos(now[2]), s = Math.sin(now[2]);
  return [x * c + z * s + now[0], -x * s + z * c + now[1]];
}

/** Root pose now and the wanted poses (horizon of [x, z, yaw]) one token apart -> the control vector. */
export function encode(now, future) {
  const out = new Float32Array(controlDim(future.length));   // storing rounds as numpy's astype(float32)
  out[0] = 1;
  future.forEach((pose, k) => {
    const [x, z] = toLocal(now, pose), turn = pose[2] - now[2];
    out.set([x, z, Math.sin(turn), Math.cos(turn)], 1 + FIELDS * k);
  });
  return out;
}

/** A present control vector read back as world poses (horizon of [x, z, yaw]) from root pose `now`. */
export function decode(now, vector) {
  const poses = [];
  for (let i = 1; i + FIELDS <= vector.length; i += FIELDS) {
    const [x, z] = toWorld(now, [vector[i], vector[i + 1]]);
    poses.push([x, z, now[2] + Math.atan2(vector[i + 2], vector[i + 3])]);
  }
  return poses;
}
