"""ROS 2 face of the simulator: clock, joint states, camera, ground truth, arm control, services.

Threads: a physics thread owns the SimWorld (every PyBullet call happens on it). It steps the
world in ticks of a few physics steps, publishes /clock after each tick and the other topics
when due, and runs requests from ROS callbacks (goals, services) between ticks. ROS callbacks
run on a MultiThreadedExecutor and hand work to the physics thread through a queue. A trajectory
goal starts as it is accepted, so of two goals the one accepted later preempts.

Time: this node drives /clock and therefore never runs on simulation time itself; physics is paced
by the wall clock (real_time_factor > 0) or runs as fast as it can (0). Message stamps are
simulation time. Rates:
- clock_rate_hz and joint_state_rate_hz are in simulation time, like a robot's own loops, and
  capped at max_publish_wall_hz per wall second: at a real-time factor of 40, 40 Hz of simulated
  time would be 1600 messages per wall second, and every node on simulation time wakes for each
  /clock (an idle rclpy node spent 40 % of a core on it). The default cap is 20: against 50, the
  idle executor and planner nodes took 20 % and 10 % of a core instead of 40 % and 30 %, and
  pushes through the graph were faster (executor bench, 2 x 30 pushes each: median 0.58 and
  0.53 s against 0.66 and 0.59 s);
- camera_rate_hz is in wall-clock time: TinyRenderer is slow, and consumers process frames at a
  wall-clock pace; at a real-time factor of 20, 10 frames per wall second are one frame every
  2 s of simulated time. Frames are rendered in a worker process while physics continues, and
  each frame (with its ground truth on /sim/object_states) is stamped with the simulation time
  of the state it shows; a scene that looks as it did in the last frame rendered is not drawn
  again, that frame goes out with the new stamp. When a trajectory ends, frames_after_motion
  frames are rendered back to back (each as soon as the worker is free): whoever moved the arm
  out of view waits for the scene it left, and to see it still takes two frames; the next 10 Hz
  tick would be 1 s of idle simulated time and 0.1 s of wall time later.

Faults: camera_drop_fraction leaves that fraction of rendered frames unpublished (colour, depth
and camera info; chosen at random with a fixed seed, so a run is repeatable), as a lossy link
would, for testing that perception and the planner cope. Unlike the other parameters it can be
changed while the node runs, to inject the fault mid-task. Ground truth is published for every
frame: it is the simulator's own record, not a camera.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import random
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from typing import Any, TypeVar

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from trajectory_msgs.msg import JointTrajectoryPoint

from tsrrt_common.errors import TsrrtError
from tsrrt_common.geometry import Pose2D, wrap_angle
from tsrrt_common.robot_model import ARM_JOINT_NAMES
from tsrrt_common.ros_node import run_node, seconds, time_message
from tsrrt_common.scenario import load_scenario
from tsrrt_interfaces.action import FollowJointTrajectory
from tsrrt_interfaces.msg import ObjectState, ObjectStateArray
from tsrrt_interfaces.srv import DisturbObject, LoadScenario
from tsrrt_sim.image_messages import numpy_to_image
from tsrrt_sim.render_worker import RenderWorker
from tsrrt_sim.trajectory_controller import (
    ControllerGains,
    ExecutionStatus,
    JointToleranceOverride,
    JointTrajectory,
    SetPoint,
    Tolerances,
    TrajectoryError,
    TrajectoryErrorCode,
    TrajectoryExecution,
    resolve_tolerances,
    validate_trajectory,
)
from tsrrt_sim.world import CameraFrame, SimWorld, VisualState, yaw_of_quaternion

WORLD_FRAME = "world"
CAMERA_FRAME = "camera_optical"
REQUEST_TIMEOUT_S = 30.0
# If pacing falls this far behind the wall clock, restart it instead of running in a burst.
MAX_PACING_LAG_S = 0.5
GOAL_POLL_PERIOD_S = 0.005   # wall s between checks whether a trajectory goal has finished
ACCEPTED_START_WAIT_S = 1.0  # wall s a goal waits for those accepted before it to start

T = TypeVar("T")

for _code in TrajectoryErrorCode:   # the core's codes are the action's codes
    assert getattr(FollowJointTrajectory.Result, _code.name) == _code.value, _code


def _point(positions: np.ndarray, velocities: np.ndarray, accelerations: np.ndarray | None = None
           ) -> JointTrajectoryPoint:
    point = JointTrajectoryPoint()
    point.positions = positions.tolist()
    point.velocities = velocities.tolist()
    if accelerations is not None:
        point.accelerations = accelerations.tolist()
    return point


class SimulationStopped(TsrrtError):
    """Physics has stopped (the node is shutting down): a request cannot run any more."""


class SimNode(Node):
    """The simulated robot, camera and table behind ROS 2 topics, an action and services."""

    def __init__(self) -> None:
        super().__init__("sim_node")
        self._declare_parameters()
        p = self._parameter
        self.physics_hz = p("physics_hz")
        self.real_time_factor = p("real_time_factor")
        self.idle_real_time_factor = p("idle_real_time_factor")
        self.tick_steps = max(1, round(self.physics_hz / p("clock_rate_hz")))
        self.joint_state_period = 1.0 / p("joint_state_rate_hz")
        self.publish_wall_period = 1.0 / p("max_publish_wall_hz")
        self.camera_period = 1.0 / p("camera_rate_hz")
        self.frames_after_motion: int = p("frames_after_motion")
        self.feedback_period = 1.0 / p("feedback_rate_hz")
        self._drop_random = random.Random(0)
        tolerances = Tolerances.uniform(
            path_position=p("path_tolerance"), path_velocity=0.0,
            goal_position=p("goal_tolerance"), goal_velocity=p("stopped_velocity_tolerance"),
            goal_time=p("goal_time_tolerance"))
        scenario = load_scenario(p("scenario"), p("seed") if p("seed") >= 0 else None)
        self.world = SimWorld(scenario, gui=p("gui"), physics_hz=self.physics_hz,
                              gains=ControllerGains(p("kp"), p("kd")), tolerances=tolerances)
        self.world.settle(0.5)
        self.renderer = RenderWorker(scenario, self.world.camera)
        self._continuous_theta: dict[str, float] = {}
        self._pending_visual_state: VisualState | None = None
        self._last_render: tuple[VisualState, CameraFrame] | None = None  # state, its frame

        self.clock_publisher = self.create_publisher(Clock, "/clock", 10)
        self.joint_state_publisher = self.create_publisher(JointState, "/joint_states", 10)
        # Reliable, unlike most camera drivers: best effort lost most 1-2 MB frames on one
        # machine (6-13 colour-depth pairs of 100). A reliable publisher serves best-effort
        # subscribers too.
        images = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)
        self.image_publisher = self.create_publisher(Image, "/camera/image_raw", images)
        self.depth_publisher = self.create_publisher(Image, "/camera/depth/image_raw", images)
        # Reliable + transient local: a late subscriber of either kind still gets the intrinsics.
        self.camera_info_publisher = self.create_publisher(
            CameraInfo, "/camera/camera_info",
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.ground_truth_publisher = self.create_publisher(
            ObjectStateArray, "/sim/object_states", 10)
        self.camera_info = self._make_camera_info()

        group = ReentrantCallbackGroup()
        self.action_server = ActionServer(
            self, FollowJointTrajectory, "/arm_controller/follow_joint_trajectory",
            execute_callback=self._execute_goal, goal_callback=self._on_goal,
            handle_accepted_callback=self._on_accepted, cancel_callback=self._on_cancel,
            callback_group=group)
        self.create_service(LoadScenario, "/sim/load_scenario", self._on_load_scenario,
                            callback_group=group)
        self.create_service(DisturbObject, "/sim/disturb_object", self._on_disturb_object,
                            callback_group=group)

        # Goals start in the order _on_goal accepted them (tickets, keyed by the request
        # object until the goal has an id); what each started waits in _started for its
        # execute callback.
        self._start_turn = threading.Condition()
        self._tickets: dict[int, int] = {}
        self._tickets_issued = 0
        self._next_ticket = 0
        self._started: dict[bytes, TrajectoryExecution | TrajectoryError | SimulationStopped] = {}

        self._requests: queue.Queue[tuple[Callable[[], Any], Future]] = queue.Queue()
        # Cleared, under the lock, when physics stops: a request queued after its last drain
        # would wait out REQUEST_TIMEOUT_S.
        self._taking_requests = True
        self._requests_lock = threading.Lock()
        self._stop = threading.Event()
        self._frames_due = 0     # frames to render back to back (set when a trajectory ends)
        self._physics_thread = threading.Thread(target=self._physics_loop, name="physics",
                                                daemon=True)
        self._physics_thread.start()
        self.get_logger().info(
            f"simulating '{scenario.name}' at {self.physics_hz:g} Hz, real-time factor "
            f"{self.real_time_factor or 'unlimited'}, camera {1 / self.camera_period:g} Hz "
            f"(wall clock), {p('camera_drop_fraction'):.0%} of frames dropped")

    # ---------------------------------------------------------------------------- parameters
    def _declare_parameters(self) -> None:
        def number(name: str, default: float, low: float, high: float, text: str) -> None:
            self.declare_parameter(name, default, ParameterDescriptor(
                description=text, read_only=True,
                floating_point_range=[FloatingPointRange(from_value=low, to_value=high)]))

        self.declare_parameter("scenario", "clean", ParameterDescriptor(
            description="shipped scenario name or path of a scenario YAML file",
            read_only=True))
        self.declare_parameter("seed", -1, ParameterDescriptor(
            description="placement seed for random poses; -1 keeps the file's seed",
            read_only=True, integer_range=[IntegerRange(from_value=-1, to_value=2**31 - 1)]))
        self.declare_parameter("gui", False, ParameterDescriptor(
            description="open the PyBullet window (needs a display)", read_only=True))
        number("real_time_factor", 0.0, 0.0, 1000.0,
               "simulated seconds per wall second; 0 runs as fast as possible")
        number("idle_real_time_factor", 10.0, 0.0, 1000.0,
               "with real_time_factor 0: the pace while no trajectory runs (0: as fast as "
               "possible then too); the CPU goes to rendering and the other nodes")
        number("physics_hz", 240.0, 60.0, 2000.0, "physics steps per simulated second")
        number("clock_rate_hz", 40.0, 1.0, 1000.0,
               "/clock messages per simulated second (rounded to whole physics steps)")
        number("joint_state_rate_hz", 40.0, 1.0, 1000.0,
               "/joint_states messages per simulated second (at most one per clock tick)")
        number("max_publish_wall_hz", 20.0, 1.0, 1000.0,
               "/clock and /joint_states messages per WALL-CLOCK second at most (the cap "
               "of a simulation faster than real time)")
        number("camera_rate_hz", 10.0, 0.1, 60.0,
               "camera frames per WALL-CLOCK second (rendering is the bottleneck)")
        self.declare_parameter("frames_after_motion", 2, ParameterDescriptor(
            description="camera frames rendered back to back when a trajectory ends, beside "
            "camera_rate_hz (seeing the scene still takes two)", read_only=True,
            integer_range=[IntegerRange(from_value=0, to_value=10, step=1)]))
        self.declare_parameter("camera_drop_fraction", 0.0, ParameterDescriptor(
            description="fraction of camera frames left unpublished, at random (fault "
            "injection; settable at runtime)",
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1.0)]))
        number("feedback_rate_hz", 10.0, 0.5, 100.0,
               "trajectory action feedback per wall-clock second")
        number("kp", 2500.0, 1.0, 1e5, "computed-torque position gain, 1/s^2")
        number("kd", 100.0, 0.0, 1e4, "computed-torque velocity gain, 1/s")
        number("path_tolerance", 0.1, 0.0, 10.0,
               "default joint position path tolerance, rad (0 disables)")
        number("goal_tolerance", 0.01, 0.0, 10.0,
               "default joint position goal tolerance, rad (0 disables)")
        number("stopped_velocity_tolerance", 0.01, 0.0, 10.0,
               "joint speed below which the arm counts as stopped at the goal, rad/s")
        number("goal_time_tolerance", 1.0, 0.0, 60.0,
               "default time allowed after the trajectory's end to meet the goal tolerance, s")

    def _parameter(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _make_camera_info(self) -> CameraInfo:
        camera = self.world.camera
        K = camera.intrinsics
        info = CameraInfo()
        info.header.frame_id = CAMERA_FRAME
        info.width, info.height = camera.width, camera.height
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = K.ravel().tolist()
        info.r = np.eye(3).ravel().tolist()
        info.p = np.hstack([K, np.zeros((3, 1))]).ravel().tolist()
        return info

    # ---------------------------------------------------------------------- physics thread
    def _call_in_physics(self, function: Callable[[], T]) -> T:
        """Run `function` on the physics thread between ticks and return its result.

        Raises:
            SimulationStopped: physics is not running, or stopped before it got to `function`
                (the node is shutting down).
        """
        future: Future = Future()
        with self._requests_lock:
            if not self._taking_requests:
                raise SimulationStopped("the simulation has stopped (the node is shutting down)")
            self._requests.put((function, future))
        return future.result(timeout=REQUEST_TIMEOUT_S)

    def _queued_requests(self) -> Iterator[tuple[Callable[[], Any], Future]]:
        while True:
            try:
                yield self._requests.get_nowait()
            except queue.Empty:
                return

    def _run_requests(self) -> None:
        for function, future in self._queued_requests():
            try:
                future.set_result(function())
            except Exception as error:  # noqa: BLE001 - handed to the waiting caller
                future.set_exception(error)

    def _fail_requests(self) -> None:
        """Answer requests queued after the last tick: nothing will run them any more."""
        for _, future in self._queued_requests():
            future.set_exception(SimulationStopped(
                "the simulation stopped before it got to the request (the node is shutting "
                "down)"))

    def _physics_loop(self) -> None:
        world = self.world
        wall_origin, sim_origin = time.monotonic(), world.sim_time
        pace = self._pace()
        next_joint_state = world.sim_time
        next_frame_wall = next_publish_wall = time.monotonic()
        try:
            while not self._stop.is_set() and self.context.ok():
                self._run_requests()
                world.step(self.tick_steps)
                now_sim = world.sim_time
                tick_wall = time.monotonic()
                if tick_wall >= next_publish_wall:
                    next_publish_wall = tick_wall + self.publish_wall_period
                    self.clock_publisher.publish(Clock(clock=time_message(now_sim)))
                    if now_sim >= next_joint_state:
                        self._publish_joint_state()
                        next_joint_state += self.joint_state_period * math.ceil(
                            (now_sim - next_joint_state + 1e-12) / self.joint_state_period)
                frame = self.renderer.poll()
                if frame is not None:
                    self._last_render = (self._pending_visual_state, frame)
                    self._publish_frame(frame, self._pending_visual_state)
                now_wall = time.monotonic()
                # A finished trajectory gets its frames at once (frames_after_motion).
                frame_now = self._frames_due > 0
                if (now_wall >= next_frame_wall or frame_now) and not self.renderer.busy:
                    next_frame_wall = max(next_frame_wall + self.camera_period, now_wall)
                    self._frames_due = max(self._frames_due - 1, 0)
                    self._start_frame()
                if self._pace() != pace:
                    pace, wall_origin, sim_origin = self._pace(), time.monotonic(), now_sim
                if pace > 0:
                    target = wall_origin + (now_sim - sim_origin) / pace
                    lag = time.monotonic() - target
                    if lag > MAX_PACING_LAG_S:
                        wall_origin, sim_origin = time.monotonic(), now_sim
                    elif lag < 0:
                        time.sleep(-lag)
        except Exception as error:  # noqa: BLE001 - reported, then the node shuts down
            if not self.context.ok():
                return      # a signal shut ROS down while this thread was publishing
            self.get_logger().fatal(f"physics loop failed: {error!r}")
            rclpy.try_shutdown(context=self.context)
            raise
        finally:
            with self._requests_lock:
                self._taking_requests = False
            self._fail_requests()

    def _pace(self) -> float:
        """Simulated seconds per wall second now (0: as fast as possible). At full speed an idle
        arm gets idle_real_time_factor: simulating 100 s of a still table per wall second
        took the core that renders the frame everyone is waiting for."""
        if self.real_time_factor > 0 or self.world.controller.active is not None:
            return self.real_time_factor
        return self.idle_real_time_factor

    def _publish_joint_state(self) -> None:
        state = self.world.joint_state()
        message = JointState()
        message.header.stamp = time_message(self.world.sim_time)
        message.name = list(ARM_JOINT_NAMES)
        message.position = state.positions.tolist()
        message.velocity = state.velocities.tolist()
        message.effort = state.efforts.tolist()
        self.joint_state_publisher.publish(message)

    def _start_frame(self) -> None:
        """Ask the worker for a frame if anyone watches the images, else publish ground truth.
        A scene that looks as it did in the last frame rendered is not rendered again: that
        frame goes out stamped now (an idle table at 10 Hz took a third of a core to draw)."""
        state = self.world.visual_state()
        wants_images = (self.image_publisher.get_subscription_count()
                        + self.depth_publisher.get_subscription_count()) > 0
        if not wants_images:
            self._publish_ground_truth(state)
        elif self._last_render is not None and self._last_render[0].looks_like(state):
            self._publish_frame(dataclasses.replace(self._last_render[1], sim_time=state.sim_time),
                                state)
        else:
            self._pending_visual_state = state
            self.renderer.request(state)

    def _publish_frame(self, frame: CameraFrame, state: VisualState) -> None:
        drop_fraction = self._parameter("camera_drop_fraction")
        if drop_fraction > 0.0 and self._drop_random.random() < drop_fraction:
            self._publish_ground_truth(state)
            return
        header_stamp = time_message(frame.sim_time)
        rgb = numpy_to_image(frame.rgb, "rgb8")
        depth = numpy_to_image(frame.depth, "32FC1")
        for message in (rgb, depth, self.camera_info):
            message.header.stamp = header_stamp
            message.header.frame_id = CAMERA_FRAME
        self.image_publisher.publish(rgb)
        self.depth_publisher.publish(depth)
        self.camera_info_publisher.publish(self.camera_info)
        self._publish_ground_truth(state)

    def _publish_ground_truth(self, state: VisualState) -> None:
        """True poses of the movable objects at the state's time, theta kept continuous."""
        message = ObjectStateArray()
        message.header.stamp = time_message(state.sim_time)
        message.header.frame_id = WORLD_FRAME
        for spec in self.world.scenario.objects:
            position, orientation = state.body_poses[spec.id]
            theta = yaw_of_quaternion(orientation)
            previous = self._continuous_theta.get(spec.id)
            if previous is not None:
                theta = previous + wrap_angle(theta - previous)
            self._continuous_theta[spec.id] = theta
            message.objects.append(ObjectState(
                id=spec.id, object_class=spec.object_class, shape=spec.shape,
                x=position[0], y=position[1], theta=theta, length=spec.length,
                width=spec.width, height=spec.height, symmetry=spec.symmetry, confidence=1.0,
                status=ObjectState.STATUS_TRACKED, last_seen=message.header.stamp))
        self.ground_truth_publisher.publish(message)

    # ------------------------------------------------------------------------------ action
    def _on_goal(self, goal_request: FollowJointTrajectory.Goal) -> GoalResponse:
        """Accept every goal; _on_accepted validates it so the result can say what is wrong."""
        points = goal_request.trajectory.points
        self.get_logger().info(f"trajectory goal received: {len(points)} points")
        with self._start_turn:
            self._tickets[id(goal_request)] = self._tickets_issued
            self._tickets_issued += 1
        return GoalResponse.ACCEPT

    def _on_accepted(self, goal_handle: ServerGoalHandle) -> None:
        """Start the trajectory in the order the goals were accepted, so of two goals the later
        preempts.

        Execute callbacks run on executor threads in any order: started there, a goal sent just
        after another could start first and be preempted by the earlier one. The client hears
        of the acceptance before this runs, so a goal it sends next may get here first; it waits
        its turn (at most ACCEPTED_START_WAIT_S, should a goal accepted earlier never get here).
        """
        started: TrajectoryExecution | TrajectoryError | SimulationStopped
        with self._start_turn:
            ticket = self._tickets.pop(id(goal_handle.request))
            self._start_turn.wait_for(lambda: self._next_ticket >= ticket,
                                      ACCEPTED_START_WAIT_S)
            try:
                trajectory, tolerances, start = self._prepare(goal_handle.request)
                started = self._call_in_physics(
                    lambda: self._start_execution(trajectory, tolerances, start))
            except (TrajectoryError, SimulationStopped) as error:
                started = error
            self._started[bytes(goal_handle.goal_id.uuid)] = started
            self._next_ticket = max(self._next_ticket, ticket + 1)
            self._start_turn.notify_all()
        goal_handle.execute()

    def _on_cancel(self, goal_handle: ServerGoalHandle) -> CancelResponse:
        return CancelResponse.ACCEPT

    def _prepare(self, goal: FollowJointTrajectory.Goal
                 ) -> tuple[JointTrajectory, Tolerances, float | None]:
        """The goal's trajectory, tolerances and start time (None: now); raises TrajectoryError."""
        trajectory_msg = goal.trajectory
        points = trajectory_msg.points
        trajectory = validate_trajectory(
            list(trajectory_msg.joint_names),
            [seconds(p.time_from_start) for p in points],
            [list(p.positions) for p in points], [list(p.velocities) for p in points],
            [list(p.accelerations) for p in points], self.world.kinematics.limits)
        tolerances = resolve_tolerances(
            self.world.controller.default_tolerances,
            [JointToleranceOverride(t.name, t.position, t.velocity) for t in goal.path_tolerance],
            [JointToleranceOverride(t.name, t.position, t.velocity) for t in goal.goal_tolerance],
            seconds(goal.goal_time_tolerance))
        header_stamp = trajectory_msg.header.stamp
        start = seconds(header_stamp) if (header_stamp.sec or header_stamp.nanosec) else None
        return trajectory, tolerances, start

    def _start_execution(self, trajectory: JointTrajectory, tolerances: Tolerances,
                         start: float | None) -> TrajectoryExecution:
        now = self.world.sim_time
        return self.world.controller.start(trajectory, tolerances,
                                           now if start is None else start, now)

    def _execute_goal(self, goal_handle: ServerGoalHandle) -> FollowJointTrajectory.Result:
        result = FollowJointTrajectory.Result()
        with self._start_turn:
            execution = self._started.pop(bytes(goal_handle.goal_id.uuid))
        if isinstance(execution, TrajectoryError):
            self.get_logger().warn(f"trajectory goal refused ({execution.code.name}): {execution}")
            goal_handle.abort()
            result.error_code, result.error_string = int(execution.code), str(execution)
            return result
        if isinstance(execution, SimulationStopped):
            return self._abort_stopped(goal_handle, result, execution)
        published = False
        next_feedback = time.monotonic()
        while not execution.done:
            if not (self._physics_thread.is_alive() and self.context.ok()):
                # Nothing moves the arm any more: waiting on would keep this thread, and so the
                # process, alive after shutdown until it is killed (nor can feedback go out).
                return self._abort_stopped(goal_handle, result, SimulationStopped(
                    "the simulation stopped (the node is shutting down) before the trajectory "
                    "ended"))
            if goal_handle.is_cancel_requested:
                try:
                    self._call_in_physics(lambda: self.world.controller.cancel(execution))
                except SimulationStopped as stopped:
                    return self._abort_stopped(goal_handle, result, stopped)
                continue
            if execution.desired is not None and time.monotonic() >= next_feedback:
                goal_handle.publish_feedback(self._feedback(execution))
                published = True
                next_feedback += self.feedback_period
            time.sleep(GOAL_POLL_PERIOD_S)
        self._frames_due = self.frames_after_motion
        if not published and execution.desired is not None:
            # At full sim speed a short trajectory can end before the first feedback period;
            # every executed goal still reports at least its final state.
            goal_handle.publish_feedback(self._feedback(execution))
        result.error_code = int(execution.error_code)
        result.error_string = execution.error_string
        result.tool_rms_error = execution.tool_rms_error
        result.tool_max_error = execution.tool_error_max
        result.end_stamp = time_message(execution.time)
        if execution.status is ExecutionStatus.SUCCEEDED:
            goal_handle.succeed()
        elif execution.status is ExecutionStatus.CANCELED:
            goal_handle.canceled()
        else:
            self.get_logger().warn(f"trajectory goal ended {execution.status.value}: "
                                   f"{execution.error_string}")
            goal_handle.abort()
        return result

    def _abort_stopped(self, goal_handle: ServerGoalHandle, result: FollowJointTrajectory.Result,
                       stopped: SimulationStopped) -> FollowJointTrajectory.Result:
        """End a goal the stopped simulation cannot execute: PREEMPTED, by the shutdown."""
        result.error_code = int(TrajectoryErrorCode.PREEMPTED)
        result.error_string = str(stopped)
        if self.context.ok():
            goal_handle.abort()
        return result

    def _feedback(self, execution: TrajectoryExecution) -> FollowJointTrajectory.Feedback:
        desired: SetPoint = execution.desired
        positions, velocities = execution.actual_positions, execution.actual_velocities
        feedback = FollowJointTrajectory.Feedback()
        feedback.header.stamp = time_message(execution.time)
        feedback.joint_names = list(ARM_JOINT_NAMES)
        feedback.desired = _point(desired.positions, desired.velocities, desired.accelerations)
        feedback.actual = _point(positions, velocities)
        feedback.error = _point(desired.positions - positions, desired.velocities - velocities)
        return feedback

    # ---------------------------------------------------------------------------- services
    def _on_load_scenario(self, request: LoadScenario.Request,
                          response: LoadScenario.Response) -> LoadScenario.Response:
        try:
            scenario = load_scenario(request.scenario, request.seed if request.seed >= 0 else None)
        except TsrrtError as error:
            response.success, response.message = False, str(error)
            return response

        def reload() -> None:
            self.world.load_scenario(scenario)
            self.renderer.load_scenario(scenario)
            self._last_render = None
            self._continuous_theta.clear()
            self.world.settle(0.5)

        try:
            self._call_in_physics(reload)
        except TsrrtError as error:
            response.success, response.message = False, str(error)
            return response
        self.get_logger().info(f"loaded scenario '{scenario.name}' (seed {scenario.seed})")
        response.success, response.scenario_name = True, scenario.name
        response.message = f"loaded {scenario.source} with seed {scenario.seed}"
        return response

    def _on_disturb_object(self, request: DisturbObject.Request,
                           response: DisturbObject.Response) -> DisturbObject.Response:
        try:
            pose: Pose2D = self._call_in_physics(lambda: self.world.disturb_object(
                request.object_id, request.dx, request.dy, request.dtheta))
        except TsrrtError as error:
            response.success, response.message = False, str(error)
            return response
        response.success = True
        response.message = (f"{request.object_id} moved to ({pose.x:.4f}, {pose.y:.4f}, "
                            f"{pose.theta:.4f})")
        return response

    # ---------------------------------------------------------------------------- shutdown
    def destroy_node(self) -> None:
        """Stop physics, the render worker and PyBullet before the node goes."""
        self._stop.set()
        if self._physics_thread.is_alive():
            self._physics_thread.join(timeout=5.0)
        self.renderer.close()
        self.world.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(SimNode, "sim_node", threads=6, args=args)


if __name__ == "__main__":
    main()
