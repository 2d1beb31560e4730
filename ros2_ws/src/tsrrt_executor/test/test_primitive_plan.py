"""Planning a primitive end to end (no ROS): valid goals plan, each bad goal raises its error."""

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import READY_POSTURE
from tsrrt_executor.errors import PrimitiveError, UnreachableError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.primitive_plan import TableObject, plan_primitive, retreat_trajectory

READY = np.array(READY_POSTURE)


@pytest.fixture(scope="module")
def ik():
    return PusherIK()


def eraser(x=0.45, y=0.0, theta=0.0, name="eraser"):
    return TableObject(name, "box", 0.12, 0.05, 0.03, Pose2D(x, y, theta))


def plate(x, y):
    return TableObject("plate", "cylinder", 0.10, 0.10, 0.015, Pose2D(x, y, 0.0))


def test_plan_ends_above_the_pushed_point(ik):
    plan = plan_primitive(ik, eraser(), [plate(0.45, 0.2)], 3, 0.0, READY)
    assert plan.geometry.push_length == 0.05               # 0 asks for the default
    np.testing.assert_allclose(ik.tool_position(plan.trajectory.positions[-1]),
                               plan.geometry.post_retreat_point, atol=1e-4)
    assert plan.planning_ms > 0.0


def test_safe_height_rises_for_a_tall_neighbour(ik):
    tall = TableObject("box", "box", 0.1, 0.1, 0.12, Pose2D(0.45, 0.3, 0.0))
    plan = plan_primitive(ik, eraser(), [tall], 1, 0.05, READY)
    assert plan.geometry.safe_z == pytest.approx(0.12 + 0.012 + 0.02)


def test_blocked_approach_names_the_blocker(ik):
    # Primitive 3 approaches the eraser from -y; a plate right there blocks the ball.
    with pytest.raises(UnreachableError, match="blocked by 'plate'"):
        plan_primitive(ik, eraser(), [plate(0.45, -0.09)], 3, 0.05, READY)


def test_tall_object_next_to_the_push_is_hit_by_the_hand(ik):
    tall = TableObject("tower", "box", 0.05, 0.05, 0.12, Pose2D(0.45, 0.15, 0.0))
    with pytest.raises(UnreachableError, match="hand would hit 'tower'"):
        plan_primitive(ik, eraser(), [tall], 1, 0.05, READY)


def test_unreachable_push_reported(ik):
    with pytest.raises(UnreachableError, match="reachable workspace"):
        plan_primitive(ik, eraser(x=0.34), [], 1, 0.05, READY)


@pytest.mark.parametrize("primitive, push_length, message", [
    (5, 0.05, "does not exist for a disc"), (0, 0.05, "not one of"),
    (1, 0.2, "push length"), (1, -0.01, "push length")])
def test_bad_goals_on_a_disc(ik, primitive, push_length, message):
    with pytest.raises(PrimitiveError, match=message):
        plan_primitive(ik, plate(0.45, 0.0), [], primitive, push_length, READY)


def test_retreat_lifts_the_ball_vertically(ik):
    plan = plan_primitive(ik, eraser(), [], 2, 0.05, READY)
    pushing = [i for i, name in enumerate(plan.trajectory.segment_names) if name == "push"]
    q_mid_push = plan.trajectory.positions[pushing[len(pushing) // 2]]
    retreat = retreat_trajectory(ik, q_mid_push, plan.geometry.safe_z)
    tool = ik.tool_positions(retreat.positions)
    np.testing.assert_allclose(tool[:, :2] - tool[0, :2], 0.0, atol=1e-4)
    assert tool[-1, 2] == pytest.approx(plan.geometry.safe_z, abs=1e-4)
    assert retreat_trajectory(ik, retreat.positions[-1], plan.geometry.safe_z) is None
