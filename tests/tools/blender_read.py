"""Reads .glb and .bvh files with real Blender (bpy): its glTF importer and its BVH importer, then every bone's head in
the world at every frame, in glTF's axes (y up); optionally renders one frame of one file to a PNG.

    python blender_read.py JOBS.json OUT.json      (the Python that has bpy; JOBS as read_glb.mjs takes them)
    JOBS entries may add "render": {"frame": f, "png": "out.png"}
"""
import json
import sys
import time

import bpy


def read(job: dict) -> dict:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = round(job["fps"]), round(job["fps"]) / job["fps"]
    start = time.perf_counter()
    if job["file"].endswith(".glb"):
        bpy.ops.import_scene.gltf(filepath=job["file"])
        first = 0            # the importer keys glTF time 0 at frame 0
    else:
        bpy.ops.import_anim.bvh(filepath=job["file"], global_scale=0.01, frame_start=1, use_fps_scale=False,
                                update_scene_fps=False, update_scene_duration=True)
        first = 1
    took = time.perf_counter() - start
    arm = next(o for o in scene.objects if o.type == "ARMATURE")
    frames = []
    for f in range(job["frames"]):
        scene.frame_set(first + f)
        rows = []
        for pb in arm.pose.bones:
            x, y, z = arm.matrix_world @ pb.head
            rows.append([x, z, -y])      # Blender is z up, -y forward; glTF and HumanML3D are y up, +z forward
        frames.append(rows)
    if "render" in job:
        render(scene, arm, first + job["render"]["frame"], job["render"]["png"])
    return {"names": [pb.name for pb in arm.pose.bones], "frames": frames, "import_s": took}


def render(scene, arm, frame: int, png: str) -> None:
    """A front three-quarter view of the figure at `frame`, 480x480 (Workbench engine), nothing else in the scene."""
    scene.frame_set(frame)
    heads = [arm.matrix_world @ pb.head for pb in arm.pose.bones]
    cx = sum(h.x for h in heads) / len(heads)
    cy = sum(h.y for h in heads) / len(heads)
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(cam)
    cam.location = (cx + 2.6, cy - 3.4, 1.6)
    target = bpy.data.objects.new("target", None)
    target.location = (cx, cy, 0.9)
    scene.collection.objects.link(target)
    c = cam.constraints.new("TRACK_TO")
    c.target, c.track_axis, c.up_axis = target, "TRACK_NEGATIVE_Z", "UP_Y"
    scene.camera = cam
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 480
    scene.render.filepath = png
    arm.show_in_front = True
    bpy.ops.render.render(write_still=True)


jobs = json.load(open(sys.argv[1]))
json.dump({job["file"]: read(job) for job in jobs}, open(sys.argv[2], "w"))
