"""The snapshot tool's files and the benchmark's IK path."""

import json
import math

import cv2
import numpy as np

from tsrrt_common.robot_model import READY_POSTURE
from tsrrt_common.scenario import load_scenario
from tsrrt_sim.bench import cartesian_push_path, tool_path_to_joints
from tsrrt_sim.kinematics import PusherKinematics
from tsrrt_sim.snapshot import main


def test_snapshot_writes_image_and_true_poses(tmp_path):
    assert main(["--scenario", "tset3", "--out", str(tmp_path)]) == 0
    image = cv2.imread(str(tmp_path / "camera.png"))
    assert image.shape == (480, 640, 3)
    depth = cv2.imread(str(tmp_path / "depth.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and depth[150, 320] == 900      # table at x = 0.56, mm
    content = json.loads((tmp_path / "objects.json").read_text())
    scenario = load_scenario("tset3")
    assert [o["id"] for o in content["objects"]] == [o.id for o in scenario.objects]
    for entry, spec in zip(content["objects"], scenario.objects, strict=True):
        assert math.dist((entry["x"], entry["y"]), (spec.pose.x, spec.pose.y)) < 1e-3


def test_snapshot_reports_an_unknown_scenario(tmp_path, capsys):
    assert main(["--scenario", "no_such_scenario", "--out", str(tmp_path)]) == 2
    assert "no_such_scenario" in capsys.readouterr().err


def test_benchmark_ik_reaches_every_tool_point():
    kinematics = PusherKinematics()
    q_start = np.array(READY_POSTURE)
    _, points = cartesian_push_path(kinematics.tool_position(q_start))
    solutions = tool_path_to_joints(kinematics, q_start, points)
    reached = np.array([kinematics.tool_position(q) for q in solutions])
    assert np.abs(reached - points).max() < 1e-6
