"""executor_node: the ExecutePrimitive action on top of the ROS-free core (primitive_plan).

Action server /executor/execute_primitive (tsrrt_interfaces/action/ExecutePrimitive):
1. before  <- /perception/get_settled_objects (the object's settled state before the push);
2. plan    <- primitive_plan.plan_primitive (goal checks, reachability, clearance, IK, timing);
3. execute -> /arm_controller/follow_joint_trajectory, feedback by phase from the trajectory;
4. after   <- /perception/get_settled_objects; displacement in the object frame at 'before'.
Errors map to the result codes: PrimitiveError -> INVALID_GOAL, UnreachableError -> UNREACHABLE,
IKError -> IK_FAILED, a controller failure or a tool error above max_tool_error ->
TRACKING_FAILED, the object missing/lost after the push -> OBJECT_LOST, no controller or no joint
states -> CONTROLLER_UNAVAILABLE. A cancel stops the controller goal and lifts the ball
vertically to the safe height before the result CANCELED.

Goals are validated in the execute callback, not the goal callback, so that a bad goal gets a
result with its error code and message instead of a bare rejection; the goal callback only
refuses a second goal while one runs (there is one arm). The execute callback blocks on other
actions and services, so it runs in a ReentrantCallbackGroup on a MultiThreadedExecutor.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import rclpy
from builtin_interfaces.msg import Duration
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.action import ActionClient, ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import ARM_JOINT_NAMES
from tsrrt_executor.errors import IKError, PrimitiveError, TrajectoryError, UnreachableError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.primitive_plan import (
    ExecutorSettings,
    TableObject,
    plan_primitive,
    retreat_trajectory,
)
from tsrrt_executor.push_primitives import (
    MAX_PUSH_LENGTH,
    PHASE_APPROACH,
    PHASE_PUSH,
    PHASE_RETREAT,
)
from tsrrt_executor.trajectory import TimedJointTrajectory, TimingSettings
from tsrrt_interfaces.action import ExecutePrimitive, FollowJointTrajectory
from tsrrt_interfaces.msg import ObjectState, ObjectStateArray
from tsrrt_interfaces.srv import GetSettledObjects

Result = ExecutePrimitive.Result
PHASE_CODES = {PHASE_APPROACH: ExecutePrimitive.Feedback.PHASE_APPROACH,
               PHASE_PUSH: ExecutePrimitive.Feedback.PHASE_PUSH,
               PHASE_RETREAT: ExecutePrimitive.Feedback.PHASE_RETREAT}


class GoalFailed(Exception):
    """Ends a goal early with an ExecutePrimitive error code and message."""

    def __init__(self, code: int, message: str) -> None:
        self.code = code
        super().__init__(message)


def table_object(state: ObjectState) -> TableObject:
    return TableObject(state.id, state.shape, state.length, state.width, state.height,
                       Pose2D(state.x, state.y, state.theta))


def trajectory_message(trajectory: TimedJointTrajectory) -> JointTrajectory:
    """trajectory_msgs/JointTrajectory starting when received (zero header stamp)."""
    message = JointTrajectory(joint_names=list(trajectory.joint_names))
    for t, q, qd, qdd in zip(trajectory.times, trajectory.positions, trajectory.velocities,
                             trajectory.accelerations, strict=True):
        seconds = math.floor(t)
        message.points.append(JointTrajectoryPoint(
            positions=q.tolist(), velocities=qd.tolist(), accelerations=qdd.tolist(),
            time_from_start=Duration(sec=int(seconds), nanosec=int(round((t - seconds) * 1e9)))))
    return message


def _float_range(low: float, high: float, description: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, floating_point_range=[
        FloatingPointRange(from_value=low, to_value=high)])


class ExecutorNode(Node):
    """Executes push primitives on perceived objects with the simulated (or a real) arm."""

    def __init__(self) -> None:
        super().__init__("executor_node")
        self._declare_parameters()
        self.ik = PusherIK()
        self.lock = threading.Lock()
        self.joint_positions: np.ndarray | None = None
        self.busy = False
        group = ReentrantCallbackGroup()
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(JointState, "/joint_states", self._on_joint_state, reliable,
                                 callback_group=group)
        self.latest_objects: ObjectStateArray | None = None
        self.create_subscription(ObjectStateArray, "/perception/objects", self._on_objects,
                                 reliable, callback_group=group)
        self.settled_client = self.create_client(
            GetSettledObjects, "/perception/get_settled_objects", callback_group=group)
        self.controller = ActionClient(self, FollowJointTrajectory,
                                       "/arm_controller/follow_joint_trajectory",
                                       callback_group=group)
        self.server = ActionServer(
            self, ExecutePrimitive, "/executor/execute_primitive", self._execute,
            goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group)

    # --------------------------------------------------------------------------- parameters
    def _declare_parameters(self) -> None:
        declare = self.declare_parameter
        declare("push_length", 0.05, _float_range(
            0.005, MAX_PUSH_LENGTH, "push length used when a goal asks for 0, metres"))
        declare("safe_height", 0.10, _float_range(
            0.05, 0.20, "lowest ball-centre height above the table when crossing it, metres "
                        "(raised automatically above the tallest object)"))
        declare("path_clearance", 0.003, _float_range(
            0.0, 0.05, "clearance of the ball's low path from other objects, metres"))
        declare("table_height", 0.0, _float_range(-1.0, 2.0, "world z of the table top, m"))
        declare("push_speed", 0.05, _float_range(0.005, 0.1, "ball speed while pushing, m/s"))
        declare("transit_speed", 0.3, _float_range(
            0.02, 0.5, "ball speed for lift, transit, descend and retreat, m/s"))
        declare("tool_acceleration", 1.0, _float_range(0.1, 3.0, "ball acceleration, m/s^2"))
        declare("velocity_scale", 0.5, _float_range(
            0.05, 1.0, "fraction of the URDF joint velocity limits used"))
        declare("acceleration_scale", 0.5, _float_range(
            0.05, 1.0, "fraction of the Panda joint acceleration limits used"))
        declare("sample_period", 0.04, _float_range(
            0.005, 0.2, "time between trajectory points, s"))
        declare("max_tool_error", 0.01, _float_range(
            0.0005, 0.1, "largest ball tracking error (m) before a push counts as failed"))
        declare("settle_timeout", 10.0, _float_range(
            0.5, 120.0, "how long to wait for a settled observation, s"))
        declare("server_timeout", 5.0, _float_range(
            0.1, 60.0, "how long to wait for the controller and perception servers, s"))

    def _value(self, name: str) -> float:
        return float(self.get_parameter(name).value)

    def _settings(self) -> ExecutorSettings:
        value = self._value
        timing = TimingSettings(
            push_speed=value("push_speed"), transit_speed=value("transit_speed"),
            tool_acceleration=value("tool_acceleration"),
            velocity_scale=value("velocity_scale"),
            acceleration_scale=value("acceleration_scale"), sample_period=value("sample_period"))
        return ExecutorSettings(
            default_push_length=value("push_length"), safe_height=value("safe_height"),
            path_clearance=value("path_clearance"), table_height=value("table_height"),
            timing=timing)

    # ---------------------------------------------------------------------------- topics
    def _on_joint_state(self, message: JointState) -> None:
        index = {name: i for i, name in enumerate(message.name)}
        if all(name in index for name in ARM_JOINT_NAMES):
            positions = np.array([message.position[index[name]] for name in ARM_JOINT_NAMES])
            with self.lock:
                self.joint_positions = positions

    def _on_objects(self, message: ObjectStateArray) -> None:
        with self.lock:
            self.latest_objects = message

    # ---------------------------------------------------------------------------- waiting
    def _wait(self, future, timeout: float, goal_handle=None) -> bool:
        """Block this worker thread until `future` is done; False on timeout or cancel."""
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        deadline = time.monotonic() + timeout
        while not done.wait(0.02):
            if goal_handle is not None and goal_handle.is_cancel_requested:
                return False
            if time.monotonic() > deadline:
                return False
        return True

    def _settled_objects(self) -> list[ObjectState]:
        if not self.settled_client.wait_for_service(timeout_sec=self._value("server_timeout")):
            raise GoalFailed(Result.OBJECT_LOST, "perception's /perception/get_settled_objects "
                                                 "service is not available")
        timeout = self._value("settle_timeout")
        future = self.settled_client.call_async(GetSettledObjects.Request(timeout_s=timeout))
        if not self._wait(future, timeout + self._value("server_timeout")):
            raise GoalFailed(Result.OBJECT_LOST, "no settled observation from perception")
        response = future.result()
        if not response.success:
            raise GoalFailed(Result.OBJECT_LOST, f"perception: {response.message}")
        return list(response.objects.objects)

    # ---------------------------------------------------------------------------- the action
    def _on_goal(self, goal: ExecutePrimitive.Goal) -> GoalResponse:
        with self.lock:
            if self.busy:
                self.get_logger().warning(
                    f"rejected primitive {goal.primitive} on {goal.object_id!r}: busy")
                return GoalResponse.REJECT
            self.busy = True
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle) -> ExecutePrimitive.Result:
        result = Result()
        try:
            self._run(goal_handle, result)
            result.error_code = Result.SUCCESS
            goal_handle.succeed()
        except GoalFailed as failure:
            result.error_code, result.error_msg = failure.code, str(failure)
            self.get_logger().warning(f"primitive {goal_handle.request.primitive} on "
                                      f"{goal_handle.request.object_id!r}: {failure}")
            if failure.code == Result.CANCELED:
                goal_handle.canceled()
            else:
                goal_handle.abort()
        finally:
            with self.lock:
                self.busy = False
        return result

    def _feedback(self, goal_handle, phase: int, progress: float) -> None:
        goal_handle.publish_feedback(ExecutePrimitive.Feedback(phase=phase, progress=progress))

    def _run(self, goal_handle, result: ExecutePrimitive.Result) -> None:
        goal = goal_handle.request
        self._feedback(goal_handle, ExecutePrimitive.Feedback.PHASE_PLANNING, 0.0)
        settled = self._settled_objects()
        with self.lock:
            latest = self.latest_objects
            q_current = self.joint_positions
        known = {s.id for s in settled} | (
            {o.id for o in latest.objects} if latest is not None else set())
        if goal.object_id not in known:
            raise GoalFailed(Result.UNKNOWN_OBJECT,
                             f"no object {goal.object_id!r} in /perception/objects; known: "
                             f"{sorted(known)}")
        if q_current is None:
            raise GoalFailed(Result.CONTROLLER_UNAVAILABLE, "no /joint_states received yet")
        settings = self._settings()
        before_states = self._usable(settled)
        target = before_states.get(goal.object_id)
        if target is None:
            raise GoalFailed(Result.OBJECT_LOST,
                             f"{goal.object_id!r} is lost or not in the settled observation")
        others = [table_object(s) for i, s in before_states.items() if i != goal.object_id]
        try:
            plan = plan_primitive(self.ik, table_object(target), others, int(goal.primitive),
                                  float(goal.push_length), q_current, settings)
        except PrimitiveError as error:
            raise GoalFailed(Result.INVALID_GOAL, str(error)) from None
        except UnreachableError as error:
            raise GoalFailed(Result.UNREACHABLE, str(error)) from None
        except (IKError, TrajectoryError) as error:
            raise GoalFailed(Result.IK_FAILED, str(error)) from None
        result.before = target
        result.ik_ms = plan.planning_ms
        controller_result = self._follow(goal_handle, plan.trajectory, plan.geometry.safe_z,
                                         settings)
        result.tool_rms_error = controller_result.tool_rms_error
        result.tool_max_error = controller_result.tool_max_error
        if controller_result.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
            raise GoalFailed(Result.TRACKING_FAILED, f"controller: error "
                             f"{controller_result.error_code} {controller_result.error_string}")
        if controller_result.tool_max_error > self._value("max_tool_error"):
            raise GoalFailed(Result.TRACKING_FAILED, f"tool error "
                             f"{controller_result.tool_max_error * 1000:.1f} mm exceeds "
                             f"max_tool_error {self._value('max_tool_error') * 1000:.1f} mm")
        self._feedback(goal_handle, ExecutePrimitive.Feedback.PHASE_SETTLING, 0.0)
        after = self._usable(self._settled_objects()).get(goal.object_id)
        if after is None:
            raise GoalFailed(Result.OBJECT_LOST,
                             f"{goal.object_id!r} was not observed after the push")
        result.after = after
        before_pose = Pose2D(target.x, target.y, target.theta)
        result.displacement = before_pose.displacement_in_object_frame(
            Pose2D(after.x, after.y, after.theta)).tolist()

    @staticmethod
    def _usable(states: list[ObjectState]) -> dict[str, ObjectState]:
        return {s.id: s for s in states if s.status != ObjectState.STATUS_LOST}

    def _follow(self, goal_handle, trajectory: TimedJointTrajectory, safe_z: float,
                settings: ExecutorSettings) -> FollowJointTrajectory.Result:
        """Run the trajectory on the controller, forwarding phases; handles a cancel."""
        if not self.controller.wait_for_server(timeout_sec=self._value("server_timeout")):
            raise GoalFailed(Result.CONTROLLER_UNAVAILABLE, "the trajectory controller "
                             "/arm_controller/follow_joint_trajectory is not available")
        started = self.get_clock().now()

        def forward_feedback(_message) -> None:
            elapsed = (self.get_clock().now() - started).nanoseconds * 1e-9
            phase, progress = trajectory.phase_at(elapsed)
            self._feedback(goal_handle, PHASE_CODES[phase], progress)

        send = self.controller.send_goal_async(
            FollowJointTrajectory.Goal(trajectory=trajectory_message(trajectory)),
            feedback_callback=forward_feedback)
        server_timeout = self._value("server_timeout")
        if not self._wait(send, server_timeout) or not send.result().accepted:
            raise GoalFailed(Result.CONTROLLER_UNAVAILABLE,
                             "the trajectory controller did not accept the trajectory")
        controller_goal = send.result()
        outcome = controller_goal.get_result_async()
        # Simulated time may run slower or faster than wall time; allow generously.
        if self._wait(outcome, 10.0 * trajectory.duration + 30.0, goal_handle):
            return outcome.result().result
        if goal_handle.is_cancel_requested:
            self._stop_and_retreat(controller_goal, safe_z, settings)
            raise GoalFailed(Result.CANCELED, "canceled; the ball was lifted to the safe height")
        raise GoalFailed(Result.TRACKING_FAILED, "the controller did not finish in time")

    def _stop_and_retreat(self, controller_goal, safe_z: float,
                          settings: ExecutorSettings) -> None:
        cancel = controller_goal.cancel_goal_async()
        self._wait(cancel, self._value("server_timeout"))
        time.sleep(0.1)  # let /joint_states report the stopped arm
        with self.lock:
            q_now = self.joint_positions
        retreat = retreat_trajectory(self.ik, q_now, safe_z, settings)
        if retreat is None:
            return
        send = self.controller.send_goal_async(
            FollowJointTrajectory.Goal(trajectory=trajectory_message(retreat)))
        if self._wait(send, self._value("server_timeout")) and send.result().accepted:
            self._wait(send.result().get_result_async(), 10.0 * retreat.duration + 30.0)


def main(args: list[str] | None = None) -> None:
    rclpy.init(args=args)
    node = ExecutorNode()
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
