"""The shipped reachability grid: matches the robot, agrees with IK, checks whole pushes."""

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_executor.errors import IKError, UnreachableError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.push_primitives import ball_path_points, push_geometry
from tsrrt_executor.reachability import (
    ReachabilityMapError,
    default_map,
    erode,
    is_reachable,
    load_grid,
    push_is_executable,
)


def test_shipped_grid_matches_the_current_robot_description():
    grid = load_grid()  # raises if the URDF's kinematics changed since the grid was written
    assert grid.grid.any() and not grid.grid.all()


def test_known_points():
    flags = is_reachable(np.array([[0.45, 0.0], [0.55, 0.2], [0.95, 0.0], [0.2, 0.0],
                                   [0.0, 0.0], [0.45, 0.9]]))
    assert flags.tolist() == [True, True, False, False, False, False]


def test_reachable_grid_points_have_ik_solutions():
    grid = default_map()
    rows, cols = np.nonzero(grid.grid)
    rng = np.random.default_rng(7)
    ik = PusherIK()
    for index in rng.choice(rows.size, size=8, replace=False):
        x = grid.x0 + cols[index] * grid.step
        y = grid.y0 + rows[index] * grid.step
        for z in (min(grid.heights), max(grid.heights)):
            q, _ = ik.solve(np.array([x, y, z]))
            assert np.linalg.norm(ik.tool_position(q) - [x, y, z]) < 1e-4


def test_far_points_outside_the_grid_have_no_ik_solution():
    with pytest.raises(IKError):
        PusherIK().solve(np.array([0.95, 0.0, 0.014]))


def test_pushes_at_the_table_centre_are_reachable_all_six():
    for primitive in range(1, 7):
        geometry = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.45, 0.0, 0.3), primitive)
        assert push_is_executable(geometry)


def test_push_from_the_robot_side_at_the_near_edge_is_unreachable():
    pose = Pose2D(0.34, 0.0, 0.0)  # primitive 1 approaches from x = 0.34 - 0.06 - 0.022
    assert not push_is_executable(push_geometry("box", 0.12, 0.05, 0.03, pose, 1))
    assert push_is_executable(push_geometry("box", 0.12, 0.05, 0.03, pose, 2))


def test_the_margin_is_for_planning_the_executor_checks_the_ik_set():
    grid = default_map()
    assert not (grid.grid & ~grid.ik_grid).any()        # the margin only takes points away
    in_margin = np.array([[0.31, 0.0]])                   # 2 cm short of the near limit
    assert not grid.is_reachable(in_margin)[0] and grid.is_executable(in_margin)[0]
    assert not grid.is_executable(np.array([[0.29, 0.0]]))[0]
    # A box a little nearer the robot than planned: its push from the robot's side starts
    # inside the margin; the executor still makes it.
    planned = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.42, 0.0, 0.0), 1)
    observed = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.405, 0.0, 0.0), 1)
    assert grid.is_reachable(ball_path_points(planned)).all()
    assert not grid.is_reachable(ball_path_points(observed)).all()
    assert push_is_executable(observed)


def test_heights_outside_the_verified_range_are_an_error():
    geometry = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.45, 0.0, 0.0), 1,
                             safe_height=0.3)
    with pytest.raises(UnreachableError, match="safe height"):
        push_is_executable(geometry)


def test_erode_removes_nodes_near_unreachable_ones():
    grid = np.ones((7, 7), dtype=bool)
    grid[3, 3] = False
    eroded = erode(grid, step=0.01, margin=0.01)
    expected = np.ones((7, 7), dtype=bool)
    expected[[3, 2, 4, 3, 3], [3, 3, 3, 2, 4]] = False
    expected[0, :] = expected[-1, :] = expected[:, 0] = expected[:, -1] = False  # grid border
    np.testing.assert_array_equal(eroded, expected)


def test_malformed_grid_file_is_reported(tmp_path):
    path = tmp_path / "grid.yaml"
    path.write_text("x0: 0.1\n")
    with pytest.raises(ReachabilityMapError, match="malformed"):
        load_grid(path)
    with pytest.raises(ReachabilityMapError, match="missing"):
        load_grid(tmp_path / "absent.yaml")


def test_map_satisfies_the_planners_reachability_protocol():
    """The planner calls .reachable(points); it must agree with is_reachable."""
    grid = default_map()
    points = np.array([[0.45, 0.0], [0.05, 0.0], [0.6, 0.2]])
    np.testing.assert_array_equal(grid.reachable(points), grid.is_reachable(points))
