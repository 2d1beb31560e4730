"""ExecutePrimitive through the ROS graph: sim_node + perception_node + executor_node.

The three nodes run as processes with their parameter files on a ROS domain of their own (see
conftest.py), the simulator at full speed. Each primitive is run on a box (the `clean` scenario's
scale, where all six are reachable) and on a disc (a plate of `tset3`), and the displacement
perception measured is checked for direction and size; then bad goals, an object pushed out of
reach, a cancel, and an executor without a robot.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = pytest.mark.integration

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("tsrrt_interfaces.action")
from action_msgs.msg import GoalStatus  # noqa: E402
from builtin_interfaces.msg import Duration  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from trajectory_msgs.msg import JointTrajectoryPoint  # noqa: E402

from tsrrt_common.geometry import Pose2D  # noqa: E402
from tsrrt_common.robot_model import ARM_JOINT_NAMES, OBSERVE_POSTURE, READY_POSTURE  # noqa: E402
from tsrrt_common.scenario import load_scenario  # noqa: E402
from tsrrt_interfaces.action import ExecutePrimitive, FollowJointTrajectory  # noqa: E402
from tsrrt_interfaces.msg import ObjectState, ObjectStateArray  # noqa: E402
from tsrrt_interfaces.srv import DisturbObject, LoadScenario  # noqa: E402

Result = ExecutePrimitive.Result
Feedback = ExecutePrimitive.Feedback
BOX_SCENARIO, BOX = "clean", "scale"
DISC_SCENARIO = "tset3"
PUSH = 0.05
# A push of 5 cm moves the object 3.5-6 cm along the push and at most 1.5 cm across it.
ALONG, ACROSS = (0.035, 0.06), 0.015
ALL_PHASES = [Feedback.PHASE_PLANNING, Feedback.PHASE_APPROACH, Feedback.PHASE_PUSH,
              Feedback.PHASE_RETREAT, Feedback.PHASE_SETTLING]


class ExecutorProbe:
    """The test's side of the graph: the action, perception's objects, the sim's services."""

    def __init__(self, probe) -> None:
        self.probe = probe
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.perceived = probe.record(ObjectStateArray, "/perception/objects", reliable)
        self.truths = probe.record(ObjectStateArray, "/sim/object_states", reliable)
        self.action = ActionClient(probe, ExecutePrimitive, "/executor/execute_primitive")
        self.feedback_topic = probe.record(
            ExecutePrimitive.Impl.FeedbackMessage,
            "/executor/execute_primitive/_action/feedback",
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.arm = ActionClient(probe, FollowJointTrajectory,
                                "/arm_controller/follow_joint_trajectory")
        self.disturb = probe.create_client(DisturbObject, "/sim/disturb_object")
        self.load = probe.create_client(LoadScenario, "/sim/load_scenario")
        self.executor_parameters = probe.create_client(SetParameters,
                                                       "/executor_node/set_parameters")

    def run(self, object_id: str, primitive: int, push_length: float = 0.0,
            feedback: list | None = None):
        """Execute one primitive; returns the result wrapper (status and result).

        Feedback and the result travel on separate topics with no order between them, and
        rclpy's action client drops a goal's feedback once its result is in: under load (CI with
        a benchmark beside it) the settling feedback came after the result and was lost. So the
        feedback is read from the action's feedback topic, waiting up to 5 s for the last one."""
        goal = ExecutePrimitive.Goal(object_id=object_id, primitive=primitive,
                                     push_length=push_length)
        handle = self.probe.send_goal(self.action, goal)
        assert handle.accepted, "goal rejected"
        outcome = self.probe.wait_for(handle.get_result_async(), 120.0)
        if feedback is not None:
            def of_this_goal() -> list:
                return [m for m in self.feedback_topic if bytes(m.goal_id.uuid) ==
                        bytes(handle.goal_id.uuid)]

            if outcome.result.error_code == Result.SUCCESS:
                self.probe.spin_until(lambda: any(
                    m.feedback.phase == Feedback.PHASE_SETTLING and m.feedback.progress >= 1.0
                    for m in of_this_goal()), 5.0)
            feedback.extend(of_this_goal())
        return outcome

    def tracked(self, object_class: str, x: float, y: float, timeout: float = 60.0
                ) -> ObjectState:
        """Wait until perception tracks an object of the class within 1 cm of (x, y)."""
        def find() -> ObjectState | None:
            if not self.perceived:
                return None
            return next((o for o in self.perceived[-1].objects
                         if o.status == ObjectState.STATUS_TRACKED
                         and o.object_class == object_class
                         and math.hypot(o.x - x, o.y - y) < 0.01), None)

        assert self.probe.spin_until(lambda: find() is not None, timeout), \
            f"perception does not track a {object_class} at ({x:.3f}, {y:.3f})"
        return find()

    def move_arm(self, posture: tuple[float, ...], duration: float = 3.0) -> None:
        """Drive the arm to `posture` with the sim's trajectory action (around the executor)."""
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = list(ARM_JOINT_NAMES)
        goal.trajectory.points = [JointTrajectoryPoint(
            positions=list(posture), velocities=[0.0] * len(posture),
            time_from_start=Duration(sec=int(duration)))]
        result = self.probe.execute(self.arm, goal).result
        assert result.error_code == FollowJointTrajectory.Result.SUCCESSFUL, result.error_string

    def set_executor_parameter(self, name: str, value: float) -> None:
        parameter = Parameter(name=name, value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE, double_value=value))
        answer = self.probe.call(self.executor_parameters,
                                 SetParameters.Request(parameters=[parameter]),
                                 resend_after=10.0)
        assert answer.results[0].successful, answer.results[0].reason

    def joint_positions(self) -> np.ndarray:
        return np.array(self.probe.next_message(JointState, "/joint_states").position)


@pytest.fixture(scope="module")
def graph(launch, graph_probe) -> ExecutorProbe:
    launch.start("tsrrt_sim", "sim_node", f"scenario:={BOX_SCENARIO}")
    launch.start("tsrrt_perception", "perception_node", f"scenario:={BOX_SCENARIO}")
    launch.start("tsrrt_executor", "executor_node")
    graph = ExecutorProbe(graph_probe)
    assert graph.action.wait_for_server(timeout_sec=60.0), "no /executor/execute_primitive"
    return graph


@pytest.fixture(scope="module")
def plate(graph) -> str:
    """Perception's id of tset3's plate_1, after loading tset3 into the running sim."""
    answer = graph.probe.call(graph.load, LoadScenario.Request(scenario=DISC_SCENARIO, seed=-1))
    assert answer.success, answer.message
    spec = next(o for o in load_scenario(DISC_SCENARIO).objects if o.id == "plate_1")
    return graph.tracked("plate", spec.pose.x, spec.pose.y).id


def expected_direction(primitive: int) -> np.ndarray:
    """Sign of (dx, dy, dtheta) that a primitive is meant to produce (0: not its purpose)."""
    return np.array({1: (1, 0, 0), 2: (-1, 0, 0), 3: (0, 1, 0), 4: (0, -1, 0),
                     5: (0, 0, 1), 6: (0, 0, -1)}[primitive])


def check_push(outcome, object_id: str, primitive: int, feedback: list) -> None:
    """Succeeded, moved the object the way the primitive means to, reported it consistently."""
    result = outcome.result
    assert result.error_code == Result.SUCCESS, result.error_msg
    assert outcome.status == GoalStatus.STATUS_SUCCEEDED
    before, after, d = result.before, result.after, np.array(result.displacement)
    assert before.id == after.id == object_id
    assert before.status == after.status == ObjectState.STATUS_TRACKED
    moved = Pose2D(before.x, before.y, before.theta).apply_displacement(d)
    np.testing.assert_allclose([moved.x, moved.y], [after.x, after.y], atol=1e-9)
    direction = expected_direction(primitive)
    if primitive <= 4:
        axis = int(np.flatnonzero(direction[:2])[0])
        assert ALONG[0] <= direction[axis] * d[axis] <= ALONG[1], d
        assert abs(d[1 - axis]) <= ACROSS, d
        assert abs(d[2]) < 0.15, d
    else:
        assert direction[2] * d[2] > 0.1, d                 # turns the intended way
    assert 0.0 < result.tool_rms_error < 1e-3
    assert result.ik_ms > 0.0
    phases = [message.feedback.phase for message in feedback]
    assert phases == sorted(phases), phases                 # never back to an earlier phase
    assert list(dict.fromkeys(phases)) == ALL_PHASES, phases


@pytest.mark.parametrize("primitive", [2, 1, 3, 4, 5, 6])   # pairs undo each other
def test_box_primitive_moves_the_object_as_intended(graph, primitive):
    feedback: list = []
    check_push(graph.run(BOX, primitive, PUSH, feedback), BOX, primitive, feedback)


def test_arm_waits_out_of_the_cameras_view_after_a_push(graph):
    np.testing.assert_allclose(graph.joint_positions(), OBSERVE_POSTURE, atol=0.01)


def test_arm_in_the_cameras_view_is_parked_before_the_observation(graph):
    # At the ready posture the arm hides the remote from the camera: perception could not settle
    # on a "before" observation (OBJECT_LOST) unless the executor moved the arm out of view.
    graph.move_arm(READY_POSTURE)
    feedback: list = []
    check_push(graph.run("remote", 3, PUSH, feedback), "remote", 3, feedback)
    np.testing.assert_allclose(graph.joint_positions(), OBSERVE_POSTURE, atol=0.01)


def test_unknown_object_names_the_known_ones(graph):
    result = graph.run("stapler", 1).result
    assert result.error_code == Result.UNKNOWN_OBJECT
    assert "'stapler'" in result.error_msg
    for known in ("eraser", "remote", "scale"):
        assert f"'{known}'" in result.error_msg


@pytest.mark.parametrize("primitive, push_length, message", [
    (0, 0.05, "not one of"), (7, 0.05, "not one of"),
    (1, 0.3, "push length"), (2, -0.01, "push length")])
def test_bad_goals_are_invalid(graph, primitive, push_length, message):
    result = graph.run(BOX, primitive, push_length).result
    assert result.error_code == Result.INVALID_GOAL
    assert message in result.error_msg


@pytest.mark.parametrize("primitive", [1, 2, 3, 4])
def test_disc_primitive_moves_the_plate_as_intended(graph, plate, primitive):
    feedback: list = []
    check_push(graph.run(plate, primitive, PUSH, feedback), plate, primitive, feedback)


def test_rotation_primitive_on_a_disc_is_invalid(graph, plate):
    result = graph.run(plate, 5).result
    assert result.error_code == Result.INVALID_GOAL
    assert "does not exist for a disc" in result.error_msg


def test_cancel_lifts_the_ball_and_returns_the_arm(graph, plate):
    # At full simulation speed a 5 cm push at 5 cm/s is over in a tenth of a wall second: a
    # slow, long push leaves time to cancel it while the ball is down.
    graph.set_executor_parameter("push_speed", 0.005)
    try:
        feedback: list = []
        handle = graph.probe.send_goal(graph.action, ExecutePrimitive.Goal(
            object_id=plate, primitive=2, push_length=0.15), feedback)
        assert handle.accepted
        assert graph.probe.spin_until(lambda: any(
            m.feedback.phase == Feedback.PHASE_PUSH for m in feedback), 60.0)
        graph.probe.wait_for(handle.cancel_goal_async())
        outcome = graph.probe.wait_for(handle.get_result_async(), 60.0)
    finally:
        graph.set_executor_parameter("push_speed", 0.05)
    assert outcome.status == GoalStatus.STATUS_CANCELED
    assert outcome.result.error_code == Result.CANCELED
    assert "lifted" in outcome.result.error_msg
    np.testing.assert_allclose(graph.joint_positions(), OBSERVE_POSTURE, atol=0.01)


def test_object_moved_out_of_reach_is_unreachable(graph, plate):
    # The near edge of the table, in front of the robot (clear of tset3's other objects): the
    # ball cannot come down behind the plate (x = 0.27) to push it away from the robot.
    assert graph.probe.spin_until(lambda: bool(graph.truths))
    where = next(o for o in graph.truths[-1].objects if o.id == "plate_1")
    target = (0.34, -0.15)
    moved = graph.probe.call(graph.disturb, DisturbObject.Request(
        object_id="plate_1", dx=target[0] - where.x, dy=target[1] - where.y, dtheta=0.0))
    assert moved.success, moved.message
    plate_now = graph.tracked("plate", *target).id
    result = graph.run(plate_now, 1).result
    assert result.error_code == Result.UNREACHABLE, result.error_msg
    assert "reachable workspace" in result.error_msg


def test_without_a_robot_the_controller_is_unavailable(launch, probe_on_domain):
    env = launch.other_domain_env()
    launch.start("tsrrt_executor", "executor_node", "server_timeout:=1.0", env=env)
    lonely = probe_on_domain(int(env["ROS_DOMAIN_ID"]))
    action = ActionClient(lonely, ExecutePrimitive, "/executor/execute_primitive")
    result = lonely.execute(action, ExecutePrimitive.Goal(object_id="scale", primitive=1),
                            timeout=60.0).result
    assert result.error_code == Result.CONTROLLER_UNAVAILABLE
    assert "/joint_states" in result.error_msg
