// The skeleton on screen (three.js): joints as spheres, bones as cylinders, a ground grid, an orbit camera that
// follows the pelvis, and a player that shows frames at the motion's fps as they arrive.
//
//   const viewer = new SkeletonViewer(canvas, manifest.skeleton);
//   viewer.player.start({ fps: 20, live: true });   viewer.player.push(frame.joints);   // (J * 3) metres, y up
//
// Colours: the left side blue, the right side orange, the spine and head yellow (the model's left/right mix-ups
// are easy to see); everything else on screen is grey, so the skeleton is the only saturated colour.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

export const COLOURS = { left: 0x3fa7ff, right: 0xff7a1a, centre: 0xf2c230 };
const BACKGROUND = 0x1d1f24;
const JOINT_RADIUS = 0.035;
const BONE_RADIUS = 0.018;
const UP = new THREE.Vector3(0, 1, 0);
const GRID_SIZE = 40, GRID_CELL = 0.5;   // metres; the grid moves with the camera a whole cell at a time

export class SkeletonViewer {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{joint_names: string[], parents: number[]}} skeleton
   */
  constructor(canvas, skeleton) {
    this.canvas = canvas;
    this.parents = skeleton.parents;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(BACKGROUND);
    this.scene.fog = new THREE.Fog(BACKGROUND, 5, 16);   // the far grid fades out instead of flickering
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.05, 200);
    this.camera.position.set(2.2, 1.6, 3.4);   // in front of the body (it faces +z), a little to its left
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.target.set(0, 0.9, 0);
    this.controls.enableDamping = true;
    this.follow = true;                        // the camera target tracks the pelvis over the ground

    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x30343c, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(3, 6, 4);
    this.scene.add(sun);
    this.grid = groundGrid(GRID_SIZE, GRID_CELL, 0x5a5f69);
    this.scene.add(this.grid);

    const side = (name) => (name.startsWith('left') ? 'left' : name.startsWith('right') ? 'right' : 'centre');
    const material = (c) => new THREE.MeshStandardMaterial({ color: c, emissive: c, emissiveIntensity: 0.35, roughness: 0.6 });
    const materials = Object.fromEntries(Object.entries(COLOURS).map(([k, c]) => [k, material(c)]));
    const sphere = new THREE.SphereGeometry(1, 20, 14);
    const cylinder = new THREE.CylinderGeometry(1, 1, 1, 12);   // along y, centred: scaled to each bone
    this.joints = skeleton.joint_names.map((name, j) => {
      const mesh = new THREE.Mesh(sphere, materials[side(name)]);
      mesh.scale.setScalar(name === 'head' ? JOINT_RADIUS * 2.2 : JOINT_RADIUS);
      mesh.visible = false;
      this.scene.add(mesh);
      return mesh;
    });
    this.bones = skeleton.parents.map((p, j) => {
      if (p < 0) return null;
      const mesh = new THREE.Mesh(cylinder, materials[side(skeleton.joint_names[j])]);
      mesh.visible = false;
      this.scene.add(mesh);
      return mesh;
    });
    this.player = new Player();
    this.resize();
    new ResizeObserver(() => this.resize()).observe(canvas);
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.canvas;
    if (!w || !h) return;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  /** Place the skeleton at one frame's joints ((J * 3) metres). */
  pose(joints) {
    const p = (j) => new THREE.Vector3(joints[3 * j], joints[3 * j + 1], joints[3 * j + 2]);
    this.joints.forEach((mesh, j) => {
      mesh.position.copy(p(j));
      mesh.visible = true;
    });
    this.bones.forEach((mesh, j) => {
      if (!mesh) return;
      const a = p(this.parents[j]), b = p(j);
      const along = b.clone().sub(a);
      const length = along.length();
      mesh.visible = length > 1e-6;
      if (!mesh.visible) return;
      mesh.position.copy(a).add(b).multiplyScalar(0.5);
      mesh.quaternion.setFromUnitVectors(UP, along.divideScalar(length));
      mesh.scale.set(BONE_RADIUS, length, BONE_RADIUS);
    });
    if (this.follow) {   // move target and camera together: the user's orbit is kept, the body stays in view
      const root = p(0);
      const shift = new THREE.Vector3(root.x - this.controls.target.x, 0, root.z - this.controls.target.z);
      this.controls.target.add(shift);
      this.camera.position.add(shift);
    }
    // a walk never leaves the ground: the grid jumps along under the camera by whole cells (the lines stay put)
    const t = this.controls.target;
    this.grid.position.set(Math.round(t.x / GRID_CELL) * GRID_CELL, 0, Math.round(t.z / GRID_CELL) * GRID_CELL);
  }

  /** Advance the player by dt seconds and draw. */
  frame(dt) {
    const joints = this.player.advance(dt);
    if (joints) this.pose(joints);
    this.controls.update();
    this.renderer.render(this.scene, this.camera);
  }
}

/**
 * Grid lines on the ground (y = 0), one segment per cell edge: software WebGL (SwiftShader, as in headless
 * Chromium) drops a whole line that passes behind the camera, so long lines (three's GridHelper) vanish nearby.
 */
function groundGrid(size, cell, colour) {
  const n = Math.round(size / cell), half = size / 2, points = [];
  for (let i = 0; i <= n; i++) {
    const a = -half + i * cell;
    for (let k = 0; k < n; k++) {
      const b = -half + k * cell;
      points.push(a, 0, b, a, 0, b + cell, b, 0, a, b + cell, 0, a);
    }
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.Float32BufferAttribute(points, 3));
  return new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: colour }));
}

/**
 * Frames in arrival order and a playhead in seconds. A live player (a stream) waits at the newest frame for the
 * next one; a clip loops (or stops at its end).
 */
export class Player {
  constructor() {
    this.frames = [];
    this.fps = 20;
    this.time = 0;
    this.playing = true;
    this.live = false;
    this.loop = true;
    this.stalls = 0;     // frames the playhead had to wait for (generation slower than real time)
  }

  start({ fps, live }) {
    this.frames = [];
    this.fps = fps;
    this.time = 0;
    this.live = live;
    this.stalls = 0;
  }

  push(joints) {
    this.frames.push(joints);
  }

  /** The frame under the playhead. */
  get index() {
    return Math.min(Math.floor(this.time * this.fps + 1e-9), Math.max(this.frames.length - 1, 0));
  }

  /** Frames received but not shown yet. */
  get ahead() {
    return this.frames.length - 1 - this.index;
  }

  advance(dt) {
    if (!this.frames.length) return null;
    if (this.playing) {
      this.time += dt;
      const end = this.frames.length / this.fps;
      if (this.time >= end) {
        if (this.live) {
          if (Math.floor(this.time * this.fps) > this.frames.length - 1) this.stalls += 1;
          this.time = (this.frames.length - 1) / this.fps;   // hold the newest frame until the next arrives
        } else if (this.loop) {
          this.time %= end;
        } else {
          this.time = (this.frames.length - 1) / this.fps;
          this.playing = false;
        }
      }
    }
    return this.frames[this.index];
  }
}
