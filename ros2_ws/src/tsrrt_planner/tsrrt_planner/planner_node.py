"""planner_node: LearnModels, PlanTask and RunTask on top of the ROS-free planner core.

Actions (one at a time: there is one arm):
* /planner/learn_models (LearnModels): LEARN_MODEL (Fig. 2) in place for every object whose
  models do not yet satisfy the stopping rule, through /executor/execute_primitive; models are
  saved atomically after every object and published on /planner/models (transient local).
* /planner/plan_task (PlanTask): anytime TASK_SPACE_RRT (Fig. 4) from the settled observation;
  cancel returns the best plan so far. The plan goes to /planner/plan and /planner/markers.
* /planner/run_task (RunTask): learn what is missing, plan, execute push by push, replan when the
  observation leaves what the models explain (closed_loop.run_task).

An object the arm cannot push where it stands (problem.out_of_reach) is not learned: it is
logged as UNREACHABLE, the task is planned around it where it stands, and a RunTask that
succeeds says so in its error_msg.

Observations come only from perception (/perception/get_settled_objects), never ground truth.
Callbacks that wait on other servers run in a ReentrantCallbackGroup on a MultiThreadedExecutor
and wait with timeouts, so a missing executor or perception node ends a goal with a clear error
instead of a hang.
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time as TimeMessage
from geometry_msgs.msg import Point, Vector3
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from tsrrt_common.errors import TsrrtError
from tsrrt_common.geometry import Pose2D, footprint_polygon
from tsrrt_common.ros_node import (
    SETTLE_REQUEST_S,
    ActionClient,
    answer_internal_error,
    run_node,
    shutting_down,
)
from tsrrt_common.scenario import Scenario, load_scenario
from tsrrt_executor.push_primitives import primitives_for
from tsrrt_executor.reachability import default_map
from tsrrt_interfaces.action import ExecutePrimitive, LearnModels, PlanTask, RunTask
from tsrrt_interfaces.msg import ForwardModel as ForwardModelMsg
from tsrrt_interfaces.msg import ForwardModelArray, ObjectState, ObjectStateArray, Plan, PlanStep
from tsrrt_interfaces.srv import GetSettledObjects
from tsrrt_planner.closed_loop import (
    MIN_MEASURED_SHARE,
    ExecutionFailed,
    LearningArea,
    LearningProgress,
    PushOutcome,
    TaskReport,
    TaskSettings,
    learn_in_place,
    plan_from,
    run_task,
    scenario_at,
)
from tsrrt_planner.errors import Cancelled, ModelFileError, PlannerError
from tsrrt_planner.lower_bound import LowerBound, lower_bound, relative_gap
from tsrrt_planner.model_learning import (
    ConfidenceStoppingRule,
    DisplacementStats,
    MirrorCheck,
    ModelStore,
    PaperStoppingRule,
    StoppingRule,
    learned,
)
from tsrrt_planner.objectives import build_objective
from tsrrt_planner.problem import PlanningProblem, longest_push, out_of_reach
from tsrrt_planner.push_rule import assume_rule_where_uncovered
from tsrrt_planner.task_space_rrt import MODES, PlanResult

# String parameters and their allowed values (numbers have ranges in their descriptors).
CHOICES = {"planner": MODES, "stopping_rule": ("confidence", "variance")}
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


class GoalFailed(Exception):
    """Ends a goal early: `reason` names a result constant (e.g. "NO_OBSERVATION").

    The three actions number their codes differently, so the name is resolved against the
    running action's result type; a reason that action lacks becomes its generic failure.
    """

    def __init__(self, reason: str, message: str) -> None:
        self.reason = reason
        super().__init__(message)

    def code_for(self, result: Any) -> int:
        for name in (self.reason, "EXECUTION_FAILED", "PLANNING_FAILED", "INVALID_GOAL"):
            if hasattr(result, name):
                return int(getattr(result, name))
        raise AssertionError(f"{type(result).__name__} has no failure code")


def _float(low: float, high: float, description: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, floating_point_range=[
        FloatingPointRange(from_value=low, to_value=high)])


def _integer(low: int, high: int, description: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, integer_range=[
        IntegerRange(from_value=low, to_value=high, step=1)])


def default_models_path(scenario_name: str) -> Path:
    data_home = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(data_home) / "tsrrt" / "models" / f"{scenario_name}.yaml"


def wait_for_future(future: rclpy.task.Future, timeout_s: float,
                    cancelled: Callable[[], bool] = lambda: False) -> bool:
    """Block this (executor worker) thread until the future is done; False on timeout, cancel
    or shutdown."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    deadline = time.monotonic() + timeout_s
    while not done.wait(0.05):
        if time.monotonic() > deadline or cancelled() or shutting_down():
            return False
    return True


def _raise_if_shutting_down() -> None:
    if shutting_down():
        raise GoalFailed("CANCELED", "the node is shutting down")


def _stop_requested(goal_handle) -> bool:
    """A goal's work stops on its cancel and on the node's shutdown alike."""
    return goal_handle.is_cancel_requested or shutting_down()


OBSERVE_ATTEMPTS = 3   # settled observations an object may be missing from before the task stops
HANDSHAKE_RESEND_S = 1.0   # a handshake goal unanswered this long is sent again


class RosTaskEnvironment:
    """closed_loop.TaskEnvironment over perception's settled observations and the executor."""

    def __init__(self, node: PlannerNode, object_ids: list[str],
                 cancelled: Callable[[], bool]) -> None:
        self.node = node
        self.object_ids = object_ids
        self.cancelled = cancelled
        # Stamp of the executor's settled observation after the last push: the scene it shows
        # is current, so the next observe() need not wait for a newer frame.
        self.last_push_seen: TimeMessage | None = None

    def observe(self) -> dict[str, Pose2D]:
        """Poses of every object in a settled observation; an object missing from one is asked
        for again in fresh frames (perception re-acquires a lost track when it sees the object)."""
        for attempt in range(OBSERVE_ATTEMPTS):
            states = self.node.settled_objects(self.last_push_seen)
            self.last_push_seen = None
            self.node.publish_observation(states)
            poses = {s.id: Pose2D(s.x, s.y, s.theta) for s in states
                     if s.status != ObjectState.STATUS_LOST}
            missing = [i for i in self.object_ids if i not in poses]
            if not missing:
                return poses
            self.node.get_logger().warning(
                f"perception does not see {missing} (observation {attempt + 1} of "
                f"{OBSERVE_ATTEMPTS})")
        raise GoalFailed("NO_OBSERVATION", f"perception does not see {missing} in "
                                           f"{OBSERVE_ATTEMPTS} settled observations")

    def execute(self, object_id: str, primitive: int, push_length: float) -> PushOutcome:
        result = self.node.execute_primitive(object_id, primitive, push_length, self.cancelled)
        if result.error_code != ExecutePrimitive.Result.SUCCESS:
            codes = ExecutePrimitive.Result
            # Refused before moving, or stopped part-way with the arm taken back out of view.
            blocked = result.error_code in (codes.UNREACHABLE, codes.IK_FAILED)
            recoverable = result.error_code == codes.TRACKING_FAILED
            raise ExecutionFailed(result.error_code, result.error_msg, blocked, recoverable)
        before, after = result.before, result.after
        self.last_push_seen = after.last_seen
        return PushOutcome(Pose2D(before.x, before.y, before.theta),
                           Pose2D(after.x, after.y, after.theta))


class PlannerNode(Node):
    def __init__(self) -> None:
        super().__init__("planner_node")
        # Registered first, so that a bad value is refused at declaration too.
        self.add_on_set_parameters_callback(self._check_choices)
        self._declare_parameters()
        self.scenario: Scenario = load_scenario(self.get_parameter("scenario").value,
                                                self.get_parameter("seed").value)
        build_objective(self.scenario)   # a contradictory objective stops the node here
        path = self.get_parameter("models_path").value
        self.models_path = Path(path) if path else default_models_path(self.scenario.name)
        self.store, self.store_problem = self._load_models()
        self.reachability = default_map()
        self._lower_bound: Future[LowerBound] = Future()
        threading.Thread(target=self._compute_bound, name="lower_bound", daemon=True).start()
        self.unreachable: set[str] = set()   # objects left where they stand: out of reach
        self._busy = threading.Lock()
        self._executor_answered = False   # since this goal began (see _handshake_executor)
        group = ReentrantCallbackGroup()

        self.models_publisher = self.create_publisher(ForwardModelArray, "/planner/models",
                                                      LATCHED)
        self.plan_publisher = self.create_publisher(Plan, "/planner/plan", LATCHED)
        self.markers_publisher = self.create_publisher(MarkerArray, "/planner/markers", LATCHED)
        # Every settled observation the planner acts on, for reports and replay.
        self.observed_publisher = self.create_publisher(ObjectStateArray, "/planner/observed",
                                                        10)
        self.settled_client = self.create_client(
            GetSettledObjects, "/perception/get_settled_objects", callback_group=group)
        self.executor_client = ActionClient(self, ExecutePrimitive,
                                            "/executor/execute_primitive", callback_group=group)
        common = dict(goal_callback=self._accept_one, cancel_callback=lambda _: (
            CancelResponse.ACCEPT), callback_group=group)
        self.learn_server = ActionServer(self, LearnModels, "/planner/learn_models",
                                         self._learn_models, **common)
        self.plan_server = ActionServer(self, PlanTask, "/planner/plan_task", self._plan_task,
                                        **common)
        self.run_server = ActionServer(self, RunTask, "/planner/run_task", self._run_task,
                                       **common)
        self._publish_models()
        self.get_logger().info(
            f"planning {self.scenario.name} ({len(self.scenario.objects)} objects); models: "
            f"{self.models_path} ({len(self.store.models)} loaded)")

    # ------------------------------------------------------------------ parameters, models
    def _declare_parameters(self) -> None:
        declare = self.declare_parameter
        declare("scenario", "clean", ParameterDescriptor(
            description="shipped scenario name or path to a scenario YAML", read_only=True))
        declare("seed", -1, _integer(-1, 2**31 - 1, "placement seed override (-1: the file's)"))
        declare("models_path", "", ParameterDescriptor(
            description="forward-model file; empty: $XDG_DATA_HOME/tsrrt/models/<scenario>.yaml",
            read_only=True))
        declare("planner", "tsrrt", ParameterDescriptor(
            description=f"default planner: one of {list(MODES)}"))
        declare("planning_budget_s", 8.0, _float(0.05, 600.0, "time per (re)plan, s"))
        declare("first_planning_budget_s", 12.0, _float(0.0, 600.0,
                "longest time for a task's first plan (at least planning_budget_s); past "
                "planning_budget_s only while its best is above first_plan_gap, s"))
        declare("first_plan_gap", 0.10, _float(0.0, 10.0,
                "gap to the lower bound above which a task's first plan goes on past "
                "planning_budget_s (relative to |bound|; to the start's distance if it is 0)"))
        declare("stall_s", 2.0, _float(0.0, 600.0,
                "RunTask: a plan stops when, near what the plan it replaces promised (or the "
                "lower bound; the first plan: within first_plan_gap of it), its best improves "
                "by less than convergence in this long, s (0: off)"))
        declare("stall_far_s", 3.0, _float(0.0, 600.0,
                "RunTask: ... and, farther from it but with a gain worth executing, when its "
                "best improves by less than convergence in this long, s (0: never)"))
        declare("give_up_s", 4.0, _float(0.0, 600.0,
                "RunTask: a plan after the first stops when it has found nothing worth "
                "executing (a gain below convergence) in this long, s (0: off; replans: see "
                "give_up_near)"))
        declare("give_up_near", 6.0, _float(0.0, 1000.0,
                "RunTask: a replan gives up (give_up_s) only when it starts within this many "
                "times convergence of the best cost the task was promised"))
        declare("pushes_per_convergence", 10, _integer(1, 10000,
                "RunTask: a plan after the first must predict a gain of convergence for every "
                "this many pushes it takes, or the task has converged"))
        declare("push_cost_share", 0.5, _float(0.0, 10.0,
                "RunTask, PlanTask: a plan goes to the state whose cost plus this share of "
                "that gain per push is least (0: to the best state found)"))
        declare("planning_margin", 0.005, _float(0.0, 0.1,
                "clearance plans keep between objects (and the lower bound too), m"))
        declare("planner_seed", 0, _integer(0, 2**31 - 1, "seed of the planner"))
        declare("planning_workers", 2, _integer(1, 64,
                "seeds searched at once, one process each; the best plan is kept (a core "
                "each: more than the machine's cores only slows each search)"))
        declare("max_pushes", 150, _integer(1, 10000, "pushes a RunTask may execute"))
        declare("time_budget_s", 900.0, _float(1.0, 86400.0, "wall time a RunTask may take"))
        declare("convergence", 0.01, _float(0.0, 1.0,
                                             "relative predicted improvement to stop at"))
        declare("stopping_rule", "confidence", ParameterDescriptor(
            description="'confidence' (mean's 95 % half-width) or 'variance' (paper)"))
        declare("min_trials", 3, _integer(2, 1000, "fewest trials of a primitive"))
        declare("max_trials", 12, _integer(2, 1000, "most trials of a primitive"))
        declare("position_tolerance", 0.004, _float(1e-4, 0.1,
                                                    "confidence rule: half-width, m"))
        declare("angle_tolerance", 0.035, _float(1e-4, 1.0,
                                                 "confidence rule: half-width, rad"))
        declare("mirror_check", True, ParameterDescriptor(
            description="learn the second primitive of a mirror pair (2, 4, 6) from the first's "
                        "trials plus one of its own within position/angle_tolerance of them"))
        declare("learning_edge_margin", 0.005, _float(0.0, 0.2,
                "closest a learning push may bring an object to the table edge, m"))
        declare("learning_clearance", 0.01, _float(0.0, 0.2,
                "closest a learning push may bring an object to another one, m"))
        declare("lower_bound_starts", 12, _integer(1, 1000, "multi-starts of the lower bound"))
        declare("server_timeout_s", 5.0, _float(0.1, 600.0,
                                                "wait for executor/perception servers, s"))
        declare("push_timeout_s", 60.0, _float(1.0, 3600.0, "wait for one push, s"))
        declare("observe_timeout_s", 15.0, _float(0.5, 600.0,
                                                  "wait for a settled observation, s"))

    @staticmethod
    def _check_choices(parameters: list) -> SetParametersResult:
        for parameter in parameters:
            choices = CHOICES.get(parameter.name)
            if choices is not None and parameter.value not in choices:
                return SetParametersResult(successful=False, reason=(
                    f"{parameter.name} must be one of {list(choices)}, got {parameter.value!r}"))
        return SetParametersResult(successful=True)

    def _check_goal_value(self, field: str, value: float, parameter: str) -> None:
        """A goal field that overrides a parameter (0: use the parameter) must lie within the
        parameter's declared range; raises GoalFailed(INVALID_GOAL) naming both."""
        descriptor = self.describe_parameter(parameter)
        bounds = (descriptor.floating_point_range or descriptor.integer_range)[0]
        if value != 0 and not bounds.from_value <= value <= bounds.to_value:   # NaN too
            raise GoalFailed("INVALID_GOAL", f"{field} must be 0 (the {parameter} parameter) "
                             f"or within [{bounds.from_value:g}, {bounds.to_value:g}], got "
                             f"{value!r}")

    def _require_readable_models(self) -> None:
        """Learning must not start when its result could only be saved over a file that
        could not be read (that file is kept as it is)."""
        if self.store_problem is not None:
            raise GoalFailed("LEARNING_FAILED", "the model file could not be read and is not "
                             f"overwritten; move it away to learn anew: {self.store_problem}")

    def _param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _load_models(self) -> tuple[ModelStore, str | None]:
        """Models from disk; a corrupt file is reported and never overwritten."""
        if not self.models_path.exists():
            return ModelStore(), None
        try:
            return ModelStore.load(self.models_path), None
        except ModelFileError as error:
            self.get_logger().error(f"{error}; learning will not overwrite it - move it away")
            return ModelStore(), str(error)

    def _save_models(self) -> None:
        if self.store_problem is not None:
            raise GoalFailed("EXECUTION_FAILED",
                             f"not saving over the unreadable model file: {self.store_problem}")
        self.models_path.parent.mkdir(parents=True, exist_ok=True)
        self.store.save(self.models_path)
        self._publish_models()

    def _stopping_rule(self, name: str, max_trials: int) -> StoppingRule:
        self._check_goal_value("max_trials_per_primitive", max_trials, "max_trials")
        name = name or self._param("stopping_rule")
        max_trials = max_trials or self._param("max_trials")
        min_trials = min(self._param("min_trials"), max_trials)
        if name == "confidence":
            return ConfidenceStoppingRule(self._param("position_tolerance"),
                                          self._param("angle_tolerance"),
                                          min_trials=min_trials, max_trials=max_trials)
        if name == "variance":
            return PaperStoppingRule(min_trials=min_trials, max_trials=max_trials)
        raise GoalFailed("INVALID_GOAL",
                         f"unknown stopping rule {name!r}; known: 'confidence', 'variance'")

    def _mirror_check(self) -> MirrorCheck | None:
        if not self._param("mirror_check"):
            return None
        return MirrorCheck(self._param("position_tolerance"), self._param("angle_tolerance"))

    def _statistics(self, object_id: str) -> dict[int, DisplacementStats]:
        """What the store holds of the object's primitives, as learning statistics."""
        return {p: DisplacementStats(m.count, m.mean.copy(), m.m2.copy())
                for (o, p), m in self.store.models.items() if o == object_id}

    def _needs_learning(self, object_id: str, shape_primitives: tuple[int, ...],
                        rule: StoppingRule) -> bool:
        if self.store.classes.get(object_id) != self.scenario.object(object_id).object_class:
            return True
        statistics = self._statistics(object_id)
        mirror = self._mirror_check()
        return not all(learned(p, statistics, rule, mirror) for p in shape_primitives)

    def _models_message(self) -> ForwardModelArray:
        rule, mirror = self._stopping_rule("", 0), self._mirror_check()
        statistics = {object_id: self._statistics(object_id)
                      for object_id in {object_id for object_id, _ in self.store.models}}
        longest = {spec.id: longest_push(self.store, spec) for spec in self.scenario.objects}
        message = ForwardModelArray()
        message.header.stamp = self.get_clock().now().to_msg()
        for (object_id, primitive), model in sorted(self.store.models.items()):
            message.models.append(ForwardModelMsg(
                object_id=object_id, object_class=self.store.classes.get(object_id, ""),
                primitive=primitive, nominal_push_length=float(model.push_length),
                samples=int(model.count), mean=[float(v) for v in model.mean],
                variance=[float(v) for v in model.variance],
                converged=learned(primitive, statistics[object_id], rule, mirror),
                longest_push=longest.get(object_id, 0.0)))
        return message

    def _publish_models(self) -> None:
        self.models_publisher.publish(self._models_message())

    def publish_observation(self, states: list[ObjectState]) -> None:
        message = ObjectStateArray(objects=states)
        message.header.stamp = self.get_clock().now().to_msg()
        message.header.frame_id = "world"
        self.observed_publisher.publish(message)

    # ------------------------------------------------------------------ calls to other nodes
    def settled_objects(self, not_before: TimeMessage | None = None) -> list[ObjectState]:
        """A settled observation: stamped at or after `not_before`, else taken after now."""
        if not self.settled_client.wait_for_service(timeout_sec=self._param("server_timeout_s")):
            raise GoalFailed("NO_OBSERVATION",
                             "perception's /perception/get_settled_objects is not available")
        timeout = self._param("observe_timeout_s")
        deadline = time.monotonic() + timeout
        problem = "perception did not answer"
        while (remaining := deadline - time.monotonic()) > 0.0:
            _raise_if_shutting_down()
            wait_s = min(max(remaining, 0.5), SETTLE_REQUEST_S)
            future = self.settled_client.call_async(GetSettledObjects.Request(
                timeout_s=wait_s, not_before=not_before or TimeMessage()))
            if not wait_for_future(future, wait_s + SETTLE_REQUEST_S):
                self.settled_client.remove_pending_request(future)
                problem = "perception did not answer"
                continue
            response = future.result()
            if response.success:
                return list(response.objects.objects)
            problem = f"perception: {response.message}"
        raise GoalFailed("NO_OBSERVATION",
                         f"no settled observation within {timeout:.0f} s ({problem})")

    def execute_primitive(self, object_id: str, primitive: int, push_length: float,
                          cancelled: Callable[[], bool]) -> ExecutePrimitive.Result:
        if not self.executor_client.wait_for_server(timeout_sec=self._param("server_timeout_s")):
            raise GoalFailed("EXECUTOR_UNAVAILABLE",
                             "the executor's /executor/execute_primitive is not available")
        if not self._executor_answered:
            self._handshake_executor()
        goal = ExecutePrimitive.Goal(object_id=object_id, primitive=primitive,
                                     push_length=float(push_length))
        sent = self.executor_client.send_goal_async(goal)
        if not wait_for_future(sent, self._param("server_timeout_s")):
            raise GoalFailed("EXECUTOR_UNAVAILABLE",
                             "the executor did not answer the goal")
        handle = sent.result()
        if not handle.accepted:
            raise GoalFailed("EXECUTION_FAILED", "the executor rejected the push")
        result_future = handle.get_result_async()
        if not wait_for_future(result_future, self._param("push_timeout_s"), cancelled):
            _raise_if_shutting_down()   # nobody is left to answer a cancel
            cancel_future = handle.cancel_goal_async()
            wait_for_future(cancel_future, self._param("server_timeout_s"))
            # The executor retreats before it answers a cancel; wait for that answer.
            wait_for_future(result_future, self._param("push_timeout_s"))
            if cancelled():
                raise GoalFailed("CANCELED", "cancelled during a push")
            raise GoalFailed("EXECUTION_FAILED",
                             f"push of {object_id} took longer than "
                             f"{self._param('push_timeout_s'):.0f} s")
        return result_future.result().result

    def _handshake_executor(self) -> None:
        """Before a goal's first push, goals naming no object until one is answered in full.

        wait_for_server sees only that the executor exists; rmw_fastrtps drops the answers of a
        server that has not yet matched this client's readers (a restarted executor), and a push
        whose answer is lost cannot be sent again, since it may be running. A goal naming no
        object fails at once and is safe to repeat."""
        timeout = self._param("server_timeout_s")
        deadline = time.monotonic() + timeout
        sent: list[rclpy.task.Future] = []
        while time.monotonic() < deadline:
            _raise_if_shutting_down()
            sent.append(self.executor_client.send_goal_async(ExecutePrimitive.Goal()))
            answered = next((f for f in sent if f.done()), None)
            if answered is None and wait_for_future(sent[-1], HANDSHAKE_RESEND_S):
                answered = sent[-1]
            if answered is None:
                continue
            handle = answered.result()
            if not handle.accepted or wait_for_future(handle.get_result_async(),
                                                      HANDSHAKE_RESEND_S):
                self._executor_answered = True
                return
        raise GoalFailed("EXECUTOR_UNAVAILABLE",
                         f"the executor did not answer {len(sent)} handshake goals within "
                         f"{timeout:g} s")

    # ------------------------------------------------------------------ actions
    def _accept_one(self, goal: object) -> GoalResponse:
        if self._busy.locked():
            self.get_logger().warning("rejecting a goal: another task is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _run_exclusive(self, goal_handle, result, work: Callable[[], None]):
        """Run `work`, mapping GoalFailed and library errors to the result's code/message. A
        goal still running at shutdown outlives its node (rclpy destroys the node without
        waiting for callbacks): its handle and publishers are gone, so nothing is sent."""
        if not self._busy.acquire(blocking=False):
            result.error_code = result.INVALID_GOAL
            result.error_msg = "another task is running"
            goal_handle.abort()
            return result
        self._executor_answered = False
        try:
            work()
            result.error_code = result.SUCCESS
            if not shutting_down():
                goal_handle.succeed()
        except GoalFailed as failure:
            result.error_code, result.error_msg = failure.code_for(result), str(failure)
            self._finish(goal_handle, failure.reason == "CANCELED")
        except ExecutionFailed as failure:
            reason = ("UNREACHABLE" if failure.code == ExecutePrimitive.Result.UNREACHABLE
                      else "EXECUTION_FAILED")
            result.error_code = GoalFailed(reason, "").code_for(result)
            result.error_msg = f"executor: {failure}"
            self._finish(goal_handle, failure.code == ExecutePrimitive.Result.CANCELED)
        except (TsrrtError, ValueError) as failure:
            result.error_code, result.error_msg = result.INVALID_GOAL, str(failure)
            self._finish(goal_handle, False)
        except Exception as error:   # noqa: BLE001 - a bug: answered, never left unanswered
            if shutting_down():
                result.error_code = GoalFailed("CANCELED", "").code_for(result)
                result.error_msg = "the node shut down during the goal"
            else:
                answer_internal_error(self, goal_handle, result, error)
        finally:
            self._busy.release()
        if result.error_code != result.SUCCESS:
            self.get_logger().error(f"goal failed: {result.error_msg}")
        return result

    @staticmethod
    def _finish(goal_handle, cancelled: bool) -> None:
        if shutting_down():
            return
        if cancelled and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()

    def _learn_models(self, goal_handle) -> LearnModels.Result:
        result = LearnModels.Result()
        goal = goal_handle.request

        def work() -> None:
            ids = list(goal.object_ids) or [o.id for o in self.scenario.objects]
            known = [o.id for o in self.scenario.objects]
            unknown = [i for i in ids if i not in known]
            if unknown:
                raise GoalFailed("UNKNOWN_OBJECT", f"unknown objects {unknown}; known: "
                                 f"{known}")
            rule = self._stopping_rule(goal.stopping_rule, goal.max_trials_per_primitive)
            self._require_readable_models()
            result.trials = self._learn(
                ids, rule, lambda: _stop_requested(goal_handle),
                lambda progress, total: goal_handle.publish_feedback(LearnModels.Feedback(
                    object_id=progress.object_id, primitive=progress.primitive,
                    trials_done=total, sigma=[float(v) for v in progress.sigma])))
            result.models = self._models_message().models

        return self._run_exclusive(goal_handle, result, work)

    def _learn(self, ids: list[str], rule: StoppingRule, cancelled: Callable[[], bool],
               on_trial: Callable[[LearningProgress, int], None]) -> int:
        """LEARN_MODEL for each listed object that needs it; returns the number of trials.

        `on_trial` gets each trial's progress and the trials done so far over all objects.
        """
        environment = RosTaskEnvironment(self, [o.id for o in self.scenario.objects],
                                         cancelled)
        trials = 0
        self.unreachable = set()
        to_learn = [i for i in ids if self._needs_learning(
            i, primitives_for(self.scenario.object(i).shape), rule)]
        for k, object_id in enumerate(to_learn):
            spec = self.scenario.object(object_id)
            observed = environment.observe()
            pose = observed[object_id]
            if out_of_reach(dataclasses.replace(spec, pose=pose), self.reachability,
                            self.scenario.table.height):
                self.unreachable.add(object_id)
                self.get_logger().warning(
                    f"UNREACHABLE: {object_id} at ({pose.x:.3f}, {pose.y:.3f}) is out of the "
                    "arm's reach; not learned, the task is planned around it where it stands")
                continue
            area = LearningArea(self.scenario.table, tuple(
                [(o, observed[o.id]) for o in self.scenario.objects if o.id != object_id]
                + [(o, o.pose) for o in self.scenario.obstacles]),
                edge_margin=self._param("learning_edge_margin"),
                clearance=self._param("learning_clearance"), reach=self.reachability,
                waiting=frozenset(to_learn[k + 1:]))
            self.get_logger().info(f"learning push models of {object_id}")
            done_before = trials
            outcome = learn_in_place(
                spec, pose, environment.execute, rule,
                on_trial=lambda progress, before=done_before: on_trial(
                    progress, before + progress.trials),
                cancelled=cancelled, prior=self._statistics(object_id), area=area,
                mirror=self._mirror_check())
            for reason in outcome.skipped:
                self.get_logger().warning(f"{object_id}: could not learn {reason}")
            trials += outcome.trials
            for model in outcome.models.values():
                self.store.add(model, spec.object_class)
            self._save_models()
            if cancelled():
                raise GoalFailed("CANCELED", "cancelled while learning")
            if not outcome.converged:
                self.get_logger().warning(f"{object_id}: models did not converge within the "
                                          "trial limit; planning with them anyway")
        return trials

    def _compute_bound(self) -> None:
        """The lower bound and its optimum (the planner's target), computed once, in the
        background from the node's start: it needs only the scenario, not the models (it
        ignores pushing), so it is ready by the time learning ends instead of adding its
        seconds to the task's (clean 4 s, tset6 with its twelve starts up to 22 s).

        From the scenario as loaded, as the planner bench does, not from what the robot
        observes when a task begins: the multi-start's first start is the start state, and an
        objective may have a continuum of optima (tset6: two platters touching on any line
        through the table's centre cost the same), of which the one found decides what the
        planner steers to. From a tset6 demo's observed start, 8 s of planning towards the
        optimum found from that start reached 51-63 % above the bound (3 seeds), towards the
        bench's 26 %. A shutdown stops it."""
        try:
            rules = ModelStore()   # any models covering the objects: the bound ignores them
            assume_rule_where_uncovered(rules, self.scenario.objects)
            problem = PlanningProblem(self.scenario, rules, self.reachability,
                                      margin=self._param("planning_margin"))
            self._lower_bound.set_result(lower_bound(
                problem, starts=self._param("lower_bound_starts"), cancel=shutting_down))
        except Exception as error:   # Cancelled too: handed to the goal that needs the bound
            self._lower_bound.set_exception(error)

    def _bound(self, cancelled: Callable[[], bool]) -> LowerBound:
        """The lower bound, waiting for the background computation while the goal lasts."""
        while True:
            try:
                return self._lower_bound.result(timeout=0.1)
            except TimeoutError:
                if cancelled():
                    raise GoalFailed("CANCELED",
                                     "cancelled while the lower bound was computed") from None
            except Cancelled:
                raise GoalFailed("CANCELED",
                                 "the lower bound was stopped by the shutdown") from None

    def _settings(self, planner: str, budget_s: float, max_pushes: int = 0,
                  time_budget_s: float = 0.0, seed: int = -1) -> TaskSettings:
        planner = planner or self._param("planner")
        if planner not in MODES:
            raise GoalFailed("INVALID_GOAL",
                             f"unknown planner {planner!r}; known: {list(MODES)}")
        for field, value, parameter in (("budget_s", budget_s, "planning_budget_s"),
                                        ("max_pushes", max_pushes, "max_pushes"),
                                        ("time_budget_s", time_budget_s, "time_budget_s")):
            self._check_goal_value(field, value, parameter)
        return TaskSettings(
            planner=planner, planning_budget_s=budget_s or self._param("planning_budget_s"),
            first_planning_budget_s=self._param("first_planning_budget_s"),
            first_plan_gap=self._param("first_plan_gap"),
            max_pushes=max_pushes or self._param("max_pushes"),
            time_budget_s=time_budget_s or self._param("time_budget_s"),
            convergence=self._param("convergence"),
            stall_s=self._param("stall_s") or None,
            stall_far_s=self._param("stall_far_s") or None,
            give_up_s=self._param("give_up_s") or None,
            give_up_near=self._param("give_up_near"),
            pushes_per_convergence=self._param("pushes_per_convergence"),
            push_cost_share=self._param("push_cost_share"),
            seed=seed if seed >= 0 else self._param("planner_seed"),
            planning_workers=self._param("planning_workers"),
            margin=self._param("planning_margin"))

    def _check_models(self, reason: str) -> None:
        """Every object needs models; a primitive nothing learned covers (never tried: it was
        blocked while learning, and neither a class-mate nor its mirror partner has one) is
        planned with the physics-free push rule until it is executed, with a warning."""
        if self.store_problem is not None:
            raise GoalFailed(reason, f"the model file could not be read: {self.store_problem}")
        objects = [o for o in self.scenario.objects if o.id not in self.unreachable]
        try:
            self.store.check_covers([(o.id, o.object_class, o.shape) for o in objects],
                                    every_primitive=False, borrow=True)
        except ModelFileError as error:
            raise GoalFailed(reason, str(error)) from None
        assumed = assume_rule_where_uncovered(self.store, objects)
        if assumed:
            self.get_logger().warning(
                f"nothing learned covers {', '.join(assumed)}: planned with the physics-free "
                "push rule until executed")

    def _plan_task(self, goal_handle) -> PlanTask.Result:
        result = PlanTask.Result()
        goal = goal_handle.request

        def work() -> None:
            settings = self._settings(goal.planner, goal.budget_s, seed=goal.seed)
            self._check_models("NO_MODELS")
            ids = [o.id for o in self.scenario.objects]
            cancelled = lambda: _stop_requested(goal_handle)  # noqa: E731
            observed = RosTaskEnvironment(self, ids, cancelled).observe()
            self._check_start(observed, "INFEASIBLE_START")
            bound = self._bound(cancelled)
            began = time.monotonic()

            def feedback(info) -> None:
                goal_handle.publish_feedback(PlanTask.Feedback(
                    best_cost=float(info.best_cost), gap=_gap(info.best_cost, bound.cost),
                    nodes=int(info.nodes), elapsed_s=time.monotonic() - began))

            _, plan = plan_from(self.scenario, observed, self.store, self.reachability,
                                settings, bound.cost, bound.state, cancelled, feedback,
                                goal.max_nodes or None)
            result.plan = self._publish_plan(plan)
            result.nodes, result.planning_s = plan.nodes, plan.elapsed_s
            if not plan.steps:
                raise GoalFailed("NO_IMPROVEMENT",
                                 "no push lowers the objective from the observed state")

        return self._run_exclusive(goal_handle, result, work)

    def _check_start(self, observed: dict[str, Pose2D], reason: str) -> None:
        """Fail the goal with `reason` when no plan can start from the observed state."""
        try:
            PlanningProblem(scenario_at(self.scenario, observed), self.store,
                            self.reachability, margin=self._param("planning_margin"))
        except PlannerError as error:
            raise GoalFailed(reason, str(error)) from None

    def _run_task(self, goal_handle) -> RunTask.Result:
        result = RunTask.Result()
        goal = goal_handle.request

        def work() -> None:
            settings = self._settings(goal.planner, goal.planning_budget_s, goal.max_pushes,
                                      goal.time_budget_s)
            cancelled = lambda: _stop_requested(goal_handle)  # noqa: E731
            ids = [o.id for o in self.scenario.objects]
            self._require_readable_models()
            result.learning_trials = self._learn(
                ids, self._stopping_rule("", 0), cancelled,
                lambda progress, total: goal_handle.publish_feedback(RunTask.Feedback(
                    phase="learning", pushes_done=total, current_cost=math.nan,
                    best_predicted_cost=math.nan)))
            self._check_models("LEARNING_FAILED")
            environment = RosTaskEnvironment(self, ids, cancelled)
            self._check_start(environment.observe(), "PLANNING_FAILED")
            bound = self._bound(cancelled)

            reports: list[TaskReport] = []   # the task's, kept for a result on failure

            def on_event(phase: str, report: TaskReport) -> None:
                if not reports:
                    reports.append(report)
                if phase == "replanning" and report.divergences:
                    why = report.divergences[-1]
                    self.get_logger().info(
                        f"replanning after push {report.pushes}: {why.object_id} {why.reason} "
                        f"(position off by {why.position_error * 1000:.1f} mm, heading by "
                        f"{math.degrees(why.angle_error):.1f} deg)")
                goal_handle.publish_feedback(RunTask.Feedback(
                    phase=phase, pushes_done=report.pushes, pushes_planned=report.planned,
                    current_cost=report.final_cost,
                    best_predicted_cost=report.predicted_cost, replans=report.replans))

            try:
                report = run_task(self.scenario, self.store, environment, self.reachability,
                                  settings, bound.cost, bound.state, on_event, cancelled,
                                  on_model_update=self._save_models, on_plan=self._log_plan)
            except BaseException:
                # a push failed or was cancelled: report what was done up to there
                if reports:
                    self._fill_result(result, reports[0], bound.cost)
                raise
            self._fill_result(result, report, bound.cost)
            if report.stop_reason == "cancelled":
                raise GoalFailed("CANCELED", "cancelled")
            if report.stop_reason != "converged":
                raise GoalFailed("BUDGET_EXHAUSTED",
                                 f"stopped by the {report.stop_reason} before converging")
            if self.unreachable:
                result.error_msg = (f"UNREACHABLE: {sorted(self.unreachable)} out of the arm's "
                                    "reach, left where they stand")

        return self._run_exclusive(goal_handle, result, work)

    def _fill_result(self, result: RunTask.Result, report: TaskReport,
                     lower_bound: float) -> None:
        """A RunTask result's figures and final poses from the task's report."""
        result.final_cost, result.predicted_cost = report.final_cost, report.predicted_cost
        result.lower_bound, result.pushes = lower_bound, report.pushes
        result.replans, result.planning_s = report.replans, report.planning_s
        if report.clipped:
            self.get_logger().info(
                f"{report.clipped} executed pushes learned from clipped to their model's "
                "confidence (a neighbour or the table edge in the way?)")
        if report.unmeasured:
            self.get_logger().info(
                f"{report.unmeasured} executed pushes too short to learn from (under "
                f"{MIN_MEASURED_SHARE:.0%} of their model's length)")
        if report.capped:
            self.get_logger().info(
                f"pushes of {', '.join(report.capped)} held to the learned length from now on: "
                "a longer one turned the object outside its prediction")
        last = report.visited[-1]
        result.final_objects = [_object_state(spec, last[spec.id])
                                for spec in self.scenario.objects]

    # ------------------------------------------------------------------ plan output
    def _log_plan(self, plan: PlanResult) -> None:
        """Publish a RunTask (re)plan and say in the log what it promises."""
        self._publish_plan(plan)
        start = ", ".join(f"{spec.id} {x:.4f} {y:.4f} {theta:.3f}" for spec, (x, y, theta)
                          in zip(self.scenario.objects, plan.states[0], strict=True))
        self.get_logger().info(
            f"plan: {len(plan.steps)} pushes, cost {plan.costs[0]:.4f} -> {plan.best_cost:.4f} "
            f"predicted, {plan.nodes} nodes in {plan.elapsed_s:.1f} s, from {start}")

    def _publish_plan(self, plan: PlanResult) -> Plan:
        message = Plan()
        message.header.stamp = self.get_clock().now().to_msg()
        message.header.frame_id = "world"
        specs = self.scenario.objects
        message.start = [_object_state(s, Pose2D(*plan.states[0][i]))
                         for i, s in enumerate(specs)]
        for k, step in enumerate(plan.steps):
            message.steps.append(PlanStep(
                object_id=step.object_id, primitive=step.primitive,
                push_length=float(step.push_length),
                predicted=[_object_state(s, Pose2D(*plan.states[k + 1][i]))
                           for i, s in enumerate(specs)],
                predicted_cost=float(plan.costs[k + 1])))
        message.start_cost = float(plan.costs[0])
        message.predicted_cost = plan.best_cost
        bound = plan.lower_bound if plan.lower_bound is not None else math.nan
        message.lower_bound = float(bound)
        message.gap = _gap(plan.best_cost, bound)
        self.plan_publisher.publish(message)
        self.markers_publisher.publish(self._plan_markers(plan, message.header))
        return message

    def _plan_markers(self, plan: PlanResult, header) -> MarkerArray:
        """Outlines of every object along the plan, fading from start to goal (Fig. 1/6/7)."""
        markers = MarkerArray(markers=[Marker(action=Marker.DELETEALL)])
        count = len(plan.states)
        for i, spec in enumerate(self.scenario.objects):
            red, green, blue = spec.color
            for k, state in enumerate(plan.states):
                outline = footprint_polygon(spec.shape, spec.length, spec.width,
                                            Pose2D(*state[i]))
                alpha = 0.25 + 0.75 * k / max(count - 1, 1)
                markers.markers.append(Marker(
                    header=header, ns=f"plan/{spec.id}", id=k, type=Marker.LINE_STRIP,
                    action=Marker.ADD, scale=_scale(0.002),
                    color=ColorRGBA(r=red, g=green, b=blue, a=alpha),
                    points=[Point(x=float(x), y=float(y), z=self.scenario.table.height + 0.001)
                            for x, y in np.vstack([outline, outline[:1]])]))
        return markers


def _scale(width: float) -> Vector3:
    return Vector3(x=width, y=width, z=width)


def _gap(cost: float, bound: float) -> float:
    """The relative gap for a message: NaN where there is none (no bound, a zero optimum)."""
    gap = relative_gap(cost, bound)
    return math.nan if gap is None else float(gap)


def _object_state(spec, pose: Pose2D) -> ObjectState:
    return ObjectState(id=spec.id, object_class=spec.object_class, shape=spec.shape,
                       x=float(pose.x), y=float(pose.y), theta=float(pose.theta),
                       length=float(spec.length), width=float(spec.width),
                       height=float(spec.height), symmetry=int(spec.symmetry), confidence=1.0,
                       status=ObjectState.STATUS_TRACKED)


def main(args: list[str] | None = None) -> None:
    run_node(PlannerNode, "planner_node", threads=4, args=args)


if __name__ == "__main__":
    main()
