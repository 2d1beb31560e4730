"""Planning a primitive end to end (no ROS): valid goals plan, each bad goal raises its error,
and the joint-space moves to and from the observe posture keep the arm above the objects."""

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import BALL_RADIUS, OBSERVE_POSTURE, READY_POSTURE
from tsrrt_executor.errors import PrimitiveError, UnreachableError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.primitive_plan import (
    TableObject,
    check_joint_moves_clear,
    lift_trajectory,
    lowest_arm_point,
    plan_primitive,
    return_to_observe,
)
from tsrrt_executor.push_primitives import PHASE_APPROACH
from tsrrt_executor.trajectory import JointMove, time_parameterise

READY = np.array(READY_POSTURE)
OBSERVE = np.array(OBSERVE_POSTURE)


@pytest.fixture(scope="module")
def ik():
    return PusherIK()


def eraser(x=0.45, y=0.0, theta=0.0, name="eraser"):
    return TableObject(name, "box", 0.12, 0.05, 0.03, Pose2D(x, y, theta))


def plate(x, y):
    return TableObject("plate", "cylinder", 0.10, 0.10, 0.015, Pose2D(x, y, 0.0))


def test_plan_runs_from_the_arm_over_the_push_back_to_the_observe_posture(ik):
    plan = plan_primitive(ik, eraser(), [plate(0.45, 0.2)], 3, 0.0, OBSERVE)
    assert plan.geometry.push_length == 0.05               # 0 asks for the default
    trajectory = plan.trajectory
    assert list(dict.fromkeys(trajectory.segment_names)) == [
        "transit", "descend", "push", "back_off", "retreat", "return"]
    np.testing.assert_allclose(trajectory.positions[[0, -1]], [OBSERVE, OBSERVE])
    retreat_end = max(i for i, name in enumerate(trajectory.segment_names) if name == "retreat")
    np.testing.assert_allclose(ik.tool_position(trajectory.positions[retreat_end]),
                               plan.geometry.post_retreat_point, atol=1e-4)
    assert plan.planning_ms > 0.0


@pytest.mark.parametrize("x, y, theta", [(0.36, -0.2, 0.5), (0.45, 0.0, 0.0), (0.58, 0.22, 2.0),
                                         (0.55, -0.22, -1.2)])
def test_joint_moves_stay_above_the_safe_height(ik, x, y, theta):
    plan = plan_primitive(ik, eraser(x, y, theta), [], 6, 0.05, OBSERVE)
    joint_space = plan.trajectory.positions[plan.trajectory.in_joint_space]
    lowest = min(lowest_arm_point(ik, q) for q in joint_space)
    assert lowest >= plan.geometry.safe_z - BALL_RADIUS - 1e-3


def test_low_joint_move_is_refused(ik):
    q_low_a, _ = ik.solve(np.array([0.40, -0.15, 0.02]))
    q_low_b, _ = ik.solve(np.array([0.40, 0.15, 0.02]))
    sweep = time_parameterise(ik, [JointMove("sweep", PHASE_APPROACH, q_low_b)], q_low_a)
    with pytest.raises(UnreachableError, match="'sweep' would bring the arm down"):
        check_joint_moves_clear(ik, sweep, 0.10)


def test_safe_height_rises_for_a_tall_neighbour(ik):
    tall = TableObject("box", "box", 0.1, 0.1, 0.12, Pose2D(0.45, 0.3, 0.0))
    plan = plan_primitive(ik, eraser(), [tall], 1, 0.05, OBSERVE)
    assert plan.geometry.safe_z == pytest.approx(0.12 + 0.012 + 0.02)


def test_blocked_approach_names_the_blocker(ik):
    # Primitive 3 approaches the eraser from -y; a plate right there blocks the ball.
    with pytest.raises(UnreachableError, match="blocked by 'plate'"):
        plan_primitive(ik, eraser(), [plate(0.45, -0.09)], 3, 0.05, OBSERVE)


def test_tall_object_next_to_the_push_is_hit_by_the_hand(ik):
    tall = TableObject("tower", "box", 0.05, 0.05, 0.12, Pose2D(0.45, 0.15, 0.0))
    with pytest.raises(UnreachableError, match="hand would hit 'tower'"):
        plan_primitive(ik, eraser(), [tall], 1, 0.05, OBSERVE)


def test_unreachable_push_reported(ik):
    with pytest.raises(UnreachableError, match="reachable workspace"):
        plan_primitive(ik, eraser(x=0.34), [], 1, 0.05, OBSERVE)


@pytest.mark.parametrize("primitive, push_length, message", [
    (5, 0.05, "does not exist for a disc"), (0, 0.05, "not one of"),
    (1, 0.2, "push length"), (1, -0.01, "push length")])
def test_bad_goals_on_a_disc(ik, primitive, push_length, message):
    with pytest.raises(PrimitiveError, match=message):
        plan_primitive(ik, plate(0.45, 0.0), [], primitive, push_length, OBSERVE)


def test_return_to_observe_lifts_the_ball_vertically_first(ik):
    plan = plan_primitive(ik, eraser(), [], 2, 0.05, OBSERVE)
    pushing = [i for i, name in enumerate(plan.trajectory.segment_names) if name == "push"]
    q_mid_push = plan.trajectory.positions[pushing[len(pushing) // 2]]
    back = return_to_observe(ik, q_mid_push, plan.geometry.safe_z)
    assert list(dict.fromkeys(back.segment_names)) == ["lift", "return"]
    lift = np.array([name == "lift" for name in back.segment_names])
    tool = ik.tool_positions(back.positions[lift])
    np.testing.assert_allclose(tool[:, :2] - tool[0, :2], 0.0, atol=1e-4)
    assert tool[-1, 2] == pytest.approx(plan.geometry.safe_z, abs=1e-4)
    np.testing.assert_allclose(back.positions[-1], OBSERVE)
    assert return_to_observe(ik, back.positions[-1], plan.geometry.safe_z) is None
    assert lift_trajectory(ik, q_mid_push, plan.geometry.safe_z).duration < back.duration
    assert lift_trajectory(ik, OBSERVE, plan.geometry.safe_z) is None


def test_return_from_the_ready_posture_is_one_joint_move(ik):
    back = return_to_observe(ik, READY, 0.10)
    assert set(back.segment_names) == {"return"} and back.in_joint_space.all()


def test_low_ball_with_a_tilted_tool_is_not_lifted(ik):
    q_tilted, _ = ik.solve(np.array([0.45, 0.0, 0.05]))
    q_tilted[5] += 0.3
    with pytest.raises(UnreachableError, match="cannot be lifted straight up"):
        return_to_observe(ik, q_tilted, 0.10)
