"""Pinocchio IK: analytic Jacobian vs finite differences, accuracy, limits, unreachable targets."""

import numpy as np
import pybullet
import pytest

from tsrrt_common.robot_model import READY_POSTURE, TOOL_FRAME, pusher_urdf_path
from tsrrt_executor.errors import IKError
from tsrrt_executor.inverse_kinematics import PusherIK


@pytest.fixture(scope="module")
def ik():
    return PusherIK()


def random_configurations(ik, count, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(ik.lower_limits, ik.upper_limits, size=(count, 7))


def test_task_jacobian_matches_finite_differences(ik):
    target = np.array([0.5, 0.1, 0.05])
    eps = 1e-6
    for q in random_configurations(ik, 5, seed=1):
        analytic = ik.task_jacobian(q)                                   # (6, 7)
        numeric = np.empty_like(analytic)
        for j in range(7):
            dq = np.zeros(7)
            dq[j] = eps
            numeric[:, j] = (ik.task_residual(q + dq, target)
                             - ik.task_residual(q - dq, target)) / (2 * eps)
        np.testing.assert_allclose(analytic, numeric, atol=1e-7)


def test_tool_frame_agrees_with_pybullet(ik):
    client = pybullet.connect(pybullet.DIRECT)
    try:
        robot = pybullet.loadURDF(str(pusher_urdf_path()), useFixedBase=True,
                                  flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
                                  physicsClientId=client)
        links = {pybullet.getJointInfo(robot, j, physicsClientId=client)[12].decode(): j
                 for j in range(pybullet.getNumJoints(robot, physicsClientId=client))}
        for q in random_configurations(ik, 5, seed=2):
            for j, value in enumerate(q):
                pybullet.resetJointState(robot, j, value, physicsClientId=client)
            state = pybullet.getLinkState(robot, links[TOOL_FRAME], computeForwardKinematics=True,
                                          physicsClientId=client)
            np.testing.assert_allclose(ik.tool_position(q), state[4], atol=1e-6)
    finally:
        pybullet.disconnect(client)


def test_solutions_are_accurate_to_a_tenth_of_a_millimetre(ik):
    rng = np.random.default_rng(3)
    targets = np.column_stack([rng.uniform(0.38, 0.62, 20), rng.uniform(-0.25, 0.25, 20),
                               rng.uniform(0.014, 0.15, 20)])
    for target in targets:
        q, _ = ik.solve(target)
        position, axis = ik.tool_pose(q)
        assert np.linalg.norm(position - target) <= 1e-4
        np.testing.assert_allclose(axis, [0.0, 0.0, -1.0], atol=1e-3)


def test_joint_limits_respected_where_they_bind(ik):
    # Close to the base the elbow folds onto its lower limit; solutions must stay inside.
    closest_to_limit = np.inf
    for x in np.linspace(0.26, 0.34, 9):
        try:
            q, _ = ik.solve(np.array([x, 0.0, 0.014]))
        except IKError:
            continue
        assert np.all(q >= ik.model.lowerPositionLimit)
        assert np.all(q <= ik.model.upperPositionLimit)
        closest_to_limit = min(closest_to_limit, float(np.min(np.minimum(
            q - ik.model.lowerPositionLimit, ik.model.upperPositionLimit - q))))
    assert closest_to_limit < 0.02  # the limit was active for at least one target


@pytest.mark.parametrize("target", [[0.95, 0.0, 0.014], [0.45, 0.0, 1.2], [1.0, 0.5, 0.5]])
def test_unreachable_targets_raise_with_residual(ik, target):
    with pytest.raises(IKError, match="no IK solution") as caught:
        ik.solve(np.array(target))
    assert caught.value.position_error > 1e-3


def test_path_is_warm_started_and_continuous(ik):
    targets = np.linspace([0.40, -0.15, 0.10], [0.55, 0.15, 0.014], 60)
    path, iterations = ik.solve_path(targets, np.array(READY_POSTURE))
    assert path.shape == (60, 7)
    assert np.abs(np.diff(path, axis=0)).max() < 0.05   # no branch switch between waypoints
    assert iterations < 4 * len(targets)                 # warm start: a few iterations each
    np.testing.assert_allclose(ik.tool_positions(path), targets, atol=1e-4)


def test_path_failure_names_the_waypoint(ik):
    targets = np.array([[0.5, 0.0, 0.05], [0.95, 0.0, 0.05]])
    with pytest.raises(IKError, match="waypoint 1 of 2"):
        ik.solve_path(targets)
