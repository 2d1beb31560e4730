"""Parallel searches (parallel.plan_in_parallel): the best worker's plan, deterministic at a
node budget, every worker's nodes counted, errors and cancel reaching the caller."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from tsrrt_planner.errors import PlannerError
from tsrrt_planner.parallel import SEED_STRIDE, WorkerTraceback, plan_in_parallel
from tsrrt_planner.task_space_rrt import TASK_SPACE_RRT, simulate


def test_the_best_of_the_workers_seeds_is_returned(problem, bound):
    options = {"time_budget_s": None, "max_nodes": 60, "target": bound.state}
    alone = [TASK_SPACE_RRT(problem, "tsrrt", 3 + worker * SEED_STRIDE, **options)
             for worker in range(3)]
    together = plan_in_parallel(problem, 3, "tsrrt", 3, **options)
    best = min(alone, key=lambda result: result.best_cost)
    assert together.steps == best.steps
    np.testing.assert_array_equal(together.states, best.states)
    assert together.nodes == sum(result.nodes for result in alone)
    assert together.seed == 3
    # the plan is the winner's, replayed through the models from the start
    steps = [(problem.objects.ids.index(step.object_id), step.primitive, step.push_length)
             for step in together.steps]
    np.testing.assert_allclose(simulate(problem, steps), together.states, atol=1e-12)


def test_deterministic_for_a_seed_and_a_node_budget(problem, bound):
    runs = [plan_in_parallel(problem, 2, "tsrrt", 5, time_budget_s=None, max_nodes=60,
                             target=bound.state) for _ in range(2)]
    assert runs[0].steps == runs[1].steps
    np.testing.assert_array_equal(runs[0].costs, runs[1].costs)


def test_the_trace_is_the_best_over_all_workers(problem, bound):
    result = plan_in_parallel(problem, 2, "tsrrt", 1, time_budget_s=None, max_nodes=80,
                              target=bound.state)
    times, nodes, costs = map(np.array, zip(*result.trace, strict=True))
    assert np.all(np.diff(costs) < 0) and np.all(np.diff(times) >= 0)
    assert np.all(np.diff(nodes) >= 0) and nodes[-1] <= result.nodes
    assert costs[-1] <= result.best_cost + 1e-12


def test_one_worker_is_the_search_itself(problem, bound):
    options = {"time_budget_s": None, "max_nodes": 50, "target": bound.state}
    assert (plan_in_parallel(problem, 1, "tsrrt", 2, **options).steps
            == TASK_SPACE_RRT(problem, "tsrrt", 2, **options).steps)


def test_cancel_and_progress_reach_every_worker(problem):
    reports = []
    event = threading.Event()

    def progress(info) -> None:
        reports.append(info)
        event.set()

    result = plan_in_parallel(problem, 2, "tsrrt", 0, time_budget_s=60.0, progress=progress,
                              cancel=event)
    assert result.stop_reason == "cancelled" and result.elapsed_s < 30.0
    assert reports and all(info.nodes >= 1 for info in reports)


@pytest.mark.parametrize("workers", [0, -1, 1.5, "2"])
def test_bad_worker_counts_are_refused(problem, workers):
    with pytest.raises(PlannerError, match="workers must be an integer >= 1"):
        plan_in_parallel(problem, workers, "tsrrt", 0, time_budget_s=1.0)


def test_a_workers_error_is_raised_in_the_caller_with_the_workers_traceback(problem):
    with pytest.raises(PlannerError, match="time budget must be > 0 s") as raised:
        plan_in_parallel(problem, 2, "paper", 0, time_budget_s=-1.0)
    cause = raised.value.__cause__
    assert isinstance(cause, WorkerTraceback)
    assert "in TASK_SPACE_RRT" in str(cause) and "raise PlannerError" in str(cause)
