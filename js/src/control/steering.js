// One stream's control (runtime/mogo_runtime/control/steering.py): the game's request (a target from targets.js, or
// none), the root pose the stream's frames have reached, and the control vector its next token is picked with.
//
//   const steering = new Steering(spec, dims, context, legs);   // context: the stream's StreamContext; legs: legsOf
//   steering.request(() => new WalkTo([4, 2]));          // between two frames
//   steering.update(nextIndex, frameJoints);             // after each token's frames: the pose read, the next
//                                                         // token's control handed to the context
//   joints = steering.place(index, joints);              // a frame as shown: on the game's capsule when it owns the root
//
// The pose is that of the next frame, which the frames so far fix, so the control of token j is read from the root
// at frame j * downsample exactly as training read it. A steered stream makes its frames every token (a chunk of 1).

import { FollowPath, GameRoot, Steer, WalkTo } from './targets.js';
import { controlDim, encode } from './vector.js';
import { RootWarp, wrap } from './warp.js';

export class Steering {
  /** `legs`: [hip, knee, ankle, toe] of each leg (plant.js legsOf) to plant the feet of the frames moved. */
  constructor(spec, dims, context, legs) {
    if (spec.dim !== controlDim(spec.horizon)) {
      throw new RangeError(`control dim ${spec.dim} does not match a horizon of ${spec.horizon} tokens`);
    }
    Object.assign(this, { spec, fps: dims.fps, context });
    this.times = Array.from({ length: spec.horizon }, (_, k) => ((k + 1) * dims.downsample) / dims.fps);   // seconds ahead
    this.downsample = dims.downsample;
    this.warp = new RootWarp(legs);
    this.target = null;
    this.pose = [0, 0, 0];   // the root of the next frame: frame 0 stands at the origin facing +z
    this.frame = 0;          // the next frame's index
  }

  /** The control vector of the next token: zeros without a target. */
  vector() {
    return this.target === null ? new Float32Array(this.spec.dim) : encode(this.pose, this.wanted());
  }

  /** The target's wanted poses (horizon of [x, z, yaw]) from the pose now. */
  wanted() {
    if (this.target instanceof GameRoot) return this.target.future(this.pose, this.times, this.fps, this.frame);
    return this.target.future(this.pose, this.times);
  }

  /** `change(this)` -> the new target (null: no control); the next token is picked with it. */
  request(change) {
    this.target = change(this);
    this.context.steer(this.vector());
  }

  /**
   * After a stream's new frames, `index` the next frame's number and `frames` the FrameJoints that made them: read
   * the next frame's pose (the capsule's, when the game owns the root) and hand the next token's control on.
   */
  update(index, frames) {
    const pose = this.warp.pose(frames.nextPose(), index);
    const target = this.target;
    if (target instanceof GameRoot && target.pose !== null) [pose[0], pose[1]] = target.at(index);
    this.pose = pose;
    this.frame = index;
    if (target === null) {
      this.context.steer(this.vector());
      return;
    }
    const wanted = this.wanted();
    this.context.steer(encode(pose, wanted));
    if (!(target instanceof GameRoot)) {   // the next token's correction, toward where it should be (warp.js)
      const reference = target.reference();
      this.warp.plan(index, this.downsample, pose, wrap(wanted[0][2] - pose[2]),
        reference === null ? [0, 0] : [reference[0] - pose[0], reference[1] - pose[1]]);
    }
  }

  /**
   * Frames (n, J, 3) flat, numbered index.., of `frameSize` values each, as shown: moved onto the game's capsule when
   * the game owns the root (where the game last placed it, moved on by its velocity); else with the correction planned
   * for them (`joints` itself while none was); either way with the feet planted (plant.js).
   */
  place(index, joints, frameSize = joints.length) {
    const target = this.target;
    if (!(target instanceof GameRoot) || target.pose === null) return this.warp.joints(index, joints, frameSize);
    if (!joints.length) return joints;
    joints = joints.slice();   // each frame's root onto the capsule there
    for (let o = 0; o < joints.length; o += frameSize) {
      const capsule = target.at(index + o / frameSize);
      const dx = Math.fround(capsule[0] - joints[o]), dz = Math.fround(capsule[1] - joints[o + 2]);
      for (let j = o; j < o + frameSize; j += 3) {
        joints[j] += dx;   // a float32 sum, as numpy's
        joints[j + 2] += dz;
      }
    }
    return this.warp.plant.apply(joints, frameSize, true);
  }
}

/**
 * Where a character goes (a stream's base class): `steering` is its Steering, or null where its bundle's model has
 * no control (`whyNotSteerable` then says why). `checkSteerable` throws where it follows no more requests.
 */
export class Steerable {
  steering = null;

  #steer(change) {
    if (this.steering === null) throw new Error(this.whyNotSteerable());
    this.checkSteerable();
    this.steering.request(change);
  }

  whyNotSteerable() {
    return "this bundle's model was trained without control (its manifest has no 'control' section): its characters "
      + 'go where the model walks them';
  }

  checkSteerable() {}

  /** The number of the next frame the game will be handed (a stream hands out decoded frames one by one). */
  nextShown(s) { return s.frame; }

  /** Walk to `goal` [x, z] (world, metres) at `speed` m/s, then stand there doing the prompt. */
  walkTo(goal, speed = 1.3) {
    const target = new WalkTo(goal, speed);
    this.#steer(() => target);
  }

  /** Follow the polyline `points` ([x, z] in metres) at `speed` m/s, from the point nearest the character. */
  followPath(points, speed = 1.3) {
    const target = new FollowPath(points, speed);
    this.#steer(() => target);
  }

  /** A joystick: move at world `velocity` [vx, vz] m/s, facing `facing` (a world direction) if given. */
  steer(velocity, facing = null) {
    const target = new Steer(velocity, facing);
    this.#steer(() => target);
  }

  /**
   * The game owns the root: its capsule is at (x, z), facing `heading` (radians; 0 faces +z, pi/2 +x) at the next
   * frame this character makes; its frames are put on the capsule, and it moves as the capsule moves.
   */
  setRoot(x, z, heading) {
    new GameRoot().place(x, z, heading, 0);   // checks the numbers before anything changes
    this.#steer((s) => {
      const target = s.target instanceof GameRoot ? s.target : new GameRoot();
      target.place(x, z, heading, this.nextShown(s));
      return target;
    });
  }

  /** Back to text only: the character goes where the model walks it. */
  release() { this.#steer(() => null); }

  /** Whether a walkTo goal or a path's end is reached (false with any other request, or none). */
  get arrived() { return Boolean(this.steering?.target?.arrived); }
}
