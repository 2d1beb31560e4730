"""The OMPL baseline plans on our problem: its pushes replay validly under our models."""

from __future__ import annotations

import numpy as np
import pytest

from tsrrt_planner.errors import PlannerError
from tsrrt_planner.ompl_baseline import plan_with_ompl


@pytest.mark.parametrize("planner", ["sst", "rrt"])
def test_ompl_plans_replay_validly_and_lower_the_cost(problem, planner):
    result = plan_with_ompl(problem, planner, seed=0, time_budget_s=0.5, lower_bound_cost=-0.5)
    assert result.mode == f"ompl-{planner}"
    assert result.steps, "half a second of OMPL finds no push that lowers tset3's cost"
    index = {object_id: i for i, object_id in enumerate(problem.objects.ids)}
    state = problem.start
    for step, predicted in zip(result.steps, result.states[1:], strict=True):
        o = index[step.object_id]
        assert problem.min_length <= step.push_length <= problem.max_length
        assert problem.pushes_valid(state, np.array([o]), np.array([step.primitive]),
                                    np.array([step.push_length]))[0], step
        state = problem.apply(state, o, step.primitive, step.push_length)
        np.testing.assert_allclose(predicted, state, atol=1e-12)
    np.testing.assert_allclose(result.costs, problem.objective.cost(result.states))
    assert result.best_cost < result.costs[0]
    assert result.gap() == pytest.approx((result.best_cost + 0.5) / 0.5)


def test_an_unknown_ompl_planner_is_named(problem):
    with pytest.raises(PlannerError, match=r"unknown OMPL planner 'prm'.*'rrt', 'sst'"):
        plan_with_ompl(problem, "prm", time_budget_s=0.1)
