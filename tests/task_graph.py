"""The four nodes on a small task, for the tests that run whole tasks (integration/test_run_task,
reliability/test_faults, reliability/test_soak).

`TaskGraph` starts sim, perception, executor and planner through conftest's `launch` on the
module's domain, with a copy of a model file learned beforehand (the planner saves every executed
push into its file, and the shipped one must stay as it is), and uses conftest's probe to send
goals, call services and read the simulator's ground truth. The planner acts on perception only;
ground truth is read here to judge the outcome, as scripts/demo.py does.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from tsrrt_common.geometry import Pose2D
from tsrrt_common.ros_node import ActionClient
from tsrrt_common.scenario import Scenario, load_scenario
from tsrrt_interfaces.action import ExecutePrimitive, LearnModels, PlanTask, RunTask
from tsrrt_interfaces.msg import ObjectStateArray, Plan
from tsrrt_interfaces.srv import DisturbObject, LoadScenario
from tsrrt_planner.objectives import Objective, build_objective

DATA = Path(__file__).resolve().parent / "data"
SMALL_SCENARIO = DATA / "two_boxes.yaml"
SMALL_MODELS = DATA / "two_boxes_models.yaml"
RESULT_NAMES = {value: name for name, value in vars(RunTask.Result).items()
                if name.isupper() and isinstance(value, int)}
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STARTUP_TIMEOUT_S = 120.0       # a node's servers to appear on a loaded 2-core machine
TASK_TIMEOUT_S = 400.0          # a RunTask on the small scenario, generously
# The simulator paced at 10x real time instead of flat out: a push still takes about a second
# of wall time, and the physics thread leaves the cores to the other nodes (flat out, it starved
# the sim's own action server on a loaded 2-core machine).
SIM_PARAMETERS = ("real_time_factor:=10.0",)
# Wall-clock waits of the executor for the controller, raised from 5 s: on a shared 2-core
# machine an answer took longer than that now and then. What a missing server gives is tested
# against the planner's own timeout (test_faults.py), which is left at its default.
EXECUTOR_PARAMETERS = ("server_timeout:=15.0",)
# Stop when a plan promises less than 5 % of the task's range (8 mm of summed distance on
# two_boxes) instead of 1 %: two_boxes' optimum is 0, and near it TASK_SPACE_RRT's plans detour
# (objects turned half a radian and back) for the last millimetre; executed, such detours
# sometimes pushed an object off the table. The graph tests are about the graph, not about
# that polish. Plans get 2 s each: two boxes need no more, and the tests run many plans.
PLANNER_PARAMETERS = ("convergence:=0.05", "planning_budget_s:=2.0")


class TaskGraph:
    """sim, perception, executor and planner on `scenario`, and clients for running tasks."""

    def __init__(self, launch, probe, folder: Path, scenario: Path = SMALL_SCENARIO,
                 models: Path = SMALL_MODELS, sim: tuple[str, ...] = (),
                 planner: tuple[str, ...] = ()) -> None:
        self.launch, self.probe = launch, probe
        self.use_scenario(scenario)
        self.models_path, self.shipped_models = folder / "models.yaml", models
        self.fresh_models()
        self.sim_parameters, self.planner_parameters = sim, planner
        self.truth: list[ObjectStateArray] = probe.record(ObjectStateArray, "/sim/object_states")
        self.plans: list[Plan] = probe.record(Plan, "/planner/plan", LATCHED)
        self.run_client = ActionClient(probe, RunTask, "/planner/run_task")
        self.plan_client = ActionClient(probe, PlanTask, "/planner/plan_task")
        self.learn_client = ActionClient(probe, LearnModels, "/planner/learn_models")
        self.execute_client = ActionClient(probe, ExecutePrimitive, "/executor/execute_primitive")
        self.disturb_client = probe.create_client(DisturbObject, "/sim/disturb_object")
        self.load_client = probe.create_client(LoadScenario, "/sim/load_scenario")
        self.sim_parameter_client = AsyncParameterClient(probe, "sim_node")
        self.processes: dict[str, Any] = {}

    def use_scenario(self, scenario: Path) -> None:
        """The scenario that nodes started from now on, reset() and true_cost() use."""
        self.scenario_path = scenario
        self.scenario: Scenario = load_scenario(str(scenario))
        self.objective: Objective = build_objective(self.scenario)

    def fresh_models(self) -> None:
        """The planner's model file back to the shipped one (with the planner stopped): every
        executed push is folded into it, bumped ones too."""
        shutil.copy(self.shipped_models, self.models_path)

    # ------------------------------------------------------------------ processes
    def start(self, *, wait: bool = True) -> TaskGraph:
        """Start the four nodes (each once) and wait for the planner's and sim's servers."""
        scenario = f"scenario:={self.scenario_path}"
        self.processes["sim_node"] = self.launch.start(
            "tsrrt_sim", "sim_node", scenario, *SIM_PARAMETERS, *self.sim_parameters)
        self.start_perception()
        self.start_executor()
        self.start_planner()
        if wait:
            self.wait_ready()
        return self

    def start_perception(self) -> Any:
        self.processes["perception_node"] = self.launch.start(
            "tsrrt_perception", "perception_node", f"scenario:={self.scenario_path}")
        return self.processes["perception_node"]

    def start_executor(self) -> Any:
        self.processes["executor_node"] = self.launch.start("tsrrt_executor", "executor_node",
                                                            *EXECUTOR_PARAMETERS)
        return self.processes["executor_node"]

    def start_planner(self) -> Any:
        self.processes["planner_node"] = self.launch.start(
            "tsrrt_planner", "planner_node", f"scenario:={self.scenario_path}",
            f"models_path:={self.models_path}", *PLANNER_PARAMETERS, *self.planner_parameters)
        return self.processes["planner_node"]

    def wait_ready(self) -> None:
        """Every action server and service the tests use is up (discovery included)."""
        for client in (self.run_client, self.plan_client, self.execute_client):
            assert client.wait_for_server(timeout_sec=STARTUP_TIMEOUT_S), \
                f"{client._action_name} did not come up:\n{self.logs()}"
        for client in (self.disturb_client, self.load_client):
            assert client.wait_for_service(timeout_sec=STARTUP_TIMEOUT_S), \
                f"{client.srv_name} did not come up:\n{self.logs()}"
        # Goals that fail at once (no such planner, no such object) until each server answers.
        self.probe.handshake(self.run_client, RunTask.Goal)
        self.probe.handshake(self.plan_client, PlanTask.Goal)
        self.probe.handshake(self.execute_client, ExecutePrimitive.Goal)
        self.wait_for_perception()

    def wait_for_perception(self, timeout: float = STARTUP_TIMEOUT_S) -> ObjectStateArray:
        """The next /perception/objects message that shows every object of the scenario."""
        ids = {o.id for o in self.scenario.objects}
        seen: list[ObjectStateArray] = []
        subscription = self.probe.create_subscription(
            ObjectStateArray, "/perception/objects", seen.append, 10)
        try:
            assert self.probe.spin_until(
                lambda: bool(seen) and ids <= {s.id for s in seen[-1].objects}, timeout), \
                f"perception does not show {sorted(ids)}:\n{self.logs()}"
        finally:
            self.probe.destroy_subscription(subscription)
        return seen[-1]

    def logs(self, tail: int = 3000) -> str:
        return "\n".join(f"--- {name} ---\n{process.log()[-tail:]}"
                         for name, process in self.processes.items())

    # ------------------------------------------------------------------ the world
    def reset(self, scenario: Path | None = None) -> None:
        """Put the objects back at the scenario's start (or another scenario's, with the same
        objects), the arm in its observe posture, and wait until perception shows them."""
        self.load(scenario)
        self.wait_for_perception()

    def load(self, scenario: Path | None = None) -> None:
        """Load the scenario (or `scenario`) into the simulator; perception may be down."""
        response = self.probe.call(self.load_client, LoadScenario.Request(
            scenario=str(scenario or self.scenario_path), seed=-1), timeout=60.0)
        assert response.success, response.message
        self.fresh_truth()

    def fresh_truth(self, timeout: float = 30.0) -> dict[str, Pose2D]:
        """True poses from a /sim/object_states message received after this call."""
        count = len(self.truth)
        assert self.probe.spin_until(lambda: len(self.truth) > count, timeout), \
            "no ground truth from the simulator"
        return {s.id: Pose2D(s.x, s.y, s.theta) for s in self.truth[-1].objects}

    def true_cost(self, poses: dict[str, Pose2D] | None = None) -> float:
        """The scenario's objective at the simulator's true poses (now, unless given)."""
        poses = poses if poses is not None else self.fresh_truth()
        state = np.array([poses[o.id].as_array() for o in self.scenario.objects])
        return float(self.objective.cost(state))

    def disturb(self, object_id: str, dx: float, dy: float, dtheta: float = 0.0) -> str:
        response = self._disturb(object_id, dx, dy, dtheta)
        assert response.success, response.message
        return response.message

    def _disturb(self, object_id: str, dx: float, dy: float,
                 dtheta: float = 0.0) -> DisturbObject.Response:
        return self.probe.call(self.disturb_client, DisturbObject.Request(
            object_id=object_id, dx=dx, dy=dy, dtheta=dtheta))

    def bump_an_idle_object(self, pushes_done: int, distance: float = 0.03) -> str:
        """Bump the object the push under way is not for (the step after `pushes_done` of the
        latest plan, valid until the first replan) `distance` along its length, as a knock on
        the table would; a bump of the pushed object would also be folded into its model.
        Forward along its length, or backward where forward would put it off the table (a plan
        had turned the remote 45 degrees near the far edge, and the simulator refused)."""
        steps = self.plans[-1].steps if self.plans else []
        busy = steps[min(pushes_done, len(steps) - 1)].object_id if steps else ""
        object_id = next(o.id for o in self.scenario.objects
                         if o.id != busy and o.shape == "box")
        theta = self.fresh_truth()[object_id].theta
        for along in (distance, -distance):
            response = self._disturb(object_id, along * np.cos(theta), along * np.sin(theta))
            if response.success:
                return response.message
        raise AssertionError(response.message)

    def wait_until_perceived(self, timeout: float = 60.0) -> tuple[dict, dict]:
        """Wait until perception's poses match ground truth (within 5 mm): after a bump or a
        restart. Returns (perceived, true) poses as (x, y, theta) arrays by id."""
        seen: list[ObjectStateArray] = []
        subscription = self.probe.create_subscription(
            ObjectStateArray, "/perception/objects", seen.append, 10)
        state: dict = {}

        def matches() -> bool:
            if not seen or len(self.truth) == 0:
                return False
            state["seen"] = {s.id: np.array([s.x, s.y, s.theta]) for s in seen[-1].objects}
            state["true"] = {s.id: np.array([s.x, s.y, s.theta]) for s in self.truth[-1].objects}
            return sorted(state["seen"]) == sorted(state["true"]) and all(
                np.hypot(*(state["seen"][k][:2] - state["true"][k][:2])) <= 0.005
                for k in state["true"])

        try:
            assert self.probe.spin_until(matches, timeout), \
                f"perception {state.get('seen')} never matched the truth {state.get('true')}"
        finally:
            self.probe.destroy_subscription(subscription)
        return state["seen"], state["true"]

    def set_sim_parameter(self, name: str, value: float) -> None:
        assert self.sim_parameter_client.wait_for_services(timeout_sec=30.0)
        future = self.sim_parameter_client.set_parameters([Parameter(name, value=value)])
        results = self.probe.wait_for(future).results
        assert results[0].successful, results[0].reason

    def joint_positions(self, timeout: float = 10.0) -> np.ndarray:
        """Arm joint positions from a /joint_states message received after this call
        (subscribed only then: at full simulation speed it is hundreds of messages a second)."""
        return np.array(self.probe.next_message(JointState, "/joint_states",
                                                timeout=timeout).position)

    # ------------------------------------------------------------------ tasks
    def send_task(self, goal: RunTask.Goal | None = None, feedback: list | None = None):
        """Send a RunTask goal; returns its (accepted) handle."""
        try:
            handle = self.probe.send_goal(self.run_client, goal or RunTask.Goal(), feedback)
        except AssertionError as error:   # no answer: what the nodes logged says why
            raise AssertionError(f"{error}\n{self.logs()}") from None
        assert handle.accepted, "RunTask rejected"
        return handle

    def wait_result(self, handle, timeout: float = TASK_TIMEOUT_S,
                    during: Callable[[], None] | None = None) -> tuple[int, RunTask.Result]:
        """(status, result) of a goal; `during` runs between spins while it is pending."""
        future = handle.get_result_async()
        deadline = time.monotonic() + timeout
        while not future.done():
            assert time.monotonic() < deadline, f"no result within {timeout} s:\n{self.logs()}"
            self.probe.spinner.spin_once(timeout_sec=0.05)
            if during is not None:
                during()
        wrapped = future.result()
        return wrapped.status, wrapped.result

    def run_task(self, goal: RunTask.Goal | None = None, feedback: list | None = None,
                 during: Callable[[], None] | None = None,
                 timeout: float = TASK_TIMEOUT_S) -> tuple[int, RunTask.Result]:
        return self.wait_result(self.send_task(goal, feedback), timeout, during)

    def spin_until(self, condition: Callable[[], bool], timeout: float = TASK_TIMEOUT_S) -> bool:
        return self.probe.spin_until(condition, timeout)


def describe(result: RunTask.Result) -> str:
    """One line for assertion messages: code, message and the figures of a RunTask result."""
    return (f"{RESULT_NAMES.get(result.error_code, result.error_code)} {result.error_msg!r}: "
            f"final {result.final_cost:.4f}, predicted {result.predicted_cost:.4f}, "
            f"pushes {result.pushes}, replans {result.replans}, "
            f"learning trials {result.learning_trials}")


def executed_pushes(feedback: list) -> int:
    """Pushes done so far according to a RunTask's feedback messages."""
    return max((message.feedback.pushes_done for message in feedback
                if message.feedback.phase != "learning"), default=0)
