# An editor plugin of the throwaway Godot 3 project test_imports.py writes: once the editor has imported every .glb in
# res:// (each one's .import file names its imported scene, and the .md5 the editor writes after an import exists), it
# writes res://imported.txt (the number of files, then those whose import failed: no scene) and ends the editor.
# Godot 3.2's headless editor never exits by itself (with --quit or get_tree().quit() alike it waits forever in its
# cleanup; godotengine/godot#42839), so it ends its own process (SIGKILL): what it imported is on disk by then.
tool
extends EditorPlugin

var glbs = []
var checked_ms = 0


func _enter_tree():
	var d = Directory.new()
	d.open("res://")
	d.list_dir_begin(true, true)
	var name = d.get_next()
	while name != "":
		if name.ends_with(".glb"):
			glbs.append("res://" + name)
		name = d.get_next()
	d.list_dir_end()


func _process(_delta):
	# the editor also runs this from inside its import loop (each progress step): look 5 times a second at most
	if OS.get_ticks_msec() - checked_ms < 200 or get_editor_interface().get_resource_filesystem().is_scanning():
		return
	checked_ms = OS.get_ticks_msec()
	if glbs.empty():
		return
	var failed = []
	for glb in glbs:
		var cf = ConfigFile.new()
		if cf.load(glb + ".import") != OK or not cf.has_section_key("remap", "path"):
			return
		var dest = cf.get_value("remap", "path")
		var f = File.new()
		if not f.file_exists(dest.get_basename() + ".md5"):
			return
		if not f.file_exists(dest):
			failed.append(glb)
	var out = File.new()
	out.open("res://imported.txt", File.WRITE)
	out.store_line(str(glbs.size()))
	for glb in failed:
		out.store_line(glb)
	out.close()
	print("mogo: the editor imported %d .glb files, %d failed" % [glbs.size(), failed.size()])
	OS.kill(OS.get_process_id())
