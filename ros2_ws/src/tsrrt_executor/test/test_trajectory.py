"""Time parameterisation: profiles, joint limits, constant push speed, the joint-space prepare."""

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import READY_POSTURE
from tsrrt_executor.errors import TrajectoryError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.push_primitives import push_geometry, workspace_segments
from tsrrt_executor.trajectory import TimingSettings, time_parameterise, trapezoid_profile


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


def primitive_trajectory(ik, primitive, settings=None, q_start=READY_POSTURE):
    geometry = push_geometry("box", 0.12, 0.05, 0.03, Pose2D(0.5, 0.1, 0.4), primitive)
    q_start = np.array(q_start)
    segments = workspace_segments(geometry, ik.tool_position(q_start))
    return geometry, time_parameterise(ik, segments, q_start, settings)


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


def test_prepare_move_from_a_configuration_off_the_path(ik):
    q_start = np.array(READY_POSTURE) + np.array([0.2, 0.1, -0.1, 0.1, 0.2, -0.1, 0.3])
    _, trajectory = primitive_trajectory(ik, 1, q_start=q_start)
    assert trajectory.segment_names[0] == "prepare"
    np.testing.assert_allclose(trajectory.positions[0], q_start)
    prepare = np.array([name == "prepare" for name in trajectory.segment_names])
    axis_after = ik.tool_pose(trajectory.positions[prepare][-1])[1]
    np.testing.assert_allclose(axis_after, [0.0, 0.0, -1.0], atol=1e-3)


@pytest.mark.parametrize("field, value", [("push_speed", 0.0), ("velocity_scale", 1.5),
                                          ("sample_period", -0.1), ("push_speed", 0.5)])
def test_bad_settings_rejected(ik, field, value):
    settings = TimingSettings(**{field: value})
    with pytest.raises(TrajectoryError):
        primitive_trajectory(ik, 1, settings)
