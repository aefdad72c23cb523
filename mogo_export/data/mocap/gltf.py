"""glTF binary (.glb) animation reader: a file's first animation -> a `Take`, sampled at its own key rate.

What is read (glTF 2.0): the default scene's node tree (every node is a joint, named as the file names it), each
node's rest transform (its translation / rotation / scale, or matrix), and the first animation's translation,
rotation and scale channels (LINEAR, STEP or CUBICSPLINE; rotations are slerped, as the specification says).
The rest pose is the nodes' own transforms, which is how exporters (Blender, the runtime's gltf.py) leave the
bind pose. glTF is y up and metres by specification; the importer still scales by the legs, so a file in other
units comes out right. Weights (morph targets), cameras and meshes are ignored.
Untrusted input: the header, every index and every accessor's bytes are checked before use; the file size,
node count and sampled frames are bounded; every problem is one MotionFileError naming the file.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pygltflib as gl

from mogo_runtime.checks import read_file
from mogo_runtime.kinematics.quaternion import quaternion_to_matrix

from . import MotionFileError, Take

MAX_FILE_BYTES = 256 << 20
MAX_NODES = 10_000
MAX_SECONDS = 3600.0
MAX_NODE_FRAMES = 4_000_000     # nodes x sampled frames (the same bound as the BVH reader's)
MAX_KEYS = 20_000_000           # animation values read, over every channel
_TYPES = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_COMPONENTS = {gl.FLOAT: ("<f4", None), gl.BYTE: ("<i1", 127.0), gl.UNSIGNED_BYTE: ("<u1", 255.0),
               gl.SHORT: ("<i2", 32767.0), gl.UNSIGNED_SHORT: ("<u2", 65535.0)}   # normalised ints: KHR quantization
_PATHS = {"translation": 3, "rotation": 4, "scale": 3}


def read_glb(path, fps: float | None = None) -> Take:
    """Read `path`'s first animation at `fps` (None: the rate of its most finely keyed channel; see the module
    docstring)."""
    where = str(path)
    data = read_file(Path(path), MAX_FILE_BYTES, error=MotionFileError)
    if len(data) < 20 or data[:4] != b"glTF" or struct.unpack_from("<I", data, 4)[0] != 2:
        raise MotionFileError(f"{where}: not a glTF 2.0 binary file (.glb)")
    try:
        doc = gl.GLTF2.load_from_bytes(data)
        blob = doc.binary_blob() or b""
    except Exception as e:        # the library raises anything from struct.error to KeyError on a broken file
        raise MotionFileError(f"{where}: unreadable glTF ({type(e).__name__}: {str(e)[:120]})") from None
    try:
        return _read(doc, blob, fps, where)
    except (TypeError, AttributeError, IndexError, KeyError, OverflowError) as e:
        # the library does not check the JSON's types: a string where a number belongs ends up here
        raise MotionFileError(f"{where}: malformed glTF ({type(e).__name__}: {str(e)[:120]})") from None


def _read(doc, blob: bytes, fps: float | None, where: str) -> Take:
    nodes, parents = _tree(doc, where)
    in_scene = set(nodes)
    if not doc.animations:
        raise MotionFileError(f"{where}: has no animation")
    anim = doc.animations[0]
    tracks, start, end, keyed = {}, np.inf, -np.inf, 0
    for i, ch in enumerate(anim.channels or []):
        path_ = ch.target.path if ch.target else None
        if path_ not in _PATHS:
            continue                                # morph weights, or an extension's path
        node = ch.target.node
        if not isinstance(node, int) or node not in in_scene:
            continue                                # a node of another scene moves nothing here
        if not isinstance(ch.sampler, int) or not 0 <= ch.sampler < len(anim.samplers or []):
            raise MotionFileError(f"{where}: animation channel {i} names sampler {ch.sampler!r}, which does not exist")
        s = anim.samplers[ch.sampler]
        times = _accessor(doc, blob, s.input, 1, where)[:, 0]
        mode = s.interpolation or "LINEAR"
        values = _accessor(doc, blob, s.output, _PATHS[path_], where)
        keys = len(times) * (3 if mode == "CUBICSPLINE" else 1)
        if mode not in ("LINEAR", "STEP", "CUBICSPLINE") or len(values) != keys or not len(times) \
                or np.any(np.diff(times) < 0) or not np.isfinite(times).all() or not np.isfinite(values).all():
            raise MotionFileError(f"{where}: animation channel {i} ({path_} of node {node}) has a bad sampler: "
                                  f"{mode} interpolation, {len(times)} times, {len(values)} values")
        tracks[(node, path_)] = (times, values, mode)
        keyed += len(values)
        if keyed > MAX_KEYS:
            raise MotionFileError(f"{where}: its animation has more than {MAX_KEYS:,} keys")
        start, end = min(start, times[0]), max(end, times[-1])
    if not tracks:
        raise MotionFileError(f"{where}: its first animation moves no node of the scene")
    if fps is None:     # float32 key times: 1 / 0.0166666675 is 59.99999...
        steps = np.diff(max((t for t, _, _ in tracks.values()), key=len))
        fps = round(1.0 / float(np.median(steps[steps > 0])), 3) if np.any(steps > 0) else 20.0
        if not 1.0 <= fps <= 1000.0:
            raise MotionFileError(f"{where}: its animation is keyed at {fps:g} frames a second; 1 to 1000 are read")
    if end - start > MAX_SECONDS:
        raise MotionFileError(f"{where}: its animation lasts {end - start:.0f} s; at most {MAX_SECONDS:.0f} s are read")
    # float32 key times (what glTF stores) are off by up to 1e-7 relative: a frame within 1e-3 of the end is kept
    times = start + np.arange(int(np.floor((end - start) * fps + 1e-3)) + 1) / fps
    if len(times) * len(nodes) > MAX_NODE_FRAMES:
        raise MotionFileError(f"{where}: {len(times)} frames of {len(nodes)} nodes; at most {MAX_NODE_FRAMES:,} "
                              f"node positions are computed")
    with np.errstate(all="ignore"):     # a zero quaternion or a huge scale: the check below says so, once
        rest = _world(doc, nodes, parents, {}, np.zeros(1), where)[0]
        positions = _world(doc, nodes, parents, tracks, times, where)
    if not (np.isfinite(positions).all() and np.isfinite(rest).all()):
        raise MotionFileError(f"{where}: its nodes cannot be placed (a zero rotation, or numbers too large)")
    names = [doc.nodes[n].name or f"node{n}" for n in nodes]
    return Take(names, parents, rest, positions, float(fps), where)


def _tree(doc, where: str) -> tuple[list[int], list[int]]:
    """The default scene's nodes, parents before children (node indices), and each one's parent (position in the
    list, -1 for a scene root)."""
    count = len(doc.nodes)
    if not 0 < count <= MAX_NODES:
        raise MotionFileError(f"{where}: {count} nodes; 1 to {MAX_NODES} are read")
    scene = doc.scene if isinstance(doc.scene, int) else 0
    if not doc.scenes or not 0 <= scene < len(doc.scenes):
        below = {c for m in doc.nodes for c in (m.children or []) if isinstance(c, int)}
        roots = [n for n in range(count) if n not in below]
    else:
        roots = list(doc.scenes[scene].nodes or [])
    order, parents, seen, stack = [], [], set(), [(n, -1) for n in reversed(roots)]
    while stack:
        n, p = stack.pop()
        if not isinstance(n, int) or not 0 <= n < count or n in seen:
            raise MotionFileError(f"{where}: node {n!r} is missing or has two parents (the nodes are not a tree)")
        seen.add(n)
        order.append(n)
        parents.append(p)
        stack.extend((c, len(order) - 1) for c in reversed(doc.nodes[n].children or []))
    return order, parents


def _accessor(doc, blob: bytes, index, width: int, where: str) -> np.ndarray:
    """Accessor `index` as float64 (count, width), every byte checked to lie inside its buffer view."""
    if not isinstance(index, int) or not 0 <= index < len(doc.accessors):
        raise MotionFileError(f"{where}: accessor {index!r} does not exist")
    a = doc.accessors[index]
    what = f"{where}: accessor {index}"
    if a.sparse is not None or a.bufferView is None:
        raise MotionFileError(f"{what}: sparse or empty accessors are not read")
    if _TYPES.get(a.type) != width or a.componentType not in _COMPONENTS:
        raise MotionFileError(f"{what}: expected {width} numbers an element, got {a.type} of type {a.componentType}")
    dtype, scale = _COMPONENTS[a.componentType]
    if not 0 <= a.bufferView < len(doc.bufferViews):
        raise MotionFileError(f"{what}: buffer view {a.bufferView} does not exist")
    view = doc.bufferViews[a.bufferView]
    size = np.dtype(dtype).itemsize
    stride = view.byteStride or size * width
    begin, count = (view.byteOffset or 0) + (a.byteOffset or 0), a.count
    if view.buffer != 0 or not isinstance(count, int) or not 0 < count <= 10_000_000 or stride < size * width \
            or begin + stride * (count - 1) + size * width > min((view.byteOffset or 0) + view.byteLength, len(blob)):
        raise MotionFileError(f"{what}: its {count!r} elements do not lie inside the file's binary chunk")
    out = np.ndarray((count, width), dtype, buffer=blob, offset=begin, strides=(stride, size)).astype(np.float64)
    return out if scale is None else np.maximum(out / scale, -1.0)


def _world(doc, nodes: list[int], parents: list[int], tracks: dict, times: np.ndarray, where: str) -> np.ndarray:
    """(T, N, 3) world positions of `nodes` at `times`: each node's rest transform, its animated parts replaced."""
    T = len(times)
    lin = np.zeros((T, len(nodes), 3, 3))          # each node's world linear part (rotation times scale)
    pos = np.zeros((T, len(nodes), 3))
    for i, n in enumerate(nodes):
        node = doc.nodes[n]
        if node.matrix is not None and not any((n, p) in tracks for p in _PATHS):
            m = _vector(node.matrix, 16, f"{where}: node {n}'s matrix").reshape(4, 4).T   # column-major in the file
            local_l, local_t = np.broadcast_to(m[:3, :3], (T, 3, 3)), np.broadcast_to(m[:3, 3], (T, 3))
        else:
            t, q, s = (_track(tracks, n, path, _vector(getattr(node, path) or rest, len(rest), f"{where}: node {n}'s "
                                                       f"{path}"), times)
                       for path, rest in (("translation", [0.0] * 3), ("rotation", [0.0, 0.0, 0.0, 1.0]),
                                          ("scale", [1.0] * 3)))
            local_l = quaternion_to_matrix(q[:, [3, 0, 1, 2]]) * s[:, None, :]
            local_t = t
        p = parents[i]
        if p < 0:
            lin[:, i], pos[:, i] = local_l, local_t
        else:
            lin[:, i] = lin[:, p] @ local_l
            pos[:, i] = pos[:, p] + np.einsum("tij,tj->ti", lin[:, p], local_t)
    return pos


def _vector(value, n: int, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (n,) or not np.isfinite(v).all():
        raise MotionFileError(f"{what} is not {n} finite numbers")
    return v


def _track(tracks: dict, node: int, path: str, rest: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(T, k) the node's `path` at `times`: its animation channel's value, or its rest value throughout."""
    if (node, path) not in tracks:
        return np.broadcast_to(rest, (len(times), len(rest)))
    keys, values, mode = tracks[(node, path)]
    # a time on a key takes that key, though the key is stored as float32 (off by up to 6e-8 of itself)
    k = np.clip(np.searchsorted(keys, times + 1e-6 + 1e-7 * np.abs(times), side="right") - 1, 0, len(keys) - 1)
    if mode == "STEP" or len(keys) == 1:
        return values[k * 3 + 1] if mode == "CUBICSPLINE" else values[k]
    k = np.minimum(k, len(keys) - 2)
    dt = keys[k + 1] - keys[k]
    u = np.clip((times - keys[k]) / np.maximum(dt, 1e-12), 0.0, 1.0)[:, None]
    if mode == "CUBICSPLINE":      # Hermite: values are (in-tangent, value, out-tangent) per key
        v0, v1 = values[3 * k + 1], values[3 * k + 4]
        b0, a1 = values[3 * k + 2] * dt[:, None], values[3 * k + 3] * dt[:, None]     # tangents, per second
        out = (2 * u**3 - 3 * u**2 + 1) * v0 + (u**3 - 2 * u**2 + u) * b0 + (-2 * u**3 + 3 * u**2) * v1 \
            + (u**3 - u**2) * a1
    elif path == "rotation":
        out = _slerp(values[k], values[k + 1], u)
    else:
        out = values[k] + u * (values[k + 1] - values[k])
    if path == "rotation":
        out = out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-12)
    return out


def _slerp(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical interpolation of (N, 4) quaternions, the short way round."""
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
    b = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-12)
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    angle = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(angle)
    near = sin < 1e-6                                  # nearly equal: lerp is exact enough and has no 0 / 0
    wa = np.where(near, 1 - u, np.sin((1 - u) * angle) / np.where(near, 1.0, sin))
    wb = np.where(near, u, np.sin(u * angle) / np.where(near, 1.0, sin))
    return wa * a + wb * b
