"""The `mogo` command: files that read back, a JSON frame stream, bundle info, and clear errors (exit 2)."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import bvhio
import numpy as np
import pytest
from PIL import Image
from toy_bundle import toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.cli import main

TEXT = "a person walks forward and then jumps"


@pytest.fixture(scope="module", params=["toy_bundle", "tiny_bundle"])
def bundle_path(request) -> Path:
    return request.getfixturevalue(request.param)


@pytest.fixture(scope="module")
def gen(bundle_path) -> MotionGenerator:
    return MotionGenerator(bundle_path)


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_usage_error(code, err, *needles):
    assert code == 2
    assert err.startswith("mogo: error: ") and "Traceback" not in err
    for n in needles:
        assert n in err, err


def bvh_positions(path, joint_names) -> np.ndarray:
    root = bvhio.readAsHierarchy(str(path))
    index = {name: i for i, name in enumerate(joint_names)}
    frames = root.getKeyframeRange()[1] + 1
    out = np.zeros((frames, len(joint_names), 3))
    for f in range(frames):
        root.loadPose(f)
        for joint, _, _ in root.layout():
            p = joint.PositionWorld
            out[f, index[joint.Name]] = (p.x, p.y, p.z)
    return out / 100.0                                                    # written in centimetres


# ---------------------------------------------------------------------------------------------------
# generate

def test_generate_writes_every_format_and_each_reads_back(capsys, tmp_path, bundle_path, gen):
    tokens = 6
    seconds = tokens * gen.dims.downsample / gen.dims.fps
    outs = [tmp_path / "out" / f"walk.{ext}" for ext in ("npy", "json", "bvh", "gif")]
    code, stdout, err = run_cli(capsys, "generate", TEXT, *sum((["-o", o] for o in outs), []),
                                "--bundle", bundle_path, "--seconds", seconds, "--seed", 1, "--threads", 1)
    assert code == 0, err
    for o in outs:
        assert f"wrote {o}" in stdout
    frames = tokens * gen.dims.downsample
    want = gen.generate(TEXT, seconds=seconds, seed=1).joints                  # the Python API, same settings
    joints = np.load(outs[0])
    assert joints.shape == (frames, gen.skeleton.num_joints, 3) and np.array_equal(joints, want)
    data = json.loads(outs[1].read_text())
    assert data["fps"] == gen.dims.fps and data["skeleton"]["joint_names"] == list(gen.skeleton.joint_names)
    assert np.abs(np.array(data["frames"]) - joints).max() <= 0.5e-4 + 1e-6
    bvh = bvh_positions(outs[2], gen.skeleton.joint_names)
    assert bvh.shape == joints.shape
    assert np.abs(bvh[:, 0] - joints[:, 0]).max() < 1e-5                     # the root channels are positions
    if json.loads((bundle_path / "manifest.json").read_text())["producer"]["name"] == "tests/runtime/toy_bundle.py":
        # A rigid skeleton reproduces generated joints only as far as their bone lengths hold still; the toy
        # decoder's vary by millimetres (an untrained model's by far more). Exact IK: test_bvh, test_motion.
        assert np.abs(bvh - joints).max() < 0.03
    with Image.open(outs[3]) as im:
        assert im.n_frames == frames
    assert f"{frames} frames" in err and "fixed length" in err


def test_generate_int8_and_sampling_flags(capsys, tmp_path, bundle_path, gen):
    out = tmp_path / "g.npy"
    code, _, err = run_cli(capsys, "generate", TEXT, "-o", out, "--bundle", bundle_path, "--int8",
                           "--temperature", 0.8, "--top-k", 5, "--top-p", 0.9, "--guidance", 2.0, "--seed", 3)
    assert code == 0, err
    want = MotionGenerator(bundle_path, variant="int8").generate(
        TEXT, seed=3, sampling=SamplingConfig(temperature=0.8, top_k=5, top_p=0.9, guidance=2.0))
    assert np.array_equal(np.load(out), want.joints)
    assert "[int8, seed 3]" in err


def test_default_bundle_comes_from_the_environment(capsys, tmp_path, monkeypatch, bundle_path):
    monkeypatch.setenv("MOGO_BUNDLE", str(bundle_path))
    code, stdout, err = run_cli(capsys, "generate", TEXT, "-o", tmp_path / "e.npy", "--seconds", 1)
    assert code == 0, err
    assert (tmp_path / "e.npy").is_file()


# ---------------------------------------------------------------------------------------------------
# stream

def test_stream_prints_one_json_line_per_frame(capsys, bundle_path, gen):
    # a fixed length: on an endless bundle a stream without --seconds never ends
    code, stdout, err = run_cli(capsys, "stream", TEXT, "--bundle", bundle_path, "--seed", 2, "--seconds", 1.6)
    assert code == 0, err
    lines = stdout.splitlines()
    frames = [json.loads(line) for line in lines]
    want = gen.generate(TEXT, seed=2, seconds=1.6)
    assert len(frames) == want.num_frames
    assert [f["frame"] for f in frames] == list(range(want.num_frames))
    assert [f["time"] for f in frames] == pytest.approx([i / gen.dims.fps for i in range(want.num_frames)])
    assert np.abs(np.array([f["joints"] for f in frames]) - want.joints).max() <= 0.5e-4 + 1e-5


def test_stream_through_a_pipe_from_the_installed_command(bundle_path):
    # What a game does: start `mogo stream`, read lines as they come, stop reading early.
    mogo = Path(sys.executable).parent / "mogo"
    proc = subprocess.Popen([str(mogo), "stream", TEXT, "--bundle", str(bundle_path), "--seconds", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = json.loads(proc.stdout.readline())
    assert first["frame"] == 0 and len(first["joints"]) == 22 and len(first["joints"][0]) == 3
    proc.stdout.close()                                                    # the game goes away mid-stream
    assert proc.wait(timeout=60) == 0
    err = proc.stderr.read()
    proc.stderr.close()
    assert "Traceback" not in err, err


def test_stream_stops_quietly_when_the_reader_goes_away(capsys, toy_bundle, monkeypatch):  # noqa: F811
    read_end, write_end = os.pipe()

    class ClosedAfterOneLine:
        """A stdout whose reader leaves after the first frame."""
        lines = 0

        def write(self, text):
            if self.lines:
                raise BrokenPipeError(32, "Broken pipe")
            self.lines += 1

        def flush(self):
            pass

        def fileno(self):
            return write_end

    fake = ClosedAfterOneLine()
    monkeypatch.setattr(sys, "stdout", fake)
    try:
        code = main(["stream", TEXT, "--bundle", str(toy_bundle), "--seconds", "1"])
    finally:
        os.close(read_end)
        os.close(write_end)
    assert code == 0 and fake.lines == 1
    assert "Traceback" not in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------
# info

def test_info_shows_ok_then_failed_after_a_flipped_byte(capsys, tmp_path, bundle_path):
    code, stdout, err = run_cli(capsys, "info", bundle_path)
    assert code == 0, err
    manifest = json.loads((bundle_path / "manifest.json").read_text())
    for name, entry in manifest["files"].items():
        assert name in stdout
    assert stdout.count(" OK") == len(manifest["files"]) and "FAILED" not in stdout
    for word in ("fp32", "int8", "fps", "frames/token", "joints", "match the manifest"):
        assert word in stdout

    copy = shutil.copytree(bundle_path, tmp_path / "copy")
    victim = copy / manifest["variants"]["fp32"]["step"]["file"]
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0xFF
    victim.write_bytes(bytes(data))
    code, stdout, err = run_cli(capsys, "info", copy)
    assert f"{victim.name}" in stdout and "FAILED" in stdout
    assert_usage_error(code, err, victim.name, "sha256")
    code, _, err = run_cli(capsys, "generate", TEXT, "-o", tmp_path / "x.npy", "--bundle", copy)
    assert_usage_error(code, err, victim.name, "corrupted")
    assert not (tmp_path / "x.npy").exists()


# ---------------------------------------------------------------------------------------------------
# errors: one line, exit 2, nothing written

def test_missing_bundle(capsys, tmp_path, monkeypatch):
    monkeypatch.delenv("MOGO_BUNDLE", raising=False)
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "generate", TEXT, "-o", "walk.bvh")
    assert_usage_error(code, err, "bundles/base", "not found", "--bundle", "MOGO_BUNDLE")
    code, _, err = run_cli(capsys, "info", tmp_path / "nowhere")
    assert_usage_error(code, err, "nowhere", "not found")
    code, _, err = run_cli(capsys, "stream", TEXT, "--bundle", tmp_path)
    assert_usage_error(code, err, "manifest missing")


def test_missing_bundle_from_the_installed_command_has_no_traceback(tmp_path):
    mogo = Path(sys.executable).parent / "mogo"
    proc = subprocess.run([str(mogo), "generate", TEXT, "-o", "w.bvh", "--bundle", str(tmp_path / "none")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.startswith("mogo: error: ") and "Traceback" not in proc.stderr


@pytest.mark.parametrize("text", ["", "   "])
def test_empty_text(capsys, tmp_path, text, toy_bundle):  # noqa: F811
    for cmd in (["generate", text, "-o", tmp_path / "a.bvh"], ["stream", text]):
        code, stdout, err = run_cli(capsys, *cmd, "--bundle", toy_bundle)
        assert_usage_error(code, err, "empty or whitespace")
        assert stdout == ""


def test_bad_extension_lists_the_formats(capsys, tmp_path, toy_bundle):  # noqa: F811
    code, _, err = run_cli(capsys, "generate", TEXT, "-o", tmp_path / "a.bvh", "-o", tmp_path / "a.fbx",
                           "--bundle", toy_bundle)
    assert_usage_error(code, err, "a.fbx", ".npy", ".json", ".bvh", ".glb", ".gif", ".mp4")
    assert not (tmp_path / "a.bvh").exists()                               # checked before generating


def test_unwritable_output(capsys, tmp_path, toy_bundle):  # noqa: F811
    (tmp_path / "file").write_text("not a folder")
    code, _, err = run_cli(capsys, "generate", TEXT, "-o", tmp_path / "file" / "a.bvh", "--bundle", toy_bundle)
    assert_usage_error(code, err, "cannot create its folder")


@pytest.mark.parametrize("args, needles", [
    (["--seconds", "0"], ["seconds must be between"]),
    (["--seconds", "100000"], ["seconds must be between"]),
    (["--seconds", "nan"], ["seconds must be between"]),
    (["--seconds", "six"], ["--seconds", "invalid float"]),
    (["--int8", "--variant", "fp32"], ["not allowed with"]),
    (["--variant", "fp16"], ["unknown variant 'fp16'", "fp32, int8"]),
    (["--top-k", "-3"], ["top_k"]),
    (["--top-p", "2"], ["top_p must be in (0, 1]"]),
    (["--temperature", "-1"], ["temperature must be in [0, 100]"]),
    (["--threads", "0"], ["threads must be an int in [1, 64]"]),
    (["--seed", "-4"], ["seeds must be ints in [0, 2**63)"]),
])
def test_bad_settings(capsys, tmp_path, toy_bundle, args, needles):  # noqa: F811
    out = tmp_path / "a.npy"
    code, _, err = run_cli(capsys, "generate", TEXT, "-o", out, "--bundle", toy_bundle, *args)
    assert_usage_error(code, err, *needles)
    assert not out.exists()


def test_usage_errors(capsys):
    code, _, err = run_cli(capsys)
    assert_usage_error(code, err, "required")
    code, _, err = run_cli(capsys, "generate", TEXT)
    assert_usage_error(code, err, "-o/--output")
    code, _, err = run_cli(capsys, "dance")
    assert_usage_error(code, err, "invalid choice")


def test_mp4_needs_no_ffmpeg_on_path(capsys, tmp_path, toy_bundle, monkeypatch):  # noqa: F811
    monkeypatch.setenv("PATH", str(tmp_path))                             # no ffmpeg anywhere on PATH
    monkeypatch.delenv("IMAGEIO_FFMPEG_EXE", raising=False)
    code, out, err = run_cli(capsys, "generate", TEXT, "-o", tmp_path / "a.mp4", "--bundle", toy_bundle,
                             "--seconds", "1")
    assert code == 0, err
    assert (tmp_path / "a.mp4").read_bytes()[4:8] == b"ftyp"


def test_progress_line_only_on_a_terminal(capsys, tmp_path, toy_bundle, monkeypatch):  # noqa: F811
    args = ("generate", TEXT, "-o", tmp_path / "a.npy", "--bundle", toy_bundle, "--seconds", 0.6)   # 3 tokens
    code, _, err = run_cli(capsys, *args)
    assert code == 0 and "\r" not in err and "token" not in err
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    code, _, err = run_cli(capsys, *args)
    assert code == 0
    updates = [p.split("\n")[0] for p in err.split("\r") if p]
    assert updates == [f"mogo: generating, token {t}/3" for t in (1, 2, 3)]
