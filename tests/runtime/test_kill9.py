"""kill -9 at any moment of `mogo generate` leaves only whole output files and no stray temporary file; a full disk
is an error that names the file (mogo_runtime/files.py says what holds).

MOGO_KILL9_RUNS (default 20) sets how many processes are killed, at seeded random moments (MOGO_KILL9_SEED).
"""
import errno
import json
import os
import random
import re
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from toy_bundle import toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime.outputs import files
from mogo_runtime.cli import main
from mogo_runtime.kinematics.skeleton import HUMANML3D
from mogo_runtime.outputs.motion import Motion, OutputError
from mogo_runtime.outputs.preview import render_mp4

RUNS = int(os.environ.get("MOGO_KILL9_RUNS", "20"))
SEED = int(os.environ.get("MOGO_KILL9_SEED", "0"))
TEXT = "a person walks forward and then jumps"
SECONDS = 8            # 160 frames: writing the six files is most of a run (the GIF and MP4 above all)
OUTPUTS = ("m.bvh", "m.gif", "m.json", "m.npy", "m.glb", "m.mp4")

# A fresh interpreter running `mogo`, optionally with the named-temporary-file fallback forced (the path taken
# where O_TMPFILE is missing), so both designs face the kill.
DRIVER = """
import sys
import mogo_runtime.outputs.files as files
if sys.argv[1] == "named":
    files._anonymous_ok = False
from mogo_runtime.cli import main
sys.exit(main(sys.argv[2:]))
"""


def generate_cmd(bundle: Path, out: Path, mode: str) -> list[str]:
    cmd = [sys.executable, "-c", DRIVER, mode, "generate", TEXT, "--bundle", str(bundle), "--seconds", str(SECONDS),
           "--seed", "1"]
    for name in OUTPUTS:
        cmd += ["-o", str(out / name)]
    return cmd


def check_complete(folder: Path) -> None:
    """Each output parses, and in full: a truncated file fails one of these."""
    frames = SECONDS * 20
    assert json.loads((folder / "m.json").read_text())["num_frames"] == frames
    assert np.load(folder / "m.npy").shape == (frames, 22, 3)
    bvh = (folder / "m.bvh").read_text()
    assert bvh.startswith("HIERARCHY") and f"Frames: {frames}\n" in bvh
    assert len(bvh.split("MOTION\n", 1)[1].strip().splitlines()) == frames + 2    # Frames:, Frame Time:, frames
    with Image.open(folder / "m.gif") as gif:
        assert gif.n_frames == frames
    glb = (folder / "m.glb").read_bytes()
    assert glb[:4] == b"glTF" and struct.unpack("<I", glb[8:12])[0] == len(glb)
    mp4, boxes, at = (folder / "m.mp4").read_bytes(), [], 0
    while at < len(mp4):                                   # top-level boxes tile the file exactly
        size, kind = struct.unpack(">I4s", mp4[at:at + 8])
        assert size >= 8, (at, size)
        boxes.append(kind)
        at += size
    assert at == len(mp4) and boxes[0] == b"ftyp" and b"moov" in boxes and b"mdat" in boxes


def wait_for_group(pgid: int, timeout: float = 20.0) -> None:
    """An orphaned ffmpeg of the killed process finishes on its own: wait for it, so that whatever it would
    leave behind is there to be seen."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.02)
    os.killpg(pgid, 9)
    raise AssertionError(f"processes of the killed run still alive after {timeout:.0f} s")


@pytest.mark.parametrize("mode,runs", [("anonymous", RUNS), ("named", max(1, RUNS // 2))])
def test_kill9_leaves_only_whole_outputs(tmp_path, toy_bundle, mode, runs):  # noqa: F811
    if mode == "anonymous" and sys.platform == "linux":   # the default there: what users get must be unnamed files
        assert files._anonymous_ok and files._DIR_FD, "O_TMPFILE and dir fds exist on Linux"
    ref = tmp_path / "ref"
    took = []
    for _ in range(2):        # the second run is the warm one the kills below interrupt
        start = time.perf_counter()
        subprocess.run(generate_cmd(toy_bundle, ref, mode), check=True, capture_output=True)
        took.append(time.perf_counter() - start)
    full = min(took)
    check_complete(ref)
    want = {n: (ref / n).read_bytes() for n in OUTPUTS}

    out = tmp_path / "out"
    rng = random.Random(SEED)
    strays, complete_kills, written = 0, 0, []
    for i in range(runs):
        if i % 2 == 0:
            shutil.rmtree(out, ignore_errors=True)   # half the runs write new files, half replace the last run's
        proc = subprocess.Popen(generate_cmd(toy_bundle, out, mode), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        time.sleep(rng.uniform(0.0, full))
        proc.kill()
        code = proc.wait()
        wait_for_group(proc.pid)
        complete_kills += code == 0
        names = set(os.listdir(out)) if out.exists() else set()
        for name in names & set(OUTPUTS):
            assert (out / name).read_bytes() == want[name], f"run {i}: {name} is not the whole file"
        stray = names - set(OUTPUTS)
        # what the killed process left is a temporary file the next write into the folder removes
        assert stray == {p.name for p in files.stale_temps(out)}, f"run {i}: unexpected files {sorted(stray)}"
        strays += len(stray)
        if i % 2 == 0:
            written.append(len(names & set(OUTPUTS)))
    print(f"\n{mode}: {runs} kill -9 runs (a run takes {full:.2f} s; {complete_kills} finished first); outputs "
          f"complete when killed, runs into an empty folder: {written}; stray temporary files right after the "
          f"kill: {strays}")
    if mode == "anonymous":
        # A stray name exists only in the microseconds between linking a replacement and renaming it; a kill
        # landing there is possible but must stay rare.
        assert strays <= 1
    subprocess.run(generate_cmd(toy_bundle, out, mode), check=True, capture_output=True)
    assert sorted(os.listdir(out)) == sorted(OUTPUTS)       # the next run removed whatever was stranded
    for name in OUTPUTS:
        assert (out / name).read_bytes() == want[name]


def test_sweep_removes_only_dead_processes_temporaries(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", ""])
    dead.wait()
    live = os.getpid()
    tag = files._TAG
    names = {
        f".a.bvh.{dead.pid}-{tag}-0123abcd.mogo-tmp.bvh": True,     # its writer is gone
        f".a.gif.{live}-{tag}-0123abcd.mogo-tmp.gif": False,        # being written right now
        f".a.gif.{dead.pid}-0000beef-0123abcd.mogo-tmp.gif": False,  # another host's or container's pid
        f".a.npy.{dead.pid}.0123abcd.tmp.npy": True,                # an earlier version's name
        f".a.npy.{dead.pid}.0123abcd.tmp.bvh": False,               # not what it would have named it
        "a.bvh": False, ".hidden": False, f".x.{dead.pid}.tmp": False,
    }
    for n in names:
        (tmp_path / n).write_bytes(b"x")
    assert {p.name for p in files.stale_temps(tmp_path)} == {n for n, stale in names.items() if stale}
    Motion.save(_motion(), tmp_path / "b.npy")                      # the first write into the folder sweeps
    assert sorted(os.listdir(tmp_path)) == sorted([n for n, stale in names.items() if not stale] + ["b.npy"])


def _motion(frames: int = 12) -> Motion:
    joints = np.zeros((frames, 22, 3), np.float32)
    joints[:, :, 1] = np.linspace(0.0, 1.7, 22)
    joints[:, :, 0] = np.linspace(0.0, 0.2, frames)[:, None]
    return Motion(text="t", features=np.zeros((frames, 263), np.float32), joints=joints, fps=20.0,
                  tokens=np.zeros((3, 2), np.int64), skeleton=HUMANML3D, seed=0)


def test_without_a_usable_proc_the_data_is_copied_to_a_named_file(tmp_path, monkeypatch):
    """A sandbox without /proc (or one that refuses linking through it): the unnamed file's data still arrives,
    through a named temporary file, and later writes go the named way at once."""
    monkeypatch.setattr(files, "_anonymous_ok", files._anonymous_ok)      # restored after the test
    real_link, tried = files._Folder.link, []

    def no_proc(self, source, name):
        if source.startswith("/proc/"):
            tried.append(name)
            raise OSError(errno.ENOENT, os.strerror(errno.ENOENT), source)
        return real_link(self, source, name)

    monkeypatch.setattr(files._Folder, "link", no_proc)
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    files.write_atomic(first, lambda f: f.write(b"{}"))
    files.write_atomic(second, lambda f: f.write(b"[]"))
    assert first.read_bytes() == b"{}" and second.read_bytes() == b"[]"
    assert sorted(os.listdir(tmp_path)) == ["a.json", "b.json"]
    assert tried == (["a.json"] if sys.platform == "linux" else [])
    assert not files._anonymous_ok


class FullDisk:
    """A file that takes `room` bytes, then fails as a full disk does."""

    def __init__(self, f, room: int):
        self.f, self.room = f, room

    def write(self, data):
        n = len(memoryview(data).cast("B"))
        if n > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.room -= n
        return self.f.write(data)

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


@pytest.mark.parametrize("anonymous", [True, False])
@pytest.mark.parametrize("suffix", [".npy", ".json", ".bvh", ".glb", ".gif"])
def test_full_disk_names_the_file_and_keeps_the_old_one(tmp_path, monkeypatch, suffix, anonymous):
    monkeypatch.setattr(files, "_anonymous_ok", anonymous and files._anonymous_ok)
    path = tmp_path / "out" / f"walk{suffix}"
    motion = _motion()
    motion.save(path)
    before = path.read_bytes()
    opened = files._fdopen
    monkeypatch.setattr(files, "_fdopen", lambda fd: FullDisk(opened(fd), room=100))
    with pytest.raises(OutputError, match=f"^{re.escape(str(path))}: cannot write it \\(No space left on device\\)$") as e:
        motion.save(path)
    assert e.value.errno == errno.ENOSPC
    assert path.read_bytes() == before and os.listdir(path.parent) == [path.name]
    monkeypatch.setattr(files, "_fdopen", opened)
    motion.save(path)
    assert os.listdir(path.parent) == [path.name]


def test_full_disk_through_the_command_is_one_line(tmp_path, monkeypatch, capsys, toy_bundle):  # noqa: F811
    opened = files._fdopen
    monkeypatch.setattr(files, "_fdopen", lambda fd: FullDisk(opened(fd), room=0))
    out = tmp_path / "a.json"
    code = main(["generate", TEXT, "--bundle", str(toy_bundle), "--seconds", "1", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert f"mogo: error: {out}: cannot write it (No space left on device)" in err
    assert os.listdir(tmp_path) == []


def test_mp4_full_disk_names_the_file(tmp_path, monkeypatch, capsys, toy_bundle):  # noqa: F811
    """ffmpeg writes the video itself: its failure (here the one a full disk gives) names our file, and `mogo`
    reports it in one line."""
    fake = tmp_path / "ffmpeg"
    fake.write_text("#!/bin/sh\ncat > /dev/null\necho 'Error writing trailer: No space left on device' >&2\n"
                    "exit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(fake))
    path = tmp_path / "out" / "walk.mp4"
    with pytest.raises(OutputError, match=f"^ffmpeg failed \\(exit 1\\) writing {re.escape(str(path))}: .*No space left"):
        render_mp4(path, _motion().joints)
    assert os.listdir(path.parent) == []
    code = main(["generate", TEXT, "--bundle", str(toy_bundle), "--seconds", "1", "-o", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and f"writing {path}: " in err and "No space left" in err
