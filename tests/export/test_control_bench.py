"""The control benchmark (benchmarks/control.py) measures what it says: its geometry on known paths and poses, and a
miniature run on the tiny bundle that writes every field (no thresholds: the tiny model barely learnt to follow)."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.control_paths import (body_yaw, corner_frames, path_progress, polyline_path, random_path,
                                      smooth_path, travel_agreement)
from mogo_runtime.kinematics.skeleton import HUMANML3D

ROOT = Path(__file__).resolve().parents[2]


def test_progress_along_a_path_is_its_distance_arc_and_direction():
    square = np.array([[0, 0], [0, 4], [-4, 4], [-4, 0]], float)
    xz = np.array([[0.1, 1.0], [0.0, 3.9], [-2.0, 4.5], [-4.2, 1.0], [-3.0, 0.0]])
    d, arc, yaw = path_progress(square, xz)
    assert np.allclose(d, [0.1, 0.0, 0.5, 0.2, 1.0])
    assert np.allclose(arc, [1.0, 3.9, 6.0, 11.0, 12.0])           # the last point is nearest the end
    assert np.allclose(np.degrees(yaw[:4]), [0, 0, -90, 180])      # +z, +z, -x, -z
    assert corner_frames(arc, [4.0, 8.0]) == [2, 3]


def test_body_yaw_reads_the_facing_as_the_features_define_it():
    joints = np.zeros((1, 22, 3))
    r_hip, l_hip, r_sh, l_sh = HUMANML3D.face_joints
    joints[0, [l_hip, l_sh], 0], joints[0, [r_hip, r_sh], 0] = 0.1, -0.1     # left is +x when facing +z
    for turn in (0.0, 0.7, -2.5):
        c, s = math.cos(turn), math.sin(turn)
        turned = joints.copy()
        turned[..., 0], turned[..., 2] = joints[..., 0] * c + joints[..., 2] * s, -joints[..., 0] * s + joints[..., 2] * c
        assert np.isclose(body_yaw(turned, HUMANML3D.face_joints)[0], turn)


def test_travel_agreement_compares_the_models_own_travel_with_the_capsules():
    t = np.arange(40) / 20.0
    capsule = np.stack([np.zeros_like(t), 1.2 * t], 1)                      # +z at 1.2 m/s
    angle, ratio = travel_agreement(capsule, capsule, 20.0)
    assert len(angle) == 30 and np.allclose(angle, 0) and np.allclose(ratio, 1)
    sideways_slow = np.stack([0.6 * t, np.zeros_like(t)], 1)                # +x at half the speed
    angle, ratio = travel_agreement(sideways_slow, capsule, 20.0)
    assert np.allclose(angle, math.pi / 2) and np.allclose(ratio, 0.5)
    standing = np.zeros((40, 2))                                            # a capsule that stands is not judged
    assert len(travel_agreement(capsule, standing, 20.0)[0]) == 0


def test_random_paths_have_the_length_the_speed_asks_and_sharp_corners():
    rng = np.random.default_rng(0)
    for speed in (0.8, 3.5):
        path = smooth_path(rng, speed, speed * 20)
        assert abs(np.hypot(*np.diff(path, axis=0).T).sum() - speed * 20) < 0.2
    points, corners = polyline_path(rng, 30.0)
    legs = np.diff(points, axis=0)
    turns = np.degrees(np.abs(np.angle(np.exp(1j * np.diff(np.arctan2(legs[:, 0], legs[:, 1]))))))
    assert len(corners) == len(legs) - 1 and ((45 <= turns) & (turns <= 135)).all()
    assert {random_path(rng, 1.0, 5.0)[2] for _ in range(20)} == {"smooth", "corners"}


def test_the_benchmark_runs_on_the_tiny_bundle(tiny_bundle, tmp_path):
    from mogo_export.data.procedural import build_dataset

    # 85 clips: their singles show every family, walk_forward (whose speed the benchmark measures) among them;
    # 10 path sequences: the held-out splits get some
    data = build_dataset(tmp_path / "data", num_clips=85, seed=0, progress=False, workers=1, long_sequences=0,
                         path_sequences=10, control_sequences=0)
    out = tmp_path / "control.json"
    cmd = [sys.executable, "-m", "benchmarks.control", str(tiny_bundle), "--data", str(data), "--paths", "2",
           "--waypoints", "2", "--game-root", "1", "--crowd", "3", "--ticks", "3", "--json", str(out),
           "--sections", "paths,waypoints,game_root,feet,cost"]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["paths"]["paths"] == 2 and report["paths"]["position_error_m"]["median"] >= 0
    assert 0 <= report["waypoints"]["reached"] <= 1
    assert report["game_root"]["root_to_capsule_m"]["max"] < 0.05      # the capsule places the root: by construction
    travel = report["game_root"]["model_travel"]
    assert travel["windows"] > 0 and 0 <= travel["off_by_45deg"] <= 1 and travel["speed_ratio_median"] >= 0
    assert report["feet"]["skating_data"] >= 0 and report["feet"]["data_path_sequences"] >= 1
    for phase in ("fresh", "steady"):
        assert report["cost"]["controlled"][phase]["per_character_token_ms"] > 0
        assert report["cost"]["controlled"][phase]["step_rows_per_character_token"] >= 1
