"""Trajectory validation, interpolation and tolerance rules (no physics)."""

import math
import re

import numpy as np
import pytest

from tsrrt_common.robot_model import ARM_JOINT_NAMES, READY_POSTURE
from tsrrt_sim.kinematics import PusherKinematics
from tsrrt_sim.trajectory_controller import (
    JointToleranceOverride,
    SetPoint,
    Tolerances,
    TrajectoryError,
    TrajectoryErrorCode,
    TrajectoryExecution,
    evaluate_segment,
    resolve_tolerances,
    segment_coefficients,
    validate_trajectory,
)

LIMITS = PusherKinematics().limits
READY = list(READY_POSTURE)
NAMES = list(ARM_JOINT_NAMES)


def nudged(delta: float, joint: int = 0) -> list[float]:
    q = list(READY)
    q[joint] += delta
    return q


def validate(names=NAMES, times=(1.0, 2.0), positions=None, velocities=None,
             accelerations=None):
    positions = positions if positions is not None else [nudged(0.1), nudged(0.2)]
    velocities = velocities if velocities is not None else [[]] * len(positions)
    accelerations = accelerations if accelerations is not None else [[]] * len(positions)
    return validate_trajectory(names, list(times), positions, velocities, accelerations, LIMITS)


def test_valid_trajectory_is_reordered_to_arm_joint_order():
    permutation = [6, 0, 5, 1, 4, 2, 3]
    names = [NAMES[i] for i in permutation]
    targets = [nudged(0.1), nudged(0.2, joint=3)]
    trajectory = validate(names=names, positions=[[q[i] for i in permutation] for q in targets])
    np.testing.assert_allclose(trajectory.positions, np.array(targets))
    assert trajectory.velocities is None and trajectory.accelerations is None
    assert trajectory.duration == 2.0


BAD_GOALS = {
    "unknown joint": (dict(names=NAMES[:6] + ["elbow"]), TrajectoryErrorCode.INVALID_JOINTS,
                      "unknown joints ['elbow']"),
    "missing joint": (dict(names=NAMES[:6], positions=[READY[:6]]),
                      TrajectoryErrorCode.INVALID_JOINTS, "missing"),
    "duplicate joint": (dict(names=NAMES[:6] + [NAMES[0]]), TrajectoryErrorCode.INVALID_JOINTS,
                        "more than once"),
    "no points": (dict(times=(), positions=[]), TrajectoryErrorCode.INVALID_GOAL, "no points"),
    "nan position": (dict(positions=[nudged(0.1), nudged(math.nan)]),
                     TrajectoryErrorCode.INVALID_GOAL, "non-finite"),
    "non-increasing times": (dict(times=(1.0, 1.0)), TrajectoryErrorCode.INVALID_GOAL,
                             "strictly increase"),
    "negative time": (dict(times=(-1.0, 2.0)), TrajectoryErrorCode.INVALID_GOAL, ">= 0"),
    "beyond position limit": (dict(positions=[nudged(0.1), nudged(2.5, joint=3)]),
                              TrajectoryErrorCode.INVALID_GOAL, "beyond its limits"),
    "beyond velocity limit": (dict(velocities=[[0.0] * 7, [5.0] + [0.0] * 6]),
                              TrajectoryErrorCode.INVALID_GOAL, "exceeds its limit"),
    "too fast between points": (dict(times=(1.0, 1.01)), TrajectoryErrorCode.INVALID_GOAL,
                                "on average"),
    "ragged velocities": (dict(velocities=[[0.0] * 7, [0.0] * 3]),
                          TrajectoryErrorCode.INVALID_GOAL, "velocities"),
    "accelerations without velocities": (dict(accelerations=[[0.0] * 7, [0.0] * 7]),
                                         TrajectoryErrorCode.INVALID_GOAL, "without velocities"),
}


@pytest.mark.parametrize("case", sorted(BAD_GOALS))
def test_bad_trajectories_are_refused_with_code_and_reason(case):
    kwargs, code, reason = BAD_GOALS[case]
    with pytest.raises(TrajectoryError, match=re.escape(reason)) as caught:
        validate(**kwargs)
    assert caught.value.code is code


@pytest.mark.parametrize("degree", [1, 3, 5])
def test_segments_meet_their_waypoints_and_are_consistent(degree):
    rng = np.random.default_rng(7)
    start = SetPoint(*rng.normal(size=(3, 7)))
    end = SetPoint(*rng.normal(size=(3, 7)))
    duration = 0.8
    coefficients = segment_coefficients(start, end, duration, degree)
    at_start, at_end = evaluate_segment(coefficients, 0.0), evaluate_segment(coefficients,
                                                                            duration)
    np.testing.assert_allclose(at_start.positions, start.positions, atol=1e-12)
    np.testing.assert_allclose(at_end.positions, end.positions, atol=1e-12)
    if degree >= 3:
        np.testing.assert_allclose(at_start.velocities, start.velocities, atol=1e-12)
        np.testing.assert_allclose(at_end.velocities, end.velocities, atol=1e-10)
    if degree == 5:
        np.testing.assert_allclose(at_start.accelerations, start.accelerations, atol=1e-12)
        np.testing.assert_allclose(at_end.accelerations, end.accelerations, atol=1e-9)
    # Velocity and acceleration are the derivatives of the sampled position and velocity.
    s, h = 0.37, 1e-6
    before, middle, after = (evaluate_segment(coefficients, t) for t in (s - h, s, s + h))
    np.testing.assert_allclose((after.positions - before.positions) / (2 * h),
                               middle.velocities, atol=1e-6)
    np.testing.assert_allclose((after.velocities - before.velocities) / (2 * h),
                               middle.accelerations, atol=1e-5)


def test_sampling_starts_from_the_state_before_the_goal_and_ends_at_rest():
    trajectory = validate(times=(1.0, 2.0))
    before = SetPoint.at_rest(np.array(READY))
    execution = TrajectoryExecution(trajectory, Tolerances.uniform(0.1, 0, 0.01, 0.01, 1.0),
                                    start_time=10.0, state_before=before, time_before=10.0)
    np.testing.assert_allclose(execution.sample(10.0).positions, READY)
    np.testing.assert_allclose(execution.sample(10.5).positions, nudged(0.05))
    np.testing.assert_allclose(execution.sample(11.5).positions, nudged(0.15))
    final = execution.sample(12.5)
    np.testing.assert_allclose(final.positions, nudged(0.2))
    assert not final.velocities.any()


def test_a_first_waypoint_already_in_the_past_is_jumped_to():
    trajectory = validate(times=(1.0, 2.0))
    execution = TrajectoryExecution(trajectory, Tolerances.uniform(0.1, 0, 0.01, 0.01, 1.0),
                                    start_time=10.0, state_before=SetPoint.at_rest(np.zeros(7)),
                                    time_before=11.2)
    np.testing.assert_allclose(execution.sample(11.2).positions, nudged(0.12))


def test_goal_tolerances_follow_joint_tolerance_rules():
    defaults = Tolerances.uniform(path_position=0.1, path_velocity=0.0, goal_position=0.01,
                                  goal_velocity=0.01, goal_time=1.0)
    assert math.isinf(defaults.path_velocity[0])          # 0 means unchecked by default
    resolved = resolve_tolerances(
        defaults, path=[JointToleranceOverride(NAMES[1], 0.3, 0.0),
                        JointToleranceOverride(NAMES[2], -1.0, 0.5)],
        goal=[JointToleranceOverride(NAMES[0], 0.0, 0.2)], goal_time=0.0)
    assert resolved.path_position[1] == 0.3                  # positive replaces
    assert math.isinf(resolved.path_position[2])             # negative removes the check
    assert resolved.path_velocity[2] == 0.5
    assert resolved.path_position[0] == 0.1                  # 0 keeps the default
    assert resolved.goal_velocity[0] == 0.2
    assert resolved.goal_time == 1.0
    with pytest.raises(TrajectoryError) as caught:
        resolve_tolerances(defaults, [JointToleranceOverride("wrist", 0.1, 0.1)], [], 0.0)
    assert caught.value.code is TrajectoryErrorCode.INVALID_JOINTS
