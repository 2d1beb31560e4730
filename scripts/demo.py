"""The main job: bring the graph up, run a task end to end, write a report, shut down.

Run through scripts/demo.sh (which sets the machine up and sources scripts/env.sh):

    ./scripts/demo.sh --scenario clean --out out/demo [--record [DIR]]

`--record` also writes a rosbag2 of the run (default OUT/bag; scripts/record_bag.py's topics:
camera, perceived and true object states, joint states, plan, markers, clock).

The planner acts only on perception; this client also reads the simulator's ground truth
(/sim/object_states), but only to evaluate the result (final_cost_true in the report).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
import yaml
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from tsrrt_common.camera import OverheadCamera
from tsrrt_common.geometry import Pose2D
from tsrrt_common.processes import stop_process_group
from tsrrt_common.ros_node import ActionClient, seconds
from tsrrt_common.scenario import Scenario, load_scenario
from tsrrt_interfaces.action import RunTask
from tsrrt_interfaces.msg import ForwardModelArray, ObjectStateArray
from tsrrt_planner.lower_bound import relative_gap
from tsrrt_planner.model_learning import ForwardModel, ModelStore
from tsrrt_planner.objectives import Objective, build_objective
from tsrrt_planner.report_figures import (
    draw_visited_outlines,
    plot_cost,
    plot_models,
    save_rgb,
)

ROOT = Path(__file__).resolve().parent.parent
ERROR_NAMES = {value: name for name, value in vars(RunTask.Result).items()
               if name.isupper() and isinstance(value, int)}


class DemoClient(Node):
    """Watches the run: camera frames, ground truth, the planner's observations and models."""

    def __init__(self) -> None:
        super().__init__("tsrrt_demo")
        self.lock = threading.Lock()
        self.image: np.ndarray | None = None
        self.truth: ObjectStateArray | None = None
        self.observed: list[ObjectStateArray] = []
        self.models: ForwardModelArray | None = None
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.create_subscription(Image, "/camera/image_raw", self._on_image,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(ObjectStateArray, "/sim/object_states", self._on_truth, 10)
        self.create_subscription(ObjectStateArray, "/planner/observed", self._on_observed, 50)
        self.create_subscription(ForwardModelArray, "/planner/models", self._on_models, latched)
        self.run_task = ActionClient(self, RunTask, "/planner/run_task")

    def _on_image(self, message: Image) -> None:
        if message.encoding != "rgb8":
            return
        rows = np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.step)
        with self.lock:
            self.image = rows[:, :message.width * 3].reshape(message.height, message.width, 3)

    def _on_truth(self, message: ObjectStateArray) -> None:
        with self.lock:
            self.truth = message

    def _on_observed(self, message: ObjectStateArray) -> None:
        with self.lock:
            self.observed.append(message)

    def _on_models(self, message: ForwardModelArray) -> None:
        with self.lock:
            self.models = message

    def fresh_frame(self, timeout_s: float = 20.0) -> tuple[np.ndarray, ObjectStateArray]:
        """A camera frame and ground truth received after this call."""
        with self.lock:
            self.image, self.truth = None, None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if self.image is not None and self.truth is not None:
                    return self.image.copy(), self.truth
            time.sleep(0.05)
        raise TimeoutError("no camera frame and ground truth from the simulator")


def poses_of(message: ObjectStateArray) -> dict[str, Pose2D]:
    return {s.id: Pose2D(s.x, s.y, s.theta) for s in message.objects}


def store_from(message: ForwardModelArray | None) -> ModelStore:
    store = ModelStore()
    for m in message.models if message is not None else []:
        variance = np.array(m.variance)
        store.add(ForwardModel(m.object_id, m.primitive, m.nominal_push_length, m.samples,
                               np.array(m.mean), variance * m.samples), m.object_class)
    return store


def start_graph(scenario: str, seed: int, out: Path) -> subprocess.Popen:
    """bringup.sh with the learned models kept in the output directory (a fresh directory
    learns from scratch; running into the same one again reuses its models)."""
    return subprocess.Popen(
        [str(ROOT / "scripts" / "bringup.sh"), "--scenario", scenario, "--seed", str(seed),
         "--models", str(out / "models.yaml"), "--log-dir", str(out / "logs")],
        start_new_session=True)


def start_recorder(bag: Path, log_dir: Path) -> subprocess.Popen:
    """scripts/record_bag.py, started beside the graph: it subscribes to each topic as its node
    comes up. zstd-compressed MCAP, because camera frames are 0.9 MB each, 10 per second."""
    log_dir.mkdir(parents=True, exist_ok=True)
    with (log_dir / "record_bag.log").open("w") as log:
        return subprocess.Popen(
            [sys.executable, str(ROOT / "scripts" / "record_bag.py"), "-o", str(bag),
             "--compression", "zstd"],
            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def bag_summary(bag: Path) -> str:
    """Messages per topic, from the metadata.yaml the recorder writes when it closes the bag."""
    metadata = bag / "metadata.yaml"
    if not metadata.is_file():
        return f"no bag in {bag}: the recorder did not close it (see logs/record_bag.log)"
    info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
    counts = ", ".join(f"{t['topic_metadata']['name']} {t['message_count']}"
                       for t in info["topics_with_message_count"])
    return f"rosbag2 of the run in {bag} ({info['message_count']} messages: {counts})"


def stop_graph(process: subprocess.Popen) -> None:
    """SIGTERM to the process group (bringup.sh stops its nodes, the recorder closes its bag),
    SIGKILL after 20 s."""
    stop_process_group(process, signal.SIGTERM, grace_s=20.0)


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, args.seed if args.seed >= 0 else None)
    out = Path(args.out)
    bag = None if args.record is None else Path(args.record or out / "bag")
    if bag is not None and bag.exists():
        raise RuntimeError(f"{bag} exists and a bag is never overwritten; move it away or give "
                           "--record DIR")
    out.mkdir(parents=True, exist_ok=True)
    objective = build_objective(scenario)
    camera = OverheadCamera()
    began = time.monotonic()
    graph = start_graph(args.scenario, args.seed, out)
    recorder = None if bag is None else start_recorder(bag, out / "logs")
    rclpy.init()
    client = DemoClient()
    spinner = threading.Thread(target=rclpy.spin, args=(client,), daemon=True)
    spinner.start()
    try:
        print(f"[demo] {scenario.name}: waiting for the graph (logs in {out / 'logs'})")
        if not client.run_task.wait_for_server(timeout_sec=args.startup_timeout):
            raise RuntimeError("the planner's /planner/run_task did not come up; see the logs")
        initial_image, initial_truth = client.fresh_frame()
        sim_start = _stamp(initial_truth)
        goal = RunTask.Goal(planner=args.planner, planning_budget_s=args.budget_s)
        print(f"[demo] RunTask sent (planner {args.planner or 'default'})")
        result = _run_goal(client, goal, args.timeout)
        final_image, final_truth = client.fresh_frame()
        wall_s = time.monotonic() - began
        with client.lock:
            observed = [poses_of(m) for m in client.observed]
            models = store_from(client.models)
        report = _report(scenario, objective, result, initial_truth, final_truth,
                         wall_s, _stamp(final_truth) - sim_start)
        (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
        specs = scenario.objects
        height = scenario.table.height
        save_rgb(out / "initial.png", draw_visited_outlines(
            initial_image, camera, specs, observed[:1] or [poses_of(initial_truth)], height))
        save_rgb(out / "final.png", draw_visited_outlines(
            final_image, camera, specs, observed or [poses_of(final_truth)], height))
        if models.models:
            plot_models(models, [o.id for o in specs], out / "models.png")
        costs = [float(objective.cost(_state(scenario, p))) for p in observed]
        if costs:
            plot_cost(costs, report["lower_bound"], out / "cost.png", report["predicted_cost"])
        _print_summary(report, out)
        return 0 if report["success"] else 1
    finally:
        client.destroy_node()
        rclpy.try_shutdown()
        if recorder is not None:
            stop_graph(recorder)
            print(f"[demo] {bag_summary(bag)}")
        stop_graph(graph)


def _run_goal(client: DemoClient, goal: RunTask.Goal, timeout_s: float) -> RunTask.Result:
    last_line = [""]

    def feedback(message: Any) -> None:
        f = message.feedback
        if f.phase == "learning":
            line = f"[demo] learning   trials {f.pushes_done:3d}"
        else:
            line = (f"[demo] {f.phase:<10} pushes {f.pushes_done:3d}  replans {f.replans}  "
                    f"cost {f.current_cost:8.4f}  predicted {f.best_predicted_cost:8.4f}")
        if line != last_line[0]:
            print(line, flush=True)
            last_line[0] = line

    sent = client.run_task.send_goal_async(goal, feedback_callback=feedback)
    handle = _wait(sent, 30.0, "the planner did not answer the goal")
    if not handle.accepted:
        raise RuntimeError("the planner rejected the task")
    response = _wait(handle.get_result_async(), timeout_s, "the task took too long")
    return response.result


def _wait(future: rclpy.task.Future, timeout_s: float, message: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while not future.done():
        if time.monotonic() > deadline:
            raise TimeoutError(message)
        time.sleep(0.05)
    return future.result()


def _stamp(message: ObjectStateArray) -> float:
    return seconds(message.header.stamp)


def _state(scenario: Scenario, poses: dict[str, Pose2D]) -> np.ndarray:
    return np.array([poses[o.id].as_array() for o in scenario.objects])


def _report(scenario: Scenario, objective: Objective, result: RunTask.Result,
            initial: ObjectStateArray, final: ObjectStateArray, wall_s: float,
            sim_s: float) -> dict[str, Any]:
    true_final = poses_of(final)
    perceived = {s.id: Pose2D(s.x, s.y, s.theta) for s in result.final_objects}
    final_cost_true = float(objective.cost(_state(scenario, true_final)))
    bound = float(result.lower_bound)
    gap = relative_gap(final_cost_true, bound)
    return {
        "scenario": scenario.name,
        "success": result.error_code == RunTask.Result.SUCCESS,
        "error_code": ERROR_NAMES.get(result.error_code, str(result.error_code)),
        "error_msg": result.error_msg,
        "initial_cost_true": float(objective.cost(_state(scenario, poses_of(initial)))),
        "final_cost_true": final_cost_true,
        "final_cost_perceived": float(result.final_cost),
        "predicted_cost": float(result.predicted_cost),
        "lower_bound": bound,
        "gap": gap,
        "pushes": int(result.pushes),
        "replans": int(result.replans),
        "learning_trials": int(result.learning_trials),
        "planning_s": float(result.planning_s),
        "wall_s": wall_s,
        "sim_s": sim_s,
        "final_poses_true": {k: list(v.as_array()) for k, v in true_final.items()},
        "final_poses_perceived": {k: list(v.as_array()) for k, v in perceived.items()},
    }


def _print_summary(report: dict[str, Any], out: Path) -> None:
    verdict = "succeeded" if report["success"] else f"failed ({report['error_code']})"
    gap = "n/a" if report["gap"] is None else f"{100 * report['gap']:.1f} %"
    print(f"[demo] task {verdict}: true cost {report['initial_cost_true']:.4f} -> "
          f"{report['final_cost_true']:.4f} (lower bound {report['lower_bound']:.4f}, gap {gap})"
          f", {report['pushes']} pushes, {report['replans']} replans, "
          f"{report['learning_trials']} learning trials, {report['wall_s']:.0f} s wall")
    print(f"[demo] report and pictures in {out}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="clean", help="shipped scenario name or path")
    parser.add_argument("--out", default="out/demo", help="directory for the report")
    parser.add_argument("--seed", type=int, default=-1, help="placement seed (-1: the file's)")
    parser.add_argument("--planner", default="", help="tsrrt | paper | paper-nogd | greedy")
    parser.add_argument("--budget-s", type=float, default=0.0, help="planning time per plan")
    parser.add_argument("--timeout", type=float, default=1800.0, help="task timeout, s")
    parser.add_argument("--startup-timeout", type=float, default=90.0)
    parser.add_argument("--record", nargs="?", const="", default=None, metavar="DIR",
                        help="write a rosbag2 of the run to DIR (default OUT/bag)")
    args = parser.parse_args(argv)
    if args.scenario and Path(args.scenario).is_file():
        args.scenario = str(Path(args.scenario).resolve())
    try:
        return run(args)
    except (RuntimeError, TimeoutError) as error:
        print(f"[demo] error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
