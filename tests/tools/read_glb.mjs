// Reads .glb files as a web game would: three.js's GLTFLoader, an AnimationMixer playing the clip once, and each
// bone's world position at every frame; and validates each file with Khronos's glTF validator.
//   node read_glb.mjs JOBS.json OUT.json     JOBS: [{"file": "...glb", "frames": T, "fps": 20}, ...]
// OUT: {file: {"names": [...], "frames": [[[x, y, z] per bone] per frame], "validator": {errors, warnings, messages}}}
import fs from 'node:fs';
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import validator from 'gltf-validator';

const [jobsPath, outPath] = process.argv.slice(2);
const out = {};
for (const job of JSON.parse(fs.readFileSync(jobsPath, 'utf8'))) {
  const bytes = fs.readFileSync(job.file);
  const report = await validator.validateBytes(new Uint8Array(bytes), { maxIssues: 100 });
  const ab = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
  const gltf = await new Promise((resolve, reject) => new GLTFLoader().parse(ab, '', resolve, reject));
  const mixer = new THREE.AnimationMixer(gltf.scene);
  const action = mixer.clipAction(gltf.animations[0]);
  action.setLoop(THREE.LoopOnce, 1);
  action.clampWhenFinished = true;          // the last frame is held, not wrapped to the first
  action.play();
  const bones = [];
  gltf.scene.traverse((o) => { if (o.isBone) bones.push(o); });
  const frames = [];
  const v = new THREE.Vector3();
  for (let t = 0; t < job.frames; t++) {
    mixer.setTime(t / job.fps);
    gltf.scene.updateMatrixWorld(true);
    frames.push(bones.map((b) => b.getWorldPosition(v).toArray()));
  }
  out[job.file] = {
    names: bones.map((b) => b.name),
    frames,
    skinnedMeshes: gltf.scene.getObjectsByProperty('isSkinnedMesh', true).length,
    validator: {
      errors: report.issues.numErrors, warnings: report.issues.numWarnings,
      messages: report.issues.messages.map((m) => `${m.severity} ${m.code} ${m.message} ${m.pointer ?? ''}`),
    },
  };
}
fs.writeFileSync(outPath, JSON.stringify(out));
