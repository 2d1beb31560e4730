"""Time parameterisation: profiles, joint limits, constant push speed, joint-space moves."""

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import OBSERVE_POSTURE, READY_POSTURE
from tsrrt_executor.errors import TrajectoryError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.push_primitives import PHASE_APPROACH, push_geometry, workspace_segments
from tsrrt_executor.trajectory import (
    JointMove,
    PhaseProgress,
    TimingSettings,
    time_parameterise,
    trapezoid_profile,
)


@pytest.fixture(scope="module")
def ik():
    return PusherIK()


def test_trapezoid_profile_reaches_the_end_within_limits():
    t, s, s_dot, s_ddot = trapezoid_profile(0.2, 0.3, 1.0, 0.01)
    assert s[0] == 0.0 and s[-1] == pytest.approx(0.2)
    assert s_dot[0] == 0.0 and s_dot[-1] == 0.0
    assert s_dot.max() == pytest.approx(0.3) and np.abs(s_ddot).max() == pytest.approx(1.0)
    assert t[-1] == pytest.approx(0.2 / 0.3 + 0.3 / 1.0)   # cruise time + one ramp time
    assert np.all(np.diff(s) >= 0.0)


def test_short_path_gives_a_triangular_profile():
    t, s, s_dot, _ = trapezoid_profile(0.01, 0.3, 1.0, 0.001)
    assert t[-1] == pytest.approx(2 * np.sqrt(0.01 / 1.0))
    assert s_dot.max() <= np.sqrt(0.01 * 1.0) + 1e-12
    assert s[-1] == pytest.approx(0.01)


def primitive_trajectory(ik, primitive, settings=None, q_start=OBSERVE_POSTURE):
    """A joint move from q_start to above the approach point, then the tool-down path."""
    geometry = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.5, 0.1, 0.4), primitive)
    q_above, _ = ik.solve(geometry.pre_approach_point)
    motions = [JointMove("transit", PHASE_APPROACH, q_above), *workspace_segments(geometry)]
    return geometry, time_parameterise(ik, motions, np.array(q_start), settings)


@pytest.mark.parametrize("primitive", [1, 5])
@pytest.mark.parametrize("velocity_scale", [0.5, 0.1])
def test_joint_limits_respected(ik, primitive, velocity_scale):
    settings = TimingSettings(velocity_scale=velocity_scale, acceleration_scale=velocity_scale)
    _, trajectory = primitive_trajectory(ik, primitive, settings)
    assert np.all(np.abs(trajectory.velocities) <= ik.velocity_limits * velocity_scale + 1e-9)
    assert np.all(np.abs(trajectory.accelerations)
                  <= ik.acceleration_limits * velocity_scale + 1e-9)
    # The stated velocities are those of the positions (no limit hidden by wrong derivatives):
    # a finite difference over steps dt differs from the true velocity by at most a_max dt.
    numeric = np.gradient(trajectory.positions, trajectory.times, axis=0)
    bound = ik.acceleration_limits * velocity_scale * np.diff(trajectory.times).max()
    assert np.all(np.abs(numeric - trajectory.velocities) <= bound + 1e-3)
    assert np.all(np.diff(trajectory.times) > 0.0) and trajectory.times[0] == 0.0


def test_slower_limits_give_a_longer_trajectory(ik):
    _, fast = primitive_trajectory(ik, 2, TimingSettings(velocity_scale=0.5))
    _, slow = primitive_trajectory(ik, 2, TimingSettings(velocity_scale=0.05,
                                                         acceleration_scale=0.05))
    assert slow.duration > 2.0 * fast.duration


def test_push_moves_the_ball_at_constant_speed_along_the_vector(ik):
    geometry, trajectory = primitive_trajectory(ik, 3)
    tool = ik.tool_positions(trajectory.positions)
    np.testing.assert_allclose(tool, trajectory.tool_targets, atol=1e-4)
    pushing = np.array([name == "push" for name in trajectory.segment_names])
    along = (tool[pushing, :2] - geometry.approach_xy) @ geometry.direction
    # Touching the object: past the approach clearance, before the final 1.25 mm stopping ramp.
    in_contact = (along >= 0.01) & (along <= geometry.push_travel - 0.002)
    speed = np.diff(along[in_contact]) / np.diff(trajectory.times[pushing][in_contact])
    np.testing.assert_allclose(speed, 0.05, rtol=0.02)
    np.testing.assert_allclose(tool[pushing, 2], geometry.push_z, atol=1e-4)


def test_phases_in_order_and_ends_at_rest_above_the_object(ik):
    geometry, trajectory = primitive_trajectory(ik, 6)
    starts = trajectory.phase_start_times()
    assert starts["approach"] == 0.0 < starts["push"] < starts["retreat"]
    np.testing.assert_allclose(trajectory.velocities[[0, -1]], 0.0, atol=1e-9)
    np.testing.assert_allclose(trajectory.tool_targets[-1], geometry.post_retreat_point,
                               atol=1e-9)


def test_phase_at_reports_phase_and_progress(ik):
    _, trajectory = primitive_trajectory(ik, 4)
    starts = trajectory.phase_start_times()
    assert trajectory.phase_at(0.0) == ("approach", 0.0)
    phase, progress = trajectory.phase_at(starts["push"] + 0.01)
    assert phase == "push" and 0.0 < progress < 0.1
    assert trajectory.phase_at(trajectory.duration + 1.0) == ("retreat", 1.0)


def test_joint_move_is_a_straight_line_in_joint_space_onto_the_path(ik):
    geometry, trajectory = primitive_trajectory(ik, 1)
    transit = np.array([name == "transit" for name in trajectory.segment_names])
    np.testing.assert_array_equal(trajectory.in_joint_space, transit)
    assert transit[0] and not transit[-1]
    positions = trajectory.positions[transit]
    np.testing.assert_allclose(positions[0], OBSERVE_POSTURE)
    direction = positions[-1] - positions[0]
    fractions = (positions - positions[0]) @ direction / (direction @ direction)
    np.testing.assert_allclose(positions, positions[0] + fractions[:, None] * direction,
                               atol=1e-12)
    np.testing.assert_allclose(ik.tool_position(positions[-1]), geometry.pre_approach_point,
                               atol=1e-4)
    np.testing.assert_allclose(trajectory.velocities[transit][[0, -1]], 0.0, atol=1e-12)


def test_joint_move_to_where_the_arm_is_is_left_out(ik):
    geometry = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.5, 0.1, 0.4), 3)
    q_above, _ = ik.solve(geometry.pre_approach_point)
    motions = [JointMove("transit", PHASE_APPROACH, q_above), *workspace_segments(geometry)]
    trajectory = time_parameterise(ik, motions, q_above)
    assert "transit" not in trajectory.segment_names
    assert not trajectory.in_joint_space.any()
    with pytest.raises(TrajectoryError, match="already there"):
        time_parameterise(ik, motions[:1], q_above)


def test_segment_that_does_not_start_at_the_ball_is_refused(ik):
    geometry = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.5, 0.1, 0.4), 3)
    with pytest.raises(TrajectoryError, match="'descend' starts at"):
        time_parameterise(ik, workspace_segments(geometry), np.array(READY_POSTURE))


def test_nearest_index_follows_the_desired_state_forward(ik):
    _, trajectory = primitive_trajectory(ik, 2)
    middle = len(trajectory.times) // 2
    assert trajectory.nearest_index(trajectory.positions[middle]) == middle
    assert trajectory.nearest_index(trajectory.positions[middle] + 1e-4, middle) == middle
    assert trajectory.nearest_index(trajectory.positions[0], middle) >= middle
    phase, progress = trajectory.phase_at_index(len(trajectory.times) - 1)
    assert (phase, progress) == ("retreat", 1.0)


@pytest.mark.parametrize("field, value", [("push_speed", 0.0), ("velocity_scale", 1.5),
                                          ("sample_period", -0.1), ("push_speed", 0.5)])
def test_bad_settings_rejected(ik, field, value):
    settings = TimingSettings(**{field: value})
    with pytest.raises(TrajectoryError):
        primitive_trajectory(ik, 1, settings)


def test_phase_progress_reports_every_phase_in_order_even_when_reports_are_sparse(ik):
    _, trajectory = primitive_trajectory(ik, 5)
    progress = PhaseProgress(trajectory)
    push_start = trajectory.phases.index("push")
    assert progress.update(trajectory.positions[3]) == [("approach", pytest.approx(
        trajectory.phase_at_index(3)[1]))]
    # The next report comes after the push is over: the push is reported completed.
    late = len(trajectory.times) - 3
    updates = progress.update(trajectory.positions[late])
    assert [phase for phase, _ in updates] == ["approach", "push", "retreat"]
    assert [fraction for _, fraction in updates[:2]] == [1.0, 1.0]
    # A stale report (an earlier desired state) does not go back.
    assert progress.update(trajectory.positions[push_start]) == [
        ("retreat", pytest.approx(updates[-1][1]))]
    assert progress.finish() == [("retreat", 1.0)]
    assert progress.update(trajectory.positions[late]) == []
