# Plays imported .glb scenes as a Godot 3 game does: each scene instanced, its AnimationPlayer's animation sought to
# each frame's time, every Skeleton bone's global position; and the skinned figure (its MeshInstance's Skin binds)
# skinned on the CPU as Godot's renderer skins it, at one vertex per bind: the one farthest from the bone's rest head
# (the tip of mogo's double pyramid), so each bone's turn and the skin's bind poses count too.
#   MOGO_GODOT_JOBS=JOBS.json godot3-server --path PROJECT -s res://godot_read.gd
#   JOBS: [{"res": "res://x.glb", "frames": T, "fps": 20, "out": "/abs/x"}, ...]. Writes, per job, OUT.json
#   {"names": [bones], "tips": [bones with a tip], "tip_rest": [[x, y, z]], "animation", "length"} and OUT.bin:
#   float32, T frames of (bones' positions, then the skinned tips), x y z each.
extends SceneTree

var jobs = []
var done = 0


func _init():
	var f = File.new()
	f.open(OS.get_environment("MOGO_GODOT_JOBS"), File.READ)
	jobs = parse_json(f.get_as_text())
	f.close()


# A few scenes a frame: the engine's message queue (the nodes' notifications, 1 MB) is flushed between frames
func _idle(_delta):
	if done < jobs.size():
		for job in jobs.slice(done, min(done + 20, jobs.size()) - 1):
			read(job)
		done = min(done + 20, jobs.size())
	else:
		print("mogo: read %d imported scenes" % jobs.size())
		quit()


func find(node, type):
	if node.is_class(type):
		return node
	for c in node.get_children():
		var found = find(c, type)
		if found:
			return found
	return null


func read(job):
	var scene = load(job["res"]).instance()
	get_root().add_child(scene)
	var skel = find(scene, "Skeleton")
	var mi = find(scene, "MeshInstance")
	var player = find(scene, "AnimationPlayer")
	var animation = player.get_animation_list()[0]
	var skin = mi.skin
	var arrays = mi.mesh.surface_get_arrays(0)
	var verts = arrays[Mesh.ARRAY_VERTEX]
	var bones = arrays[Mesh.ARRAY_BONES]
	var weights = arrays[Mesh.ARRAY_WEIGHTS]
	var tip = {}
	for v in range(verts.size()):
		if weights[4 * v] < 0.999:
			continue
		var bind = bones[4 * v]
		var head = skin.get_bind_pose(bind).affine_inverse().origin
		if not tip.has(bind) or verts[v].distance_to(head) > verts[tip[bind]].distance_to(head):
			tip[bind] = v
	var binds = tip.keys()
	binds.sort()
	var tip_bones = []
	var info = {"names": [], "tips": [], "tip_rest": [], "animation": animation,
				"length": player.get_animation(animation).length}
	for bind in binds:
		var bone = skin.get_bind_bone(bind)
		if skin.get_bind_name(bind) != "":
			bone = skel.find_bone(skin.get_bind_name(bind))
		tip_bones.append(bone)
		info["tips"].append(skel.get_bone_name(bone))
		var p = verts[tip[bind]]
		info["tip_rest"].append([p.x, p.y, p.z])
	for b in range(skel.get_bone_count()):
		info["names"].append(skel.get_bone_name(b))
	var out = File.new()
	out.open(job["out"] + ".json", File.WRITE)
	out.store_string(to_json(info))
	out.close()
	out.open(job["out"] + ".bin", File.WRITE)
	player.play(animation)
	for t in range(job["frames"]):
		player.seek(t / float(job["fps"]), true)
		var world = skel.global_transform
		for b in range(skel.get_bone_count()):
			var p = world * skel.get_bone_global_pose(b).origin
			out.store_float(p.x)
			out.store_float(p.y)
			out.store_float(p.z)
		var model = mi.global_transform
		for i in range(binds.size()):
			var skinning = skel.get_bone_global_pose(tip_bones[i]) * skin.get_bind_pose(binds[i])
			var p = model * skinning.xform(verts[tip[binds[i]]])
			out.store_float(p.x)
			out.store_float(p.y)
			out.store_float(p.z)
	out.close()
	get_root().remove_child(scene)
	scene.free()
