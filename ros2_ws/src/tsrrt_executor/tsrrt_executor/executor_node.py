"""executor_node: the ExecutePrimitive action on top of the ROS-free core (primitive_plan).

Action server /executor/execute_primitive (tsrrt_interfaces/action/ExecutePrimitive):
1. checks   <- an empty object id is UNKNOWN_OBJECT at once (clients send it as a handshake);
               /joint_states and /arm_controller/follow_joint_trajectory must be alive
               (else CONTROLLER_UNAVAILABLE); the object id must be in the latest
               /perception/objects (else UNKNOWN_OBJECT, listing the known ids; no waiting for a
               settled observation); the primitive must exist for its shape and the push length be
               valid (else INVALID_GOAL);
2. park     -> if the arm is not in OBSERVE_POSTURE (out of the camera's view), it goes there;
3. before   <- /perception/get_settled_objects (the object's settled state, arm out of view;
               asked again until the frame is newer than the arm's last move and shows the
               object);
4. plan     <- primitive_plan.plan_primitive: from the arm over the push back to OBSERVE_POSTURE;
5. execute  -> /arm_controller/follow_joint_trajectory, feedback by phase (approach, push,
               retreat) from the controller's desired state;
6. after    <- /perception/get_settled_objects with the arm back out of view; displacement in
               the object frame at 'before'.
Errors map to the result codes: PrimitiveError -> INVALID_GOAL, UnreachableError -> UNREACHABLE,
IKError -> IK_FAILED, a controller failure or a tool error above max_tool_error ->
TRACKING_FAILED, the object lost, or no settled observation, -> OBJECT_LOST. A cancel stops the
controller goal, lifts the ball vertically to the safe height and returns the arm to
OBSERVE_POSTURE before the result CANCELED.

Every wait has a wall-clock limit (server_timeout, settle_timeout, or joint states going quiet
while a trajectory runs), so a goal never hangs when a node is missing. Goals are validated in the
execute callback, not the goal callback, so that a bad goal gets a result with its error code and
message instead of a bare rejection; the goal callback only refuses a second goal while one runs
(there is one arm). The execute callback blocks on other actions and services, so it runs in a
ReentrantCallbackGroup on a MultiThreadedExecutor.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
from builtin_interfaces.msg import Duration
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import ARM_JOINT_NAMES
from tsrrt_common.ros_node import (
    SETTLE_REQUEST_S,
    ActionClient,
    answer_internal_error,
    run_node,
    seconds,
    shutting_down,
    time_message,
)
from tsrrt_executor.errors import IKError, PrimitiveError, TrajectoryError, UnreachableError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.primitive_plan import (
    ExecutorSettings,
    TableObject,
    lift_trajectory,
    plan_primitive,
    return_to_observe,
)
from tsrrt_executor.push_primitives import (
    MAX_PUSH_LENGTH,
    PHASE_APPROACH,
    PHASE_PUSH,
    PHASE_RETREAT,
    check_primitive,
    check_push_length,
    safe_transit_height,
)
from tsrrt_executor.trajectory import PhaseProgress, TimedJointTrajectory, TimingSettings
from tsrrt_interfaces.action import ExecutePrimitive, FollowJointTrajectory
from tsrrt_interfaces.msg import ObjectState, ObjectStateArray
from tsrrt_interfaces.srv import GetSettledObjects

Result = ExecutePrimitive.Result
Feedback = ExecutePrimitive.Feedback
PHASE_CODES = {PHASE_APPROACH: Feedback.PHASE_APPROACH, PHASE_PUSH: Feedback.PHASE_PUSH,
               PHASE_RETREAT: Feedback.PHASE_RETREAT}
CONTROLLER = "/arm_controller/follow_joint_trajectory"
UNKNOWN_ID_RECHECKS = 2     # further /perception/objects messages looked at for a missing id


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
        whole = math.floor(t)
        message.points.append(JointTrajectoryPoint(
            positions=q.tolist(), velocities=qd.tolist(), accelerations=qdd.tolist(),
            time_from_start=Duration(sec=int(whole), nanosec=int(round((t - whole) * 1e9)))))
    return message


def _float_range(low: float, high: float, description: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, floating_point_range=[
        FloatingPointRange(from_value=low, to_value=high)])


def _raise_if_shutting_down() -> None:
    if shutting_down():
        raise GoalFailed(Result.CANCELED, "the node is shutting down")


class ExecutorNode(Node):
    """Executes push primitives on perceived objects with the simulated (or a real) arm."""

    def __init__(self) -> None:
        super().__init__("executor_node")
        self._declare_parameters()
        self.ik = PusherIK()
        self.lock = threading.Lock()
        self.joint_positions: np.ndarray | None = None
        self.joint_state_arrival = -math.inf     # monotonic time of the latest /joint_states
        self.joint_state_stamp = 0.0             # its header stamp (the robot's clock), s
        self.joint_state_event = threading.Event()
        self.latest_objects: ObjectStateArray | None = None
        self.objects_count = 0                   # /perception/objects messages received
        self.objects_event = threading.Event()
        self.busy = False
        # Robot time since which this node has kept the arm still at the observe posture (None
        # while it moves): a settled frame stamped after it shows the scene as it is now.
        self.still_since: float | None = None
        self.stage_times: dict[str, float] = {}   # wall seconds per stage of the current goal
        self.stage_start = 0.0
        group = ReentrantCallbackGroup()
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        # Only the newest joint state matters; at full simulation speed they come at hundreds
        # per wall second, so older ones are dropped instead of queued, and their own
        # mutually exclusive group keeps them to one executor thread: the others stay free for
        # perception's messages and the actions.
        self.create_subscription(JointState, "/joint_states", self._on_joint_state,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE),
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.create_subscription(ObjectStateArray, "/perception/objects", self._on_objects,
                                 reliable, callback_group=MutuallyExclusiveCallbackGroup())
        self.settled_client = self.create_client(
            GetSettledObjects, "/perception/get_settled_objects", callback_group=group)
        self.controller = ActionClient(self, FollowJointTrajectory, CONTROLLER,
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
            0.02, 0.5, "ball speed of tool-down moves out of contact (lift, descend, retreat), "
                       "m/s"))
        declare("tool_acceleration", 1.0, _float_range(0.1, 3.0, "ball acceleration, m/s^2"))
        declare("velocity_scale", 0.9, _float_range(
            0.05, 1.0, "fraction of the URDF joint velocity limits used"))
        declare("acceleration_scale", 0.9, _float_range(
            0.05, 1.0, "fraction of the Panda joint acceleration limits used"))
        declare("sample_period", 0.04, _float_range(
            0.005, 0.2, "time between trajectory points, s"))
        declare("max_tool_error", 0.01, _float_range(
            0.0005, 0.1, "largest ball tracking error (m) before a push counts as failed"))
        declare("settle_timeout", 10.0, _float_range(
            0.5, 120.0, "how long to wait for a settled observation, wall-clock s"))
        declare("server_timeout", 5.0, _float_range(
            0.1, 60.0, "how long to wait for the controller, joint states and perception, "
                       "wall-clock s"))

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
            stamp = seconds(message.header.stamp)
            with self.lock:
                self.joint_positions = positions
                self.joint_state_arrival = time.monotonic()
                self.joint_state_stamp = stamp
            self.joint_state_event.set()

    def _on_objects(self, message: ObjectStateArray) -> None:
        with self.lock:
            self.latest_objects = message
            self.objects_count += 1
        self.objects_event.set()

    # ---------------------------------------------------------------------------- waiting
    def _wait(self, future, timeout: float, goal_handle=None) -> bool:
        """Block this worker thread until `future` is done; False on timeout.

        With a goal handle, a cancel request ends the wait by raising GoalFailed(CANCELED); a
        shutdown ends any wait so (nothing would answer it).
        """
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        deadline = time.monotonic() + timeout
        while not done.wait(0.01):
            _raise_if_shutting_down()
            if goal_handle is not None and goal_handle.is_cancel_requested:
                raise GoalFailed(Result.CANCELED, "canceled; the arm is in the observe posture")
            if time.monotonic() > deadline:
                return False
        return True

    def _fresh_joint_positions(self, newer_than: float | None = None,
                               stamped_after: float | None = None) -> np.ndarray:
        """Joint positions from a /joint_states message that arrived less than server_timeout
        ago (and after `newer_than`, monotonic, and stamped at or after `stamped_after`, robot
        time, if given), waiting up to server_timeout.

        A trajectory planned from positions read before the last motion ended starts away
        from the arm; the controller aborts it at t = 0 (seen: 0.2 rad, when the next goal came
        40 ms after the last result, and when a test moved the arm just before its goal).
        """
        timeout = self._value("server_timeout")
        deadline = time.monotonic() + timeout
        while True:
            with self.lock:
                arrival, positions = self.joint_state_arrival, self.joint_positions
                stamp = self.joint_state_stamp
                self.joint_state_event.clear()
            now = time.monotonic()
            if positions is not None and now - arrival < timeout and (
                    newer_than is None or arrival > newer_than) and (
                    stamped_after is None or stamp >= stamped_after):
                return positions
            _raise_if_shutting_down()
            if now > deadline:
                raise GoalFailed(Result.CONTROLLER_UNAVAILABLE,
                                 f"no /joint_states from the arm for {timeout:g} s; is the "
                                 "robot (tsrrt_sim sim_node) running?")
            self.joint_state_event.wait(min(0.05, deadline - now + 0.01))

    def _perceived_object(self, object_id: str) -> tuple[ObjectState, list[ObjectState]]:
        """The object's state in the latest /perception/objects, and all states in it.

        Waits up to server_timeout for a first message. An id missing from the latest message is
        looked for in the next two (a client that has just seen it there may be a message ahead
        of this node) before it counts as unknown; no settled observation is waited for.
        """
        timeout = self._value("server_timeout")
        with self.lock:
            received = self.latest_objects is not None
        if not received and not self.objects_event.wait(timeout):
            raise GoalFailed(Result.OBJECT_LOST, f"no /perception/objects within {timeout:g} s; "
                                                 "is perception_node running?")
        deadline = time.monotonic() + timeout
        with self.lock:
            wanted = self.objects_count + UNKNOWN_ID_RECHECKS
        while True:
            with self.lock:
                states = list(self.latest_objects.objects)
                count = self.objects_count
                self.objects_event.clear()
            state = next((s for s in states if s.id == object_id), None)
            if state is not None:
                return state, states
            if count >= wanted or time.monotonic() > deadline:
                raise GoalFailed(Result.UNKNOWN_OBJECT,
                                 f"no object {object_id!r} in /perception/objects; known: "
                                 f"{sorted(s.id for s in states)}")
            self.objects_event.wait(0.05)

    def _robot_time(self) -> float:
        """The robot's clock (stamp of a /joint_states message that arrived after this call)."""
        self._fresh_joint_positions(newer_than=time.monotonic())
        with self.lock:
            return self.joint_state_stamp

    def _settled_observation(self, goal_handle, object_id: str, not_before: float
                             ) -> tuple[ObjectState, dict[str, ObjectState]]:
        """The object's state in a settled observation seen at or after `not_before` (robot
        clock), with every usable state of that observation.

        Perception answers with the first settled frame after the request by its own clock,
        which lags the simulator's under load, so the answer may show the scene before the arm
        left; and an object the arm covered may be LOST until perception sees it again. Either
        way the request is repeated, until settle_timeout (wall clock) runs out.
        """
        timeout = self._value("server_timeout")
        if not self.settled_client.wait_for_service(timeout_sec=timeout):
            raise GoalFailed(Result.OBJECT_LOST,
                             "perception's service /perception/get_settled_objects is not "
                             f"available (waited {timeout:g} s)")
        deadline = time.monotonic() + self._value("settle_timeout")
        problem = "no settled observation"
        while (remaining := deadline - time.monotonic()) > 0.0:
            # Never ask for less than a few frames' worth: a sliver of time cannot succeed.
            wait_s = min(max(remaining, 0.5), SETTLE_REQUEST_S)
            future = self.settled_client.call_async(GetSettledObjects.Request(
                timeout_s=wait_s, not_before=time_message(not_before)))
            if not self._wait(future, wait_s + SETTLE_REQUEST_S, goal_handle):
                self.settled_client.remove_pending_request(future)
                problem = "perception did not answer the request for a settled observation"
                continue
            response = future.result()
            if not response.success:
                problem = f"perception: {response.message}"
                continue
            states = self._usable(list(response.objects.objects))
            state = states.get(object_id)
            if state is None:
                problem = (f"{object_id!r} is lost or missing in the settled observation (hidden,"
                           " or off the table)")
            else:
                seen = seconds(state.last_seen)
                if seen >= not_before:
                    return state, states
                problem = (f"the settled observation (t = {seen:.2f} s) is older than the "
                           f"arm's motion (t = {not_before:.2f} s)")
            self.get_logger().info(f"{problem}; asking perception again")
        raise GoalFailed(Result.OBJECT_LOST, f"{problem} (waited "
                                             f"{self._value('settle_timeout'):g} s)")

    @staticmethod
    def _usable(states: list[ObjectState]) -> dict[str, ObjectState]:
        return {s.id: s for s in states if s.status != ObjectState.STATUS_LOST}

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
        goal = goal_handle.request
        self.stage_times, self.stage_start = {}, time.monotonic()
        try:
            self._run(goal_handle, result)
            result.error_code = Result.SUCCESS
            if not shutting_down():
                goal_handle.succeed()
            stages = ", ".join(f"{name} {took:.2f}" for name, took in
                               self.stage_times.items())
            self.get_logger().info(
                f"primitive {goal.primitive} on {goal.object_id!r}: displacement "
                f"{np.round(result.displacement, 4).tolist()} (wall s: {stages})")
        except GoalFailed as failure:
            result.error_code, result.error_msg = failure.code, str(failure)
            # A goal naming no object is a client's handshake, answered as expected.
            log = self.get_logger().warning if goal.object_id else self.get_logger().debug
            log(f"primitive {goal.primitive} on {goal.object_id!r}: {failure}")
            if not shutting_down():   # else the node and the goal's handle are gone
                if failure.code == Result.CANCELED:
                    goal_handle.canceled()
                else:
                    goal_handle.abort()
        except Exception as error:   # noqa: BLE001 - a bug: answered, never left unanswered
            if shutting_down():
                result.error_code, result.error_msg = Result.CANCELED, "the node shut down"
            else:   # read as SUCCESS, a zero displacement would be learned
                answer_internal_error(self, goal_handle, result, error)
        finally:
            with self.lock:
                self.busy = False
        return result

    def _mark(self, stage: str) -> None:
        """Record the wall time since the previous stage ended (for the log)."""
        now = time.monotonic()
        self.stage_times[stage] = now - self.stage_start
        self.stage_start = now

    def _feedback(self, goal_handle, phase: int, progress: float) -> None:
        goal_handle.publish_feedback(Feedback(phase=phase, progress=progress))

    def _run(self, goal_handle, result: ExecutePrimitive.Result) -> None:
        goal = goal_handle.request
        if not goal.object_id:   # also a client's handshake: answered without waiting on anything
            raise GoalFailed(Result.UNKNOWN_OBJECT, "the goal names no object (empty object_id)")
        self._feedback(goal_handle, Feedback.PHASE_PLANNING, 0.0)
        # Read after the goal came: the arm may have moved since this node last moved it.
        q_current = self._fresh_joint_positions(newer_than=time.monotonic())
        self._require_controller()
        state, latest = self._perceived_object(goal.object_id)
        settings = self._settings()
        try:
            check_primitive(state.shape, int(goal.primitive))
            check_push_length(goal.push_length or settings.default_push_length)
        except PrimitiveError as error:
            raise GoalFailed(Result.INVALID_GOAL, str(error)) from None
        self._mark("checks")
        # Park the arm out of the camera's view so that the observation sees every object.
        safe_z = settings.table_height + safe_transit_height(
            [s.height for s in latest], minimum=settings.safe_height)
        self._return_to_observe(goal_handle, q_current, safe_z, settings)
        self._mark("park")
        target, before_states = self._settled_observation(
            goal_handle, goal.object_id,
            self.still_since if self.still_since is not None else self._robot_time())
        self._mark("before")
        others = [table_object(s) for i, s in before_states.items() if i != goal.object_id]
        try:
            plan = plan_primitive(self.ik, table_object(target), others, int(goal.primitive),
                                  float(goal.push_length),
                                  self._fresh_joint_positions(stamped_after=seconds(
                                      target.last_seen)),
                                  settings)
        except PrimitiveError as error:
            raise GoalFailed(Result.INVALID_GOAL, str(error)) from None
        except UnreachableError as error:
            raise GoalFailed(Result.UNREACHABLE, str(error)) from None
        except (IKError, TrajectoryError) as error:
            raise GoalFailed(Result.IK_FAILED, str(error)) from None
        result.before = target
        result.ik_ms = plan.planning_ms
        self._mark("plan")
        controller_result = self._follow(goal_handle, plan.trajectory, plan.geometry.safe_z,
                                         settings)
        self._mark(f"motion ({plan.trajectory.duration:.1f} s simulated)")
        result.tool_rms_error = controller_result.tool_rms_error
        result.tool_max_error = controller_result.tool_max_error
        if controller_result.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
            problem = (f"controller: error {controller_result.error_code} "
                       f"{controller_result.error_string}")
            # The arm stopped where the controller gave up, maybe in contact and in the
            # camera's view: take it back out so the caller can observe and carry on.
            try:
                self._return_to_observe(goal_handle,
                                        self._fresh_joint_positions(newer_than=time.monotonic()),
                                        plan.geometry.safe_z, settings)
            except GoalFailed as failure:
                problem += f"; then moving the arm out of view failed: {failure}"
            raise GoalFailed(Result.TRACKING_FAILED, problem)
        if controller_result.tool_max_error > self._value("max_tool_error"):
            raise GoalFailed(Result.TRACKING_FAILED, f"tool error "
                             f"{controller_result.tool_max_error * 1000:.1f} mm exceeds "
                             f"max_tool_error {self._value('max_tool_error') * 1000:.1f} mm")
        self._feedback(goal_handle, Feedback.PHASE_SETTLING, 0.0)
        # The controller's end stamp, not a later clock reading: the sim renders a frame the
        # moment a trajectory ends, stamped after the end but before the result gets here.
        motion_end = seconds(controller_result.end_stamp) or self._robot_time()
        after, _ = self._settled_observation(goal_handle, goal.object_id, motion_end)
        self.still_since = motion_end
        result.after = after
        self._mark("after")
        self._feedback(goal_handle, Feedback.PHASE_SETTLING, 1.0)
        before_pose = Pose2D(target.x, target.y, target.theta)
        result.displacement = before_pose.displacement_in_object_frame(
            Pose2D(after.x, after.y, after.theta)).tolist()

    # ---------------------------------------------------------------------------- the arm
    def _require_controller(self) -> None:
        timeout = self._value("server_timeout")
        if not self.controller.wait_for_server(timeout_sec=timeout):
            raise GoalFailed(Result.CONTROLLER_UNAVAILABLE, f"the trajectory controller "
                             f"{CONTROLLER} is not available (waited {timeout:g} s)")

    def _return_to_observe(self, goal_handle, q_current: np.ndarray, safe_z: float,
                           settings: ExecutorSettings) -> None:
        """Move the arm to the observe posture if it is elsewhere (no phase feedback)."""
        try:
            trajectory = return_to_observe(self.ik, q_current, safe_z, settings)
        except (UnreachableError, IKError, TrajectoryError) as error:
            raise GoalFailed(Result.UNREACHABLE, "cannot move the arm out of the camera's view "
                                                 f"for the observation: {error}") from None
        if trajectory is None:
            return
        outcome = self._follow(goal_handle, trajectory, safe_z, settings, phase_feedback=False)
        if outcome.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
            raise GoalFailed(Result.TRACKING_FAILED, "moving the arm to the observe posture: "
                             f"controller error {outcome.error_code} {outcome.error_string}")

    def _follow(self, goal_handle, trajectory: TimedJointTrajectory, safe_z: float,
                settings: ExecutorSettings, phase_feedback: bool = True
                ) -> FollowJointTrajectory.Result:
        """Run the trajectory on the controller, forwarding phases; handles a cancel.

        Never waits for long on a controller that went away: the goal must be accepted within
        server_timeout and /joint_states must keep coming while it runs.
        """
        self._require_controller()
        self.still_since = None
        progress = PhaseProgress(trajectory)
        # Feedback callbacks may run on several executor threads at once: one at a time, so
        # that phases are published in order.
        progress_lock = threading.Lock()

        def forward_feedback(message) -> None:
            with progress_lock:
                for phase, fraction in progress.update(
                        np.array(message.feedback.desired.positions)):
                    self._feedback(goal_handle, PHASE_CODES[phase], fraction)

        send = self.controller.send_goal_async(
            FollowJointTrajectory.Goal(trajectory=trajectory_message(trajectory)),
            feedback_callback=forward_feedback if phase_feedback else None)
        server_timeout = self._value("server_timeout")
        if not self._wait(send, server_timeout) or not send.result().accepted:
            raise GoalFailed(Result.CONTROLLER_UNAVAILABLE,
                             f"the trajectory controller {CONTROLLER} did not accept the "
                             f"trajectory within {server_timeout:g} s")
        controller_goal = send.result()
        outcome = controller_goal.get_result_async()
        try:
            while not self._wait(outcome, server_timeout, goal_handle):
                self._fresh_joint_positions()   # raises if the arm went quiet
        except GoalFailed as failure:
            if failure.code == Result.CANCELED:
                self._stop_and_retreat(controller_goal, safe_z, settings)
                raise GoalFailed(Result.CANCELED, "canceled; the ball was lifted to the safe "
                                 "height and the arm returned to the observe posture") from None
            raise
        if phase_feedback and outcome.result().result.error_code == 0:
            with progress_lock:
                for phase, fraction in progress.finish():
                    self._feedback(goal_handle, PHASE_CODES[phase], fraction)
        return outcome.result().result

    def _stop_and_retreat(self, controller_goal, safe_z: float,
                          settings: ExecutorSettings) -> None:
        """After a cancel: stop, lift the ball vertically, go back to the observe posture
        (only the lift if the way back is not clear)."""
        server_timeout = self._value("server_timeout")
        self._wait(controller_goal.cancel_goal_async(), server_timeout)
        self._wait(controller_goal.get_result_async(), server_timeout)
        q_now = self._fresh_joint_positions(newer_than=time.monotonic())
        try:
            retreat = return_to_observe(self.ik, q_now, safe_z, settings)
        except (UnreachableError, IKError, TrajectoryError) as error:
            self.get_logger().warning(f"after the cancel: {error}; only lifting the ball")
            retreat = lift_trajectory(self.ik, q_now, safe_z, settings)
        if retreat is None:
            return
        send = self.controller.send_goal_async(
            FollowJointTrajectory.Goal(trajectory=trajectory_message(retreat)))
        if self._wait(send, server_timeout) and send.result().accepted:
            outcome = send.result().get_result_async()
            while not self._wait(outcome, server_timeout):
                self._fresh_joint_positions()


def main(args: list[str] | None = None) -> None:
    run_node(ExecutorNode, "executor_node", threads=4, args=args)


if __name__ == "__main__":
    main()
