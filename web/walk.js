// Click to walk: on a bundle whose model has control (docs/bundle.md, "Control"), a click on the ground of the view
// sends the streaming character there (the runtime's walkTo, js/src/control/). The page (app.js) wires it up; the
// worker makes the request between two frames, so it lands at the stream's next token.
//
//   onGroundClick(viewer, ([x, z]) => worker.postMessage({ type: 'walkTo', id, goal: [x, z] }));

import * as THREE from 'three';

const CLICK_PIXELS = 5;   // a press that moves further is the orbit camera's drag, not a click
const MAX_REACH = 50;     // metres from the camera's target: a click near the horizon lands kilometres away
const GROUND = new THREE.Plane(new THREE.Vector3(0, 1, 0), 0);

/** The ground point [x, z] (y = 0) under the client pixel (x, y) of `viewer`'s canvas, or null (the sky, too far). */
export function groundPoint(viewer, clientX, clientY) {
  const rect = viewer.canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2(((clientX - rect.left) / rect.width) * 2 - 1, 1 - ((clientY - rect.top) / rect.height) * 2);
  const raycaster = new THREE.Raycaster();
  raycaster.setFromCamera(ndc, viewer.camera);
  const hit = raycaster.ray.intersectPlane(GROUND, new THREE.Vector3());
  if (!hit || hit.distanceTo(viewer.controls.target) > MAX_REACH) return null;
  return [hit.x, hit.z];
}

/** The view's camera and canvas, from which a click is turned into a ground point (for the page's test). */
export function cameraState({ camera, canvas }) {
  const r = canvas.getBoundingClientRect();
  return { position: camera.position.toArray(), quaternion: camera.quaternion.toArray(), fov: camera.fov,
    aspect: camera.aspect, rect: { left: r.left, top: r.top, width: r.width, height: r.height } };
}

/** `onGround([x, z])` for every click (a press and release of the main button that does not drag) on the ground. */
export function onGroundClick(viewer, onGround) {
  let down = null;
  viewer.canvas.addEventListener('pointerdown', (e) => { down = e.button === 0 ? [e.clientX, e.clientY] : null; });
  viewer.canvas.addEventListener('pointerup', (e) => {
    const press = down;
    down = null;
    if (!press || Math.hypot(e.clientX - press[0], e.clientY - press[1]) > CLICK_PIXELS) return;
    const point = groundPoint(viewer, e.clientX, e.clientY);
    if (point) onGround(point);
  });
}

/** A ring on the ground where the character was sent (grey: the skeleton keeps the only saturated colours). */
export class GoalMarker {
  constructor(scene) {
    this.mesh = new THREE.Mesh(new THREE.RingGeometry(0.16, 0.22, 40),
      new THREE.MeshBasicMaterial({ color: 0xd8d8d8, side: THREE.DoubleSide }));
    this.mesh.rotation.x = -Math.PI / 2;   // the ring's plane onto the ground
    this.mesh.visible = false;
    scene.add(this.mesh);
  }

  show([x, z]) {
    this.mesh.position.set(x, 0.005, z);
    this.mesh.visible = true;
  }

  hide() { this.mesh.visible = false; }
}
