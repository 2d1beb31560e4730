"""Benchmark of primitive execution: planning time, tool tracking, wall time, displacements.

    python -m tsrrt_executor.bench --json PATH [--trials 5] [--scenarios clean tset3] [--logs DIR]

Runs each primitive on each object class of the scenarios (>= 5 trials each) and prints the
numbers issue 5 asks for; the JSON has keys ik_ms_per_primitive, tracking_rms_mm,
tracking_max_mm, wall_s_per_primitive, displacements[class][primitive] = {mean, std} with
[dx, dy, dtheta] in the object frame (metres, radians) -- the raw material of the paper's Fig. 3.

Each trial puts one object of the class alone on the table at BENCH_CENTRE with a seeded random
offset (+-2 cm, heading +-0.3 rad), so that trials differ the way learning pushes do; both parts
below use the same poses. BENCH_CENTRE is 5 cm beyond the table centre: at the centre (0.45, 0)
primitive 1 on the remote (0.18 m long) approaches from x = 0.33, at the near edge of the
reachable workspace.

What is measured through what (also written into the JSON under "measured_through"):
1. Core, no ROS (this process): primitive_plan.plan_primitive from OBSERVE_POSTURE, then the
   trajectory on tsrrt_sim.world.SimWorld (PyBullet + the sim's computed-torque controller).
   - ik_ms_per_primitive: wall time of plan_primitive (reachability and clearance checks, IK,
     time parameterisation, joint-move checks) per primitive.
   - tracking_*: ball-centre error |FK(desired q) - FK(measured q)| at every physics step of the
     push segment (in contact), sampled like the controller does (before each step).
   - core_wall_s_per_primitive: planning + simulating the trajectory at full speed.
2. Through the ROS graph: this module starts sim_node (full speed), perception_node and
   executor_node as processes with their parameter files on a ROS domain of their own, loads a
   one-object scenario per class with /sim/load_scenario, moves the object to each trial's pose
   with /sim/disturb_object (in steps perception follows), waits until perception has settled,
   and sends ExecutePrimitive.
   - wall_s_per_primitive: from sending the goal to its result: the settled observation before,
     planning, the motion out of and back to OBSERVE_POSTURE, the settled observation after.
   - displacements: from the result, i.e. perception's settled observations before and after.
   - displacements_ground_truth: the same pushes measured on /sim/object_states at the stamps
     of those two observations (rotated into perception's object frame); the std of the
     difference (perception_error_std) is perception's share of the spread.
   - node_ik_ms_per_primitive: the result's ik_ms, planning inside the node while the sim,
     renderer and perception share the machine's cores.
A trial whose goal fails is counted under "failures" with its error code and message.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import rclpy
import yaml
from ament_index_python.packages import get_package_share_directory
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

from tsrrt_common.geometry import Pose2D, wrap_angle
from tsrrt_common.processes import stop_process_group
from tsrrt_common.scenario import ObjectSpec, Scenario, load_scenario
from tsrrt_executor.errors import ExecutorError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.primitive_plan import PrimitivePlan, TableObject, plan_primitive
from tsrrt_executor.push_primitives import DEFAULT_PUSH_LENGTH, primitives_for
from tsrrt_interfaces.action import ExecutePrimitive
from tsrrt_interfaces.msg import ObjectStateArray
from tsrrt_interfaces.srv import DisturbObject, GetSettledObjects, LoadScenario

SETTLE_S = 0.5
BENCH_CENTRE = (0.50, 0.0)
# Where a class's object is shown first, away from the bench centre: perception must see the
# previous class's object gone before trials start. Placed where that object was, a taller
# object would look like something covering it, and perception would keep waiting for it.
STAGING_POSE = Pose2D(0.52, 0.19, 0.0)
# Between trials the object is moved to its next pose with /sim/disturb_object in steps that
# perception follows (its gate for a tracked object is 5 cm), so that it keeps one identity: a
# teleported object gets a new track, and several tracks of one class can swap identities when
# perception later recovers the object after the arm has hidden it.
MOVE_STEP = 0.03            # metres
MOVE_STEP_TURN = 0.3        # radians
POSITION_JITTER = 0.02
HEADING_JITTER = 0.3
NODES = (("tsrrt_sim", "sim_node"), ("tsrrt_perception", "perception_node"),
         ("tsrrt_executor", "executor_node"))
GOAL_TIMEOUT_S = 120.0
RESULT_CODES = {0: "SUCCESS", 1: "UNKNOWN_OBJECT", 2: "UNREACHABLE", 3: "IK_FAILED",
                4: "TRACKING_FAILED", 5: "OBJECT_LOST", 6: "CANCELED", 7: "INVALID_GOAL",
                8: "CONTROLLER_UNAVAILABLE"}


@dataclasses.dataclass(frozen=True)
class Trial:
    """One push: which object class (its scenario spec), which primitive, where."""

    spec: ObjectSpec
    table: Scenario
    primitive: int
    pose: Pose2D


def first_object_of_each_class(scenario: Scenario) -> list[ObjectSpec]:
    seen: dict[str, ObjectSpec] = {}
    for spec in scenario.objects:
        seen.setdefault(spec.object_class, spec)
    return list(seen.values())


def make_trials(scenario_names: list[str], trials: int, seed: int) -> list[Trial]:
    rng = np.random.default_rng(seed)
    result = []
    for name in scenario_names:
        scenario = load_scenario(name)
        if not scenario.table.bounds[0] < BENCH_CENTRE[0] < scenario.table.bounds[2]:
            raise ExecutorError(f"scenario {name!r}: bench centre {BENCH_CENTRE} is off the table")
        for spec in first_object_of_each_class(scenario):
            for primitive in primitives_for(spec.shape):
                for _ in range(trials):
                    pose = Pose2D(
                        BENCH_CENTRE[0] + rng.uniform(-POSITION_JITTER, POSITION_JITTER),
                        BENCH_CENTRE[1] + rng.uniform(-POSITION_JITTER, POSITION_JITTER),
                        rng.uniform(-HEADING_JITTER, HEADING_JITTER))
                    result.append(Trial(spec, scenario, primitive, pose))
    return result


def one_object_scenario(trial: Trial) -> Scenario:
    return dataclasses.replace(trial.table, objects=(dataclasses.replace(trial.spec,
                                                                         pose=trial.pose),),
                               obstacles=())


def one_object_document(trial: Trial) -> dict:
    """The scenario file of a trial: the scenario's table, the object alone at its pose."""
    table, spec, pose = trial.table.table, trial.spec, trial.pose
    return {
        "format": 1, "name": f"bench_{spec.object_class}",
        "description": "executor benchmark: one object at the bench centre",
        "table": {"center": list(table.center), "size": list(table.size),
                  "height": table.height, "friction": table.friction},
        "objects": [{"id": spec.id, "class": spec.object_class, "mass": spec.mass,
                     "friction": spec.friction, "color": list(spec.color),
                     "pose": [pose.x, pose.y, pose.theta]}],
        "objective": {"terms": [{"type": "distance_to_point", "weight": 1.0,
                                 "point": "table_center"}]},
    }


# ----------------------------------------------------------------------------- 1. the core
def run_core_trial(world, ik: PusherIK, trial: Trial, push_length: float) -> dict:
    """One push on the object alone, planned and simulated in this process."""
    from tsrrt_sim.trajectory_controller import JointTrajectory

    world.load_scenario(one_object_scenario(trial))
    world.settle(0.2)
    spec = trial.spec
    before = world.object_poses()[spec.id]
    wall_start = time.perf_counter()
    target = TableObject(spec.id, spec.shape, spec.length, spec.width, spec.height, before)
    plan: PrimitivePlan = plan_primitive(ik, target, [], trial.primitive, push_length,
                                         world.joint_state().positions)
    trajectory = plan.trajectory
    execution = world.controller.start(
        JointTrajectory(trajectory.times, trajectory.positions, trajectory.velocities,
                        trajectory.accelerations), world.controller.default_tolerances,
        world.sim_time, world.sim_time)
    start_time = world.sim_time
    push_times = trajectory.times[np.array([s == "push" for s in trajectory.segment_names])]
    push_window = (push_times[0] + start_time, push_times[-1] + start_time)
    errors = []
    while not execution.done:
        if push_window[0] <= world.sim_time <= push_window[1]:
            desired = execution.sample(world.sim_time).positions
            errors.append(np.linalg.norm(ik.tool_position(desired)
                                         - ik.tool_position(world.joint_state().positions)))
        world.step()
    world.settle(SETTLE_S)
    return {"planning_ms": plan.planning_ms, "wall_s": time.perf_counter() - wall_start,
            "sim_s": trajectory.duration, "errors": np.array(errors),
            "succeeded": execution.error_code == 0,
            "controller_message": execution.error_string}


def run_core(trials: list[Trial], push_length: float, log: Callable[[str], None]) -> dict:
    from tsrrt_sim.world import SimWorld

    ik = PusherIK()
    planning_ms, walls, sims, errors = [], [], [], []
    failures: list[str] = []
    world = SimWorld(one_object_scenario(trials[0]))
    try:
        for index, trial in enumerate(trials):
            label = f"{trial.spec.object_class} p{trial.primitive}"
            try:
                outcome = run_core_trial(world, ik, trial, push_length)
            except ExecutorError as error:
                failures.append(f"{label}: {error}")
                continue
            if not outcome["succeeded"]:
                failures.append(f"{label}: controller: {outcome['controller_message']}")
            planning_ms.append(outcome["planning_ms"])
            walls.append(outcome["wall_s"])
            sims.append(outcome["sim_s"])
            errors.append(outcome["errors"])
            if (index + 1) % 20 == 0:
                log(f"core: {index + 1}/{len(trials)} trials")
    finally:
        world.close()
    push_errors = np.concatenate(errors)
    return {
        "ik_ms_per_primitive": float(np.mean(planning_ms)),
        "ik_ms_per_primitive_median": float(np.median(planning_ms)),
        "ik_ms_per_primitive_max": float(np.max(planning_ms)),
        "tracking_rms_mm": float(np.sqrt(np.mean(push_errors ** 2)) * 1000.0),
        "tracking_max_mm": float(push_errors.max() * 1000.0),
        "core_wall_s_per_primitive": float(np.mean(walls)),
        "sim_s_per_primitive": float(np.mean(sims)),
        "core_failures": failures,
    }


# ------------------------------------------------------------------------ 2. the ROS graph
class GraphSession:
    """The three nodes as processes on a private ROS domain, and a client node in this one."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        domain = os.environ.get("TSRRT_BENCH_DOMAIN_ID") or str(random.randint(1, 101))
        self.env = dict(os.environ, ROS_DOMAIN_ID=domain,
                        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        self.processes: list[subprocess.Popen] = []
        self.context = None
        self.node = None

    def __enter__(self) -> GraphSession:
        try:
            for package, node in NODES:
                params = Path(get_package_share_directory(package)) / "config" / f"{node}.yaml"
                with (self.log_dir / f"{node}.log").open("w") as log:
                    self.processes.append(subprocess.Popen(
                        [sys.executable, "-m", f"{package}.{node}", "--ros-args",
                         "--params-file", str(params)], env=self.env, stdout=log,
                        stderr=subprocess.STDOUT, start_new_session=True))
            self.context = rclpy.Context()
            rclpy.init(context=self.context, domain_id=int(self.env["ROS_DOMAIN_ID"]))
            self.node = rclpy.create_node("executor_bench", context=self.context)
            self.spinner = SingleThreadedExecutor(context=self.context)
            self.spinner.add_node(self.node)
            reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
            self.perceived: list = []
            self.truth_by_stamp: dict[int, object] = {}
            self.node.create_subscription(ObjectStateArray, "/perception/objects",
                                          self._on_perceived, reliable)
            self.node.create_subscription(ObjectStateArray, "/sim/object_states",
                                          self._on_truth, reliable)
            self.load_client = self.node.create_client(LoadScenario, "/sim/load_scenario")
            self.disturb_client = self.node.create_client(DisturbObject, "/sim/disturb_object")
            self.settled_client = self.node.create_client(GetSettledObjects,
                                                          "/perception/get_settled_objects")
            self.action = ActionClient(self.node, ExecutePrimitive,
                                       "/executor/execute_primitive")
            if not self.action.wait_for_server(timeout_sec=60.0):
                raise ExecutorError(f"the executor did not come up; logs in {self.log_dir}")
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *_exc) -> None:
        if self.node is not None:
            self.spinner.shutdown()
            self.node.destroy_node()
        if self.context is not None:
            rclpy.shutdown(context=self.context)
        for process in reversed(self.processes):
            stop_process_group(process)

    def _on_perceived(self, message) -> None:
        self.perceived[:] = [message]

    def _on_truth(self, message) -> None:
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        self.truth_by_stamp[stamp] = message
        while len(self.truth_by_stamp) > 500:
            del self.truth_by_stamp[min(self.truth_by_stamp)]

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.spinner.spin_once(timeout_sec=0.01)
            if condition():
                return True
        return False

    def wait(self, future, timeout: float, what: str):
        if not self.spin_until(future.done, timeout):
            raise ExecutorError(f"no answer from {what} within {timeout} s")
        return future.result()

    def load(self, path: Path) -> None:
        if not self.load_client.wait_for_service(timeout_sec=30.0):
            raise ExecutorError("/sim/load_scenario is not available")
        answer = self.wait(self.load_client.call_async(
            LoadScenario.Request(scenario=str(path), seed=-1)), 60.0, "/sim/load_scenario")
        if not answer.success:
            raise ExecutorError(f"/sim/load_scenario: {answer.message}")

    def tracked_id(self, object_class: str, pose: Pose2D, timeout: float = 30.0) -> str:
        """Id under which perception tracks an object of the class within 1 cm of `pose`."""
        def find():
            return next((o.id for o in (self.perceived[0].objects if self.perceived else [])
                         if o.status == 0 and o.object_class == object_class
                         and math.hypot(o.x - pose.x, o.y - pose.y) < 0.01), None)

        if not self.spin_until(lambda: find() is not None, timeout):
            raise ExecutorError(f"perception does not see the {object_class} at {pose}")
        return find()

    def true_pose(self, object_id: str) -> Pose2D:
        """The object's latest ground-truth pose (theta continuous, as the sim publishes it)."""
        if not self.spin_until(lambda: bool(self.truth_by_stamp), 30.0):
            raise ExecutorError("no /sim/object_states")
        state = next((o for o in self.truth_by_stamp[max(self.truth_by_stamp)].objects
                      if o.id == object_id), None)
        if state is None:
            raise ExecutorError(f"{object_id!r} is not in /sim/object_states")
        return Pose2D(state.x, state.y, state.theta)

    def move_object(self, sim_id: str, object_class: str, target: Pose2D) -> None:
        """Move the object to `target` in steps perception follows.

        An object pushed partly over the table's edge (the remote, 18 cm long, pushed 5 cm from
        the bench centre) cannot be moved by a short step, which would leave it partly off the
        table: it then jumps to `target` at once (and may get a new track).
        """
        start = self.true_pose(sim_id)
        turn = float(wrap_angle(target.theta - start.theta))
        steps = max(1, math.ceil(max(math.hypot(target.x - start.x, target.y - start.y)
                                     / MOVE_STEP, abs(turn) / MOVE_STEP_TURN)))
        step = np.array([target.x - start.x, target.y - start.y, turn]) / steps
        if not self.disturb_client.wait_for_service(timeout_sec=30.0):
            raise ExecutorError("/sim/disturb_object is not available")
        done = 0
        while done < steps:
            answer = self.disturb(sim_id, step)
            if not answer.success and "off the table" in answer.message:
                answer = self.disturb(sim_id, step * (steps - done))
                done = steps - 1
            if not answer.success:
                raise ExecutorError(f"/sim/disturb_object: {answer.message}")
            done += 1
            self.tracked_id(object_class, Pose2D(start.x + done * step[0],
                                                 start.y + done * step[1], 0.0))

    def disturb(self, sim_id: str, offset: np.ndarray):
        return self.wait(self.disturb_client.call_async(DisturbObject.Request(
            object_id=sim_id, dx=float(offset[0]), dy=float(offset[1]),
            dtheta=float(offset[2]))), 30.0, "/sim/disturb_object")

    def settle(self, timeout: float = 30.0) -> list:
        """Perception's next settled observation (its object states)."""
        answer = self.wait(self.settled_client.call_async(GetSettledObjects.Request(
            timeout_s=timeout)), timeout + 10.0, "/perception/get_settled_objects")
        if not answer.success:
            raise ExecutorError(f"perception did not settle: {answer.message}")
        return list(answer.objects.objects)

    def execute(self, object_id: str, primitive: int, push_length: float):
        """Send a goal; returns its result and the wall seconds from sending to the result."""
        goal = ExecutePrimitive.Goal(object_id=object_id, primitive=primitive,
                                     push_length=push_length)
        start = time.perf_counter()
        handle = self.wait(self.action.send_goal_async(goal), 30.0, "the executor")
        if not handle.accepted:
            raise ExecutorError("the executor rejected the goal")
        outcome = self.wait(handle.get_result_async(), GOAL_TIMEOUT_S, "the executor")
        return outcome.result, time.perf_counter() - start

    def truth_at(self, stamp, object_id: str):
        """Ground truth of the object in the frame perception saw at `stamp` (or None)."""
        key = stamp.sec * 1_000_000_000 + stamp.nanosec
        self.spin_until(lambda: key in self.truth_by_stamp, 2.0)
        message = self.truth_by_stamp.get(key)
        if message is None:
            return None
        return next((o for o in message.objects if o.id == object_id), None)


def settled_id(states: list, object_class: str, pose: Pose2D) -> str:
    """Id of the tracked object of the class within 1 cm of `pose` in a settled observation."""
    for state in states:
        if (state.status == 0 and state.object_class == object_class
                and math.hypot(state.x - pose.x, state.y - pose.y) < 0.01):
            return state.id
    raise ExecutorError(f"no tracked {object_class} at ({pose.x:.3f}, {pose.y:.3f}) in the "
                        "settled observation")


def ground_truth_displacement(before_state, true_before, true_after, shape: str) -> np.ndarray:
    """True displacement in perception's object frame at `before_state` (dx, dy, dtheta).

    Perception's heading of a box may differ from the simulator's by pi (symmetry), and a disc
    has no observable heading (0 rotation reported), so the frame is perception's own.
    """
    c, s = math.cos(before_state.theta), math.sin(before_state.theta)
    dx, dy = true_after.x - true_before.x, true_after.y - true_before.y
    turn = 0.0 if shape == "cylinder" else float(wrap_angle(true_after.theta - true_before.theta))
    return np.array([c * dx + s * dy, -s * dx + c * dy, turn])


def run_graph(trials: list[Trial], push_length: float, log: Callable[[str], None],
              log_dir: Path | None = None) -> dict:
    """The graph part; the nodes' output goes to log_dir (kept) or a temporary directory."""
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
        return _run_graph(trials, push_length, log, log_dir)
    with tempfile.TemporaryDirectory(prefix="executor_bench_") as tmp:
        return _run_graph(trials, push_length, log, Path(tmp))


def _run_graph(trials: list[Trial], push_length: float, log: Callable[[str], None],
               log_dir: Path) -> dict:
    walls, node_ik_ms, whole_rms, sim_spans = [], [], [], []
    perceived: dict[tuple[str, int], list[np.ndarray]] = {}
    true: dict[tuple[str, int], list[np.ndarray]] = {}
    perception_errors: dict[tuple[str, int], list[np.ndarray]] = {}
    failures: list[str] = []
    scenario_file = log_dir / "bench_scenario.yaml"
    with GraphSession(log_dir) as graph:
        shown_class = None
        for index, trial in enumerate(trials):
            key = (trial.spec.object_class, trial.primitive)
            label = f"{key[0]} p{key[1]}"
            try:
                if trial.spec.object_class != shown_class:
                    staging = dataclasses.replace(trial, pose=STAGING_POSE)
                    scenario_file.write_text(yaml.safe_dump(one_object_document(staging)))
                    graph.load(scenario_file)
                    graph.tracked_id(trial.spec.object_class, STAGING_POSE)
                    graph.settle()
                    shown_class = trial.spec.object_class
                graph.move_object(trial.spec.id, trial.spec.object_class, trial.pose)
                # The id from the settled observation: perception may have renamed the object
                # while it moved (a new track, the old one lost).
                object_id = settled_id(graph.settle(), trial.spec.object_class, trial.pose)
            except ExecutorError as error:
                failures.append(f"{label}: setting up the trial: {error}")
                continue
            result, wall = graph.execute(object_id, trial.primitive, push_length)
            if result.error_code != 0:
                failures.append(f"{label}: {RESULT_CODES.get(result.error_code)} "
                                f"{result.error_msg}")
                continue
            walls.append(wall)
            node_ik_ms.append(result.ik_ms)
            whole_rms.append(result.tool_rms_error)
            perceived.setdefault(key, []).append(np.array(result.displacement))
            sim_spans.append((result.after.last_seen.sec - result.before.last_seen.sec)
                             + (result.after.last_seen.nanosec
                                - result.before.last_seen.nanosec) * 1e-9)
            true_before = graph.truth_at(result.before.last_seen, trial.spec.id)
            true_after = graph.truth_at(result.after.last_seen, trial.spec.id)
            if true_before is not None and true_after is not None:
                truth = ground_truth_displacement(result.before, true_before, true_after,
                                                  trial.spec.shape)
                true.setdefault(key, []).append(truth)
                perception_errors.setdefault(key, []).append(
                    np.array(result.displacement) - truth)
            if (index + 1) % 10 == 0:
                log(f"graph: {index + 1}/{len(trials)} trials, last {label} "
                    f"{wall:.2f} s wall")
    return {
        "wall_s_per_primitive": float(np.mean(walls)),
        "wall_s_per_primitive_median": float(np.median(walls)),
        "wall_s_per_primitive_max": float(np.max(walls)),
        "sim_s_between_observations": float(np.mean(sim_spans)),
        "node_ik_ms_per_primitive": float(np.mean(node_ik_ms)),
        "node_ik_ms_per_primitive_max": float(np.max(node_ik_ms)),
        "graph_tracking_rms_mm_whole_trajectory": float(
            np.sqrt(np.mean(np.square(whole_rms))) * 1000.0),
        "failures": failures,
        "displacements": statistics(perceived),
        "displacements_ground_truth": statistics(true),
        "perception_error_std": {
            object_class: {primitive: stats["std"] for primitive, stats in per_primitive.items()}
            for object_class, per_primitive in statistics(perception_errors).items()},
        "ground_truth_missing": sum(len(v) for v in perceived.values())
                                - sum(len(v) for v in true.values()),
    }


def statistics(samples: dict[tuple[str, int], list[np.ndarray]]) -> dict:
    """{class: {primitive: {mean, std, trials}}} for keys with at least two samples."""
    table: dict[str, dict[str, dict]] = {}
    for (object_class, primitive), values in samples.items():
        if len(values) < 2:
            continue
        values = np.array(values)
        table.setdefault(object_class, {})[str(primitive)] = {
            "mean": values.mean(axis=0).round(5).tolist(),
            "std": values.std(axis=0, ddof=1).round(5).tolist(),
            "trials": len(values),
        }
    return table


# ------------------------------------------------------------------------------- report
def print_report(report: dict) -> None:
    for part, text in report["measured_through"].items():
        print(f"[{part}] {text}")
    print(f"IK + trajectory per primitive (core): {report['ik_ms_per_primitive']:.1f} ms mean, "
          f"{report['ik_ms_per_primitive_median']:.1f} ms median, "
          f"{report['ik_ms_per_primitive_max']:.1f} ms max (the first loads the reachability "
          "grid; target <= 20 ms)")
    print(f"  ... inside executor_node, sharing the cores with sim and perception: "
          f"{report['node_ik_ms_per_primitive']:.1f} ms mean, "
          f"{report['node_ik_ms_per_primitive_max']:.1f} ms max")
    print(f"tool tracking during the push (core): {report['tracking_rms_mm']:.3f} mm RMS, "
          f"{report['tracking_max_mm']:.3f} mm max (target <= 1 mm RMS); over whole "
          f"trajectories through the graph: "
          f"{report['graph_tracking_rms_mm_whole_trajectory']:.3f} mm RMS")
    print(f"wall per primitive through the ROS graph (sim at full speed): "
          f"{report['wall_s_per_primitive']:.2f} s mean, "
          f"{report['wall_s_per_primitive_median']:.2f} s median, "
          f"{report['wall_s_per_primitive_max']:.2f} s max (target <= 0.5 s); "
          f"{report['sim_s_between_observations']:.1f} s simulated between the two "
          f"observations, of which {report['sim_s_per_primitive']:.1f} s trajectory")
    print(f"  ... core only (plan + simulate, no ROS): "
          f"{report['core_wall_s_per_primitive']:.2f} s")
    for key in ("failures", "core_failures"):
        if report[key]:
            print(f"{key.replace('_', ' ')} ({len(report[key])}):")
            for line in report[key]:
                print(f"  {line}")
    print("displacement in the object frame over the trials: perception (settled observations) "
          "mean +- std | ground-truth std | std of perception's error; dx, dy [mm], "
          "dtheta [deg]")
    truth = report["displacements_ground_truth"]
    errors = report["perception_error_std"]
    for object_class, per_primitive in report["displacements"].items():
        for primitive, stats in per_primitive.items():
            mean, std = stats["mean"], stats["std"]
            true_std = truth.get(object_class, {}).get(primitive, {}).get("std")
            error_std = errors.get(object_class, {}).get(primitive)
            line = (f"  {object_class:8s} {primitive}: dx {mean[0] * 1000:6.1f} +- "
                    f"{std[0] * 1000:4.1f}  dy {mean[1] * 1000:6.1f} +- {std[1] * 1000:4.1f}  "
                    f"dth {math.degrees(mean[2]):6.1f} +- {math.degrees(std[2]):4.1f}")
            if true_std is not None:
                line += (f" | truth std {true_std[0] * 1000:4.1f} {true_std[1] * 1000:4.1f} "
                         f"{math.degrees(true_std[2]):4.1f}")
            if error_std is not None:
                line += (f" | perception {error_std[0] * 1000:3.1f} {error_std[1] * 1000:3.1f} "
                         f"{math.degrees(error_std[2]):3.1f}")
            print(line + f"  (n={stats['trials']})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Benchmark of tsrrt_executor's primitives.")
    parser.add_argument("--json", type=Path, help="write the numbers to this JSON file")
    parser.add_argument("--trials", type=int, default=5, help="trials per (class, primitive)")
    parser.add_argument("--scenarios", nargs="+", default=["clean", "tset3"])
    parser.add_argument("--push-length", type=float, default=DEFAULT_PUSH_LENGTH)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--logs", type=Path,
                        help="keep the nodes' output in this directory (default: discarded)")
    args = parser.parse_args(argv)
    if args.trials < 2:
        parser.error("--trials must be at least 2 (a standard deviation is reported)")

    def log(text: str) -> None:
        print(f"[bench] {text}", file=sys.stderr, flush=True)

    # A terminated benchmark still stops the nodes it started (GraphSession.__exit__).
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    trials = make_trials(args.scenarios, args.trials, args.seed)
    log(f"{len(trials)} trials; core part (no ROS)")
    report: dict = {
        "measured_through": {
            "core": "plan_primitive + tsrrt_sim.world.SimWorld in this process, no ROS: "
                    "ik_ms_per_primitive, tracking_*, core_wall_s_per_primitive",
            "graph": "sim_node (full speed) + perception_node + executor_node processes, "
                     "ExecutePrimitive goals: wall_s_per_primitive, displacements (perception's "
                     "settled observations), displacements_ground_truth (/sim/object_states at "
                     "the same stamps), node_ik_ms_per_primitive",
        },
        "scenarios": args.scenarios,
        "trials_per_primitive": args.trials,
        "push_length": args.push_length,
    }
    report.update(run_core(trials, args.push_length, log))
    log("graph part: starting sim_node, perception_node, executor_node")
    report.update(run_graph(trials, args.push_length, log, args.logs))
    print_report(report)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
