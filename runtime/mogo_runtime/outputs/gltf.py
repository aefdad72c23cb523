"""glTF 2.0 binary (.glb) output: a rig's skeleton (nodes + skin), one animation, and a simple skinned mesh.

    write_glb("walk.glb", retarget(motion.joints, "mixamo", fps=motion.fps), name=motion.text)

The file holds, in glTF's axes (y up, metres, the character faces +z):
- a node per bone, named as the rig names it, each carrying its rest pose (translation and rotation in its parent's
  axes), under one `Armature` node at the scene's root, plus a skin listing every bone with its inverse bind matrix;
- one animation sampled at the motion's fps (LINEAR): a rotation channel for every bone, a translation channel for
  the bones that move (the hips; a rig's root-motion bone), so an engine can apply it to its own copy of the rig;
- with `mesh=True` (the default), a mesh of one narrow double pyramid per bone, each bound to its bone alone, so a
  viewer shows a figure (glTF viewers draw no bones, and some importers read the skeleton only from a skinned mesh).
Python's pygltflib builds the container; the numbers are float32, as glTF stores them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl

from ..kinematics.quaternion import matrix_to_quaternion
from .files import write_atomic
from .retarget import RigMotion

GENERATOR = "mogo"
_FLOAT, _UBYTE, _USHORT = gl.FLOAT, gl.UNSIGNED_BYTE, gl.UNSIGNED_SHORT
_BONE_WIDTH = 0.12          # the pyramid's half-width at its widest, as a fraction of the bone's length
_MIN_DRAWN = 0.01           # metres: bones shorter than this get no pyramid


def write_glb(path, anim: RigMotion, name: str = "motion", mesh: bool = True, extras: dict | None = None) -> Path:
    """Write `anim` as a .glb file at `path` (atomically). Returns the path."""
    data = glb_bytes(anim, name, mesh, extras)
    return write_atomic(Path(path), lambda f: f.write(data))


def glb_bytes(anim: RigMotion, name: str = "motion", mesh: bool = True, extras: dict | None = None) -> bytes:
    """The .glb file's bytes (see the module docstring)."""
    rig = anim.rig
    B, T = rig.num_bones, anim.num_frames
    doc = _Builder()
    rest_t, rest_r = rig.rest_local
    rest_q = matrix_to_quaternion(rest_r)
    doc.gltf.nodes = [gl.Node(name=n, translation=_floats(rest_t[b]), rotation=_xyzw(rest_q[b]),
                              children=list(rig.children[b])) for b, n in enumerate(rig.bone_names)]
    root = rig.parents.index(-1)
    armature = len(doc.gltf.nodes)
    doc.gltf.nodes.append(gl.Node(name="Armature", children=[root]))
    scene_nodes = [armature]

    bind = np.tile(np.eye(4), (B, 1, 1))
    bind[:, :3, :3], bind[:, :3, 3] = rig.rest_rotations, rig.heads
    ibm = doc.add(np.linalg.inv(bind).transpose(0, 2, 1).reshape(B, 16), gl.MAT4)       # column-major
    doc.gltf.skins = [gl.Skin(name=rig.name, joints=list(range(B)), inverseBindMatrices=ibm, skeleton=root)]

    if mesh:
        positions, normals, joints = _bone_pyramids(rig)
        attrs = gl.Attributes(POSITION=doc.add(positions, gl.VEC3, minmax=True, target=gl.ARRAY_BUFFER),
                              NORMAL=doc.add(normals, gl.VEC3, target=gl.ARRAY_BUFFER),
                              JOINTS_0=doc.add(np.pad(joints[:, None], ((0, 0), (0, 3))).astype(
                                  np.uint8 if B < 256 else np.uint16), gl.VEC4, target=gl.ARRAY_BUFFER),
                              WEIGHTS_0=doc.add(np.tile([1.0, 0.0, 0.0, 0.0], (len(joints), 1)), gl.VEC4,
                                                target=gl.ARRAY_BUFFER))
        doc.gltf.materials = [gl.Material(name="figure", pbrMetallicRoughness=gl.PbrMetallicRoughness(
            baseColorFactor=[0.72, 0.72, 0.70, 1.0], metallicFactor=0.0, roughnessFactor=0.8), doubleSided=True)]
        doc.gltf.meshes = [gl.Mesh(name=f"{rig.name}_figure", primitives=[gl.Primitive(attributes=attrs, material=0)])]
        scene_nodes.append(len(doc.gltf.nodes))
        doc.gltf.nodes.append(gl.Node(name=f"{rig.name}_figure", mesh=0, skin=0))

    times = doc.add(np.arange(T) / anim.fps, gl.SCALAR, minmax=True)
    quats = matrix_to_quaternion(anim.local_rotations, continuous_axis=0)                  # (T, B, 4) w x y z
    samplers, channels = [], []
    for b in range(B):
        samplers.append(gl.AnimationSampler(input=times, output=doc.add(quats[:, b, [1, 2, 3, 0]], gl.VEC4)))
        channels.append(gl.AnimationChannel(sampler=len(samplers) - 1,
                                            target=gl.AnimationChannelTarget(node=b, path="rotation")))
    translations = anim.local_translations
    for b in anim.moving_bones:
        samplers.append(gl.AnimationSampler(input=times, output=doc.add(translations[:, b], gl.VEC3)))
        channels.append(gl.AnimationChannel(sampler=len(samplers) - 1,
                                            target=gl.AnimationChannelTarget(node=b, path="translation")))
    doc.gltf.animations = [gl.Animation(name=name, samplers=samplers, channels=channels)]

    doc.gltf.scenes = [gl.Scene(name=name, nodes=scene_nodes)]
    doc.gltf.scene = 0
    doc.gltf.asset = gl.Asset(version="2.0", generator=GENERATOR)
    doc.gltf.extras = {"rig": rig.name, "fps": anim.fps, "frames": T, "scale": anim.scale, "in_place": anim.in_place,
                       **(extras or {})}
    return doc.finish()


class _Builder:
    """Accumulates the binary buffer: each array becomes a bufferView (4-byte aligned) and an accessor."""

    def __init__(self):
        self.gltf = gl.GLTF2()
        self.blob = bytearray()

    def add(self, array: np.ndarray, kind: str, minmax: bool = False, target: int | None = None) -> int:
        a = np.ascontiguousarray(array)
        a = a.astype(np.float32) if a.dtype.kind == "f" else a
        component = {np.dtype(np.float32): _FLOAT, np.dtype(np.uint8): _UBYTE, np.dtype(np.uint16): _USHORT}[a.dtype]
        self.blob.extend(b"\0" * (-len(self.blob) % 4))
        offset = len(self.blob)
        self.blob.extend(a.tobytes())
        self.gltf.bufferViews.append(gl.BufferView(buffer=0, byteOffset=offset, byteLength=a.nbytes, target=target))
        flat = a.reshape(len(a), -1)
        accessor = gl.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=component, count=len(a),
                               type=kind)
        if minmax:
            accessor.min, accessor.max = flat.min(0).tolist(), flat.max(0).tolist()
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def finish(self) -> bytes:
        self.blob.extend(b"\0" * (-len(self.blob) % 4))
        self.gltf.buffers = [gl.Buffer(byteLength=len(self.blob))]
        self.gltf.set_binary_blob(bytes(self.blob))
        return b"".join(self.gltf.save_to_bytes())


def _bone_pyramids(rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest-pose triangles (flat-shaded: 3 vertices each) of a double pyramid from each bone's head to its tail.
    Returns positions (N, 3), normals (N, 3), the bone of each vertex (N,)."""
    positions, normals, bones = [], [], []
    for b in range(rig.num_bones):
        head, tail = rig.heads[b], rig.tails[b]
        axis = tail - head
        length = np.linalg.norm(axis)
        if length < _MIN_DRAWN:
            continue
        u = axis / length
        side = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
        side /= np.linalg.norm(side)
        other = np.cross(u, side)
        waist = head + 0.2 * axis
        ring = [waist + _BONE_WIDTH * length * (np.cos(a) * side + np.sin(a) * other)
                for a in np.arange(4) * np.pi / 2]
        for i in range(4):
            r0, r1 = ring[i], ring[(i + 1) % 4]
            for tri in ((head, r1, r0), (tail, r0, r1)):
                n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
                positions.extend(tri)
                normals.extend([n / np.linalg.norm(n)] * 3)
                bones.extend([b] * 3)
    return np.array(positions), np.array(normals), np.array(bones)


def _floats(v) -> list[float]:
    return [float(x) for x in np.asarray(v, np.float32)]


def _xyzw(q_wxyz) -> list[float]:
    q = np.asarray(q_wxyz, np.float64)
    return _floats(q[[1, 2, 3, 0]] / np.linalg.norm(q))
