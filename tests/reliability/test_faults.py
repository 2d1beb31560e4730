"""Faults while the graph runs a task (issue 7): nodes killed, stopped and restarted, camera
frames lost, objects bumped, a task cancelled mid-push, an object out of reach.

One graph for the module: sim, perception, executor and planner on tests/data/two_boxes.yaml
with its models learned beforehand (tests/task_graph.py), reset to the scenario's start through
/sim/load_scenario where a test needs work to do. Outcomes are judged on the simulator's ground
truth. The tests run in file order and each leaves the graph running for the next; the one that
switches to the out-of-reach scenario comes last. Figures (durations, pushes, replans, costs)
are printed for docs/reliability.md ("Faults"); run with -s to see them.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator

import numpy as np
import pytest

pytestmark = pytest.mark.integration

rclpy = pytest.importorskip("rclpy")
from action_msgs.msg import GoalStatus  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo  # noqa: E402
from task_graph import DATA, TaskGraph, describe, executed_pushes  # noqa: E402

from tsrrt_common.robot_model import OBSERVE_POSTURE  # noqa: E402
from tsrrt_interfaces.action import ExecutePrimitive, PlanTask, RunTask  # noqa: E402
from tsrrt_interfaces.msg import ObjectStateArray  # noqa: E402

OBSERVE_TOLERANCE = 0.05        # rad per joint: the controller's goal tolerance is 0.01
POSE_TOLERANCE = 0.005          # m: perception is within a millimetre of ground truth
ANGLE_TOLERANCE = 0.05          # rad
FAILURE_TIMEOUT_S = 120.0       # a goal that must fail has this long to say so (never hang)
Feedback = ExecutePrimitive.Feedback


@pytest.fixture(scope="module")
def graph(launch, graph_probe, tmp_path_factory) -> TaskGraph:
    return TaskGraph(launch, graph_probe, tmp_path_factory.mktemp("faults")).start()


@pytest.fixture
def figures(graph: TaskGraph) -> Iterator[dict]:
    """What a test measured, printed at its end (for docs/reliability.md)."""
    measured: dict = {}
    began = time.monotonic()
    yield measured
    measured["wall_s"] = round(time.monotonic() - began, 1)
    print(f"\nFIGURES {measured}")


def run_to_success(graph: TaskGraph, figures: dict, must_improve: bool = True,
                   **run) -> RunTask.Result:
    """A RunTask from the current state that must succeed and (unless the state may already be
    converged) lower the true cost."""
    start_cost = graph.true_cost()
    status, result = graph.run_task(RunTask.Goal(), **run)
    final_cost = graph.true_cost()
    summary = f"{describe(result)}; true cost {start_cost:.4f} -> {final_cost:.4f}"
    figures.update(pushes=result.pushes, replans=result.replans,
                   true_cost=(round(start_cost, 4), round(final_cost, 4)))
    assert status == GoalStatus.STATUS_SUCCEEDED, f"{summary}\n{graph.logs()}"
    assert result.error_code == RunTask.Result.SUCCESS, summary
    assert final_cost < start_cost or not must_improve, summary
    return result


def test_executor_down_ends_the_task_with_executor_unavailable(graph: TaskGraph, figures):
    graph.reset()
    graph.processes["executor_node"].stop_cleanly()
    began = time.monotonic()
    status, result = graph.run_task(RunTask.Goal(), timeout=FAILURE_TIMEOUT_S)
    figures["seconds_to_the_error"] = round(time.monotonic() - began, 1)
    figures["error"] = describe(result)
    assert status == GoalStatus.STATUS_ABORTED, describe(result)
    assert result.error_code == RunTask.Result.EXECUTOR_UNAVAILABLE, describe(result)
    assert "executor" in result.error_msg and result.pushes == 0, describe(result)
    graph.start_executor()
    graph.wait_ready()


def test_planner_killed_mid_task_resumes_with_its_models(graph: TaskGraph, figures):
    graph.reset()
    start_cost = graph.true_cost()
    feedback: list = []
    graph.send_task(feedback=feedback)
    assert graph.spin_until(lambda: executed_pushes(feedback) >= 1), "no push was executed"
    assert graph.processes["planner_node"].stop(signal.SIGKILL) == -signal.SIGKILL
    figures["pushes_before_the_kill"] = executed_pushes(feedback)
    began = time.monotonic()
    planner = graph.start_planner()
    assert planner.wait_for_log("(12 loaded)", timeout=120.0), planner.log()
    # The old server's endpoints linger in discovery; the new one must answer.
    graph.probe.handshake(graph.run_client, RunTask.Goal)
    figures["restart_s"] = round(time.monotonic() - began, 1)
    # The killed planner's pushes may have finished the plan before the kill took effect, and
    # a converged state is then rightly left alone: what counts is the task's start.
    result = run_to_success(graph, figures, must_improve=False)
    figures["true_cost"] = (round(start_cost, 4), figures["true_cost"][1])
    assert result.learning_trials == 0, describe(result)
    assert graph.true_cost() < start_cost


def test_cancel_mid_push_stops_the_arm_in_the_observe_posture(graph: TaskGraph, figures):
    graph.reset()
    phases = graph.probe.record(ExecutePrimitive.Impl.FeedbackMessage,
                                "/executor/execute_primitive/_action/feedback",
                                transform=lambda m: m.feedback.phase)
    feedback: list = []
    handle = graph.send_task(feedback=feedback)
    cancelled: list = []

    def cancel_once_pushing() -> None:
        # in a push after the first, so the result has pushes to report
        if executed_pushes(feedback) >= 1 and phases[-1:] == [Feedback.PHASE_PUSH] and (
                not cancelled):
            cancelled.append(handle.cancel_goal_async())

    status, result = graph.wait_result(handle, during=cancel_once_pushing)
    assert cancelled, "no push was seen"
    assert status == GoalStatus.STATUS_CANCELED, describe(result)
    assert result.error_code == RunTask.Result.CANCELED, describe(result)
    # what was done before the cancel is reported, not lost with the cancelled push
    assert result.pushes >= 1 and result.final_objects, describe(result)
    # The executor retreats before it answers the cancel, and the planner waits for that.
    error = np.abs(graph.joint_positions() - np.array(OBSERVE_POSTURE)).max()
    figures["joint_error_after_cancel_rad"] = round(float(error), 4)
    assert error <= OBSERVE_TOLERANCE, f"the arm is {error:.3f} rad from the observe posture"
    # The next task starts from the state the cancel left and finishes it.
    run_to_success(graph, figures)


def test_bump_mid_execution_is_detected_and_the_plan_repaired(graph: TaskGraph, figures):
    graph.reset()
    feedback: list = []
    bumped: list[str] = []

    def bump_after_the_first_push() -> None:
        if not bumped and executed_pushes(feedback) >= 1:
            bumped.append(graph.bump_an_idle_object(executed_pushes(feedback)))

    result = run_to_success(graph, figures, feedback=feedback,
                            during=bump_after_the_first_push)
    assert bumped, "no push was executed"
    assert result.replans >= 1, describe(result)


def test_task_completes_with_half_the_camera_frames_dropped(graph: TaskGraph, figures):
    graph.reset()
    frames, truths = [], []
    # Camera info goes with every published frame and, unlike the best-effort images, is
    # reliable: a loaded probe does not lose it, so it counts what the sim published.
    images = graph.probe.create_subscription(
        CameraInfo, "/camera/camera_info", lambda m: frames.append(1),
        QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    states = graph.probe.create_subscription(ObjectStateArray, "/sim/object_states",
                                             lambda m: truths.append(1), 10)

    def arrived() -> float:
        """Published frames per rendered frame (each has its ground truth) since the last call."""
        share = len(frames) / max(len(truths), 1)
        frames.clear()
        truths.clear()
        return share

    # Measured without drops first, as the rate of both may differ a little.
    graph.spin_until(lambda: False, 10.0)
    baseline = arrived()
    graph.set_sim_parameter("camera_drop_fraction", 0.5)
    try:
        run_to_success(graph, figures)
        with_drops = arrived()
    finally:
        graph.set_sim_parameter("camera_drop_fraction", 0.0)
        graph.probe.destroy_subscription(images)
        graph.probe.destroy_subscription(states)
    dropped = 1.0 - with_drops / max(baseline, 1e-9)
    figures.update(frames_reaching_the_probe=(round(baseline, 2), round(with_drops, 2)),
                   frames_dropped=round(dropped, 2))
    assert dropped >= 0.3, f"{with_drops:.0%} of frames arrived, {baseline:.0%} without drops"


def perceived(message: ObjectStateArray) -> dict[str, np.ndarray]:
    return {s.id: np.array([s.x, s.y, s.theta]) for s in message.objects}



def assert_same_poses(seen: dict[str, np.ndarray], truth: dict[str, np.ndarray],
                      what: str) -> None:
    assert sorted(seen) == sorted(truth), f"{what}: ids {sorted(seen)}, not {sorted(truth)}"
    for object_id, pose in seen.items():
        error = np.abs(pose - truth[object_id])
        error[2] = abs((error[2] + np.pi / 2) % np.pi - np.pi / 2)   # boxes: modulo a half turn
        assert error[:2].max() <= POSE_TOLERANCE and error[2] <= ANGLE_TOLERANCE, \
            f"{what}: {object_id} at {pose}, truly at {truth[object_id]}"


def test_perception_restart_recovers_the_same_ids_at_the_same_poses(graph: TaskGraph,
                                                                     figures):
    # Start from poses away from the scenario's (which name the detections): move both, each
    # by less than the 5 cm a tracked object may jump between frames (gate_tracked): a fresh-
    # clone CI run moved the eraser 5.4 cm within 0.5 s of its last frame, and perception
    # rightly took it for a new object ("eraser_1").
    graph.reset()
    graph.disturb("eraser", 0.04, -0.02, 0.3)
    graph.disturb("remote", 0.03, -0.03, -0.2)
    graph.fresh_truth()
    graph.fresh_truth()         # rendered after the bumps, not while they were applied
    before, truth = graph.wait_until_perceived()
    assert_same_poses(before, truth, "before the restart")
    assert abs(truth["eraser"][0] - 0.48) < POSE_TOLERANCE, "the bump has not shown yet"
    graph.processes["perception_node"].stop_cleanly(signal.SIGTERM)
    began = time.monotonic()
    graph.start_perception()
    after, _ = graph.wait_until_perceived()
    figures["restart_s"] = round(time.monotonic() - began, 1)
    assert_same_poses(after, before, "after the restart")
    # The planner's view of the objects after the restart: each id where that object is.
    observed = graph.probe.record(ObjectStateArray, "/planner/observed")
    handle = graph.probe.send_goal(graph.plan_client, PlanTask.Goal(budget_s=0.5))
    wrapped = graph.probe.wait_for(handle.get_result_async(), FAILURE_TIMEOUT_S)
    # A rare failure here (no settled observation within 15 s, twice in CI) was a response the
    # restarted perception sent but rmw_fastrtps dropped ("failed to send response (timeout)" in
    # its log); the planner now asks again (SETTLE_REQUEST_S). The log goes with any failure.
    planned = (PlanTask.Result.SUCCESS, PlanTask.Result.NO_IMPROVEMENT)
    assert wrapped.result.error_code in planned, \
        f"{wrapped.result.error_msg}\n{graph.processes['perception_node'].log()[-4000:]}"
    assert observed, "the planner published no observation"
    assert_same_poses(perceived(observed[-1]), truth, "the planner's observation")


def test_planner_signalled_mid_push_exits_at_once_without_a_traceback(graph: TaskGraph,
                                                                       figures):
    # rclpy destroys the node under a running goal, and the process exits only once the goal's
    # worker thread returns: a task waiting for its push's result (push_timeout_s, 60 s) held
    # the node past the 15-s grace (-9 before the change), and one still planning died on its
    # destroyed handle with a traceback. Every wait and the planning stop on shutdown.
    graph.reset()
    phases = graph.probe.record(ExecutePrimitive.Impl.FeedbackMessage,
                                "/executor/execute_primitive/_action/feedback",
                                transform=lambda m: m.feedback.phase)
    graph.send_task()
    assert graph.probe.spin_until(lambda: Feedback.PHASE_PUSH in phases, 120.0), "no push began"
    planner = graph.processes["planner_node"]
    began = time.monotonic()
    planner.stop_cleanly()
    figures["stop_s"] = round(time.monotonic() - began, 1)
    assert "Traceback" not in planner.log(), planner.log()[-4000:]
    # the push the planner left runs to its end before the next goal
    graph.start_planner()
    graph.wait_ready()


def test_executor_signalled_mid_push_exits_at_once(graph: TaskGraph, figures):
    # Its push waited for the controller's result and then for joint states that no longer
    # came in (server_timeout, 15 s here), past the grace. Waits end on shutdown.
    graph.reset()
    feedback: list = []
    handle = graph.probe.send_goal(graph.execute_client, ExecutePrimitive.Goal(
        object_id="eraser", primitive=1, push_length=0.03), feedback)
    assert handle.accepted, "goal rejected"
    assert graph.probe.spin_until(lambda: any(
        f.feedback.phase == Feedback.PHASE_PUSH for f in feedback), 60.0), "no push began"
    began = time.monotonic()
    graph.processes["executor_node"].stop_cleanly()
    figures["stop_s"] = round(time.monotonic() - began, 1)
    graph.start_executor()
    graph.wait_ready()


def test_object_out_of_reach_is_reported_and_the_rest_of_the_task_done(graph: TaskGraph,
                                                                       figures):
    for name in ("planner_node", "perception_node"):
        graph.processes[name].stop_cleanly()
    graph.use_scenario(DATA / "two_boxes_out_of_reach.yaml")
    graph.fresh_models()
    graph.load()
    graph.start_perception()
    planner = graph.start_planner()
    graph.wait_ready()
    plate = graph.fresh_truth()["plate"]
    result = run_to_success(graph, figures)
    figures["error_msg"] = result.error_msg
    assert "UNREACHABLE" in result.error_msg and "plate" in result.error_msg, describe(result)
    assert "UNREACHABLE: plate" in planner.log()
    assert result.pushes >= 1 and result.learning_trials == 0, describe(result)
    moved = graph.fresh_truth()["plate"]
    assert abs(moved.x - plate.x) + abs(moved.y - plate.y) <= POSE_TOLERANCE


def test_no_node_logged_a_traceback(graph: TaskGraph):
    for process in graph.launch.processes:
        assert "Traceback" not in process.log(), process.log()
