"""Load (issue 7): 60 consecutive tasks in one graph, then the nodes stopped by SIGINT and, in a
second graph, by SIGTERM.

Before each task the simulator loads tests/data/two_boxes_one_push.yaml (two_boxes with a push
or two left), so every RunTask has work to do and ends converged in a few seconds; perception
and the planner run on two_boxes.yaml, as in the other graph tests. No node may leak resident
memory (its child processes included: the sim's renderer), threads or child processes. The
issue's target, < 10 % growth from task 2 to task 20 (task 1 warms caches up), is printed for
docs/reliability.md ("Load"); run with -s to see it.
"""

from __future__ import annotations

import signal
import time

import pytest

pytestmark = [pytest.mark.integration, pytest.mark.slow]

rclpy = pytest.importorskip("rclpy")
psutil = pytest.importorskip("psutil")
from action_msgs.msg import GoalStatus  # noqa: E402
from task_graph import DATA, TaskGraph, describe  # noqa: E402

from tsrrt_interfaces.action import RunTask  # noqa: E402

TASKS = 60
BASELINE_TASK = 2
TARGET_TASK = 20
# Issue 7's target is < 10 % RSS growth from task 2 to task 20 (TARGET_TASK): printed (FIGURES)
# and reported in docs/reliability.md, since targets are measured, not asserted. What is asserted
# is the absence of a leak: a leak grows linearly, warm-up of the allocator and caches levels off
# within the first tasks, so tasks 10 to 60 may add at most LEAK_GROWTH (perception_node fails
# from a steady 0.12 MB a task). Each end is the median of three tasks' samples: one sample can be
# megabytes above its neighbours (perception holding a frame's images at that moment). Until
# session 46 perception_node kept camera frames whose partner (colour or depth) had been lost,
# up to ten per stream, and crept up by 15-20 MB over 60 tasks; the check then had to wait for
# task 40 and still failed in CI.
LEAK_FROM_TASK = 10
LEAK_GROWTH = 0.04
# Thread pools (rclpy's executors, the planner's) may start a worker late; a leak of one per
# task would add 58 between task 2 and task 60.
THREAD_SLACK = 4
ONE_PUSH = DATA / "two_boxes_one_push.yaml"
NODES = ("sim_node", "perception_node", "executor_node", "planner_node")


def footprint(pid: int) -> dict[str, int]:
    """Resident memory (bytes) of a process and its descendants, its threads and children."""
    process = psutil.Process(pid)
    children = process.children(recursive=True)
    return {"rss": sum(p.memory_info().rss for p in [process, *children]),
            "threads": process.num_threads(), "children": len(children),
            "pids": [pid, *[c.pid for c in children]]}


def assert_stops_cleanly(graph: TaskGraph, sig: int) -> None:
    """Every node exits with 0 on `sig`, logs no traceback and leaves no process behind."""
    pids = [pid for name in NODES for pid in footprint(graph.processes[name].popen.pid)["pids"]]
    for name in NODES:
        process = graph.processes[name]
        code = process.stop(sig)
        assert code == 0, f"{name} exited with {code} on {signal.Signals(sig).name}:\n" \
                          f"{process.log()[-3000:]}"
        assert "Traceback" not in process.log(), process.log()
    deadline = time.monotonic() + 10.0
    while any(psutil.pid_exists(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [pid for pid in pids if psutil.pid_exists(pid)
            and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE]
    assert not left, f"processes left behind: {left}"


@pytest.fixture(scope="module")
def graph(launch, graph_probe, tmp_path_factory) -> TaskGraph:
    return TaskGraph(launch, graph_probe, tmp_path_factory.mktemp("soak")).start()


def _median_rss(samples: dict[int, dict[str, dict]], name: str, task: int) -> float:
    """Median resident memory of `name` after tasks task - 1, task and task + 1."""
    return sorted(samples[t][name]["rss"] for t in (task - 1, task, task + 1))[1]


def test_sixty_tasks_without_growth_then_sigint(graph: TaskGraph):
    samples: dict[int, dict[str, dict]] = {}
    durations = []
    for task in range(1, TASKS + 1):
        graph.reset(ONE_PUSH)
        start_cost = graph.true_cost()
        began = time.monotonic()
        status, result = graph.run_task(RunTask.Goal(planning_budget_s=0.5))
        durations.append(time.monotonic() - began)
        final_cost = graph.true_cost()
        summary = (f"task {task}: {describe(result)}; true cost {start_cost:.4f} -> "
                   f"{final_cost:.4f}")
        assert status == GoalStatus.STATUS_SUCCEEDED, f"{summary}\n{graph.logs()}"
        assert result.pushes >= 1 and final_cost < start_cost, summary
        samples[task] = {name: footprint(graph.processes[name].popen.pid) for name in NODES}
    first, last = samples[BASELINE_TASK], samples[TARGET_TASK]
    figures = {name: {"rss_mb": (round(first[name]["rss"] / 2**20, 1),
                                 round(last[name]["rss"] / 2**20, 1)),
                      "growth": round(last[name]["rss"] / first[name]["rss"] - 1.0, 3),
                      "threads": (first[name]["threads"], last[name]["threads"]),
                      "children": (first[name]["children"], last[name]["children"])}
               for name in NODES}
    series = {name: [round(samples[t][name]["rss"] / 2**20) for t in samples] for name in NODES}
    print(f"\nFIGURES task wall s: median {sorted(durations)[TASKS // 2]:.1f}, "
          f"max {max(durations):.1f}, total {sum(durations):.0f}; per node {figures}; "
          f"RSS MB after each task {series}")
    for name in NODES:
        late_growth = (_median_rss(samples, name, TASKS - 1)
                       / _median_rss(samples, name, LEAK_FROM_TASK) - 1.0)
        assert late_growth < LEAK_GROWTH, (
            f"{name}: RSS still grew {late_growth:.1%} from around task {LEAK_FROM_TASK} to "
            f"around task {TASKS - 1} (medians of three) "
            f"({figures[name]}; MB per task {series[name]})")
        end = samples[TASKS][name]
        assert end["threads"] <= first[name]["threads"] + THREAD_SLACK, (name, end)
        assert end["children"] == first[name]["children"], (name, end)
    assert_stops_cleanly(graph, signal.SIGINT)


def test_a_fresh_graph_stops_cleanly_on_sigterm(graph: TaskGraph):
    graph.launch.stop_all()     # left running only if the test above failed early
    graph.start()               # waits until every node serves its actions and services
    assert_stops_cleanly(graph, signal.SIGTERM)
