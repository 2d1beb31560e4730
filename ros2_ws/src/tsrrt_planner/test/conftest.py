"""Small dense problems run fastest on one BLAS thread (SLSQP's QPs are tiny). The planner's
tests share tset3 with push-rule models, and its lower bound; a module that plans another
scenario defines its own `problem`."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest  # noqa: E402

from tsrrt_common.scenario import load_scenario  # noqa: E402
from tsrrt_planner.lower_bound import LowerBound, lower_bound  # noqa: E402
from tsrrt_planner.problem import PlanningProblem  # noqa: E402
from tsrrt_planner.push_rule import learn_all  # noqa: E402


@pytest.fixture(scope="module")
def problem() -> PlanningProblem:
    scenario = load_scenario("tset3")
    return PlanningProblem(scenario, learn_all(scenario.objects, seed=0))


@pytest.fixture(scope="module")
def bound(problem: PlanningProblem) -> LowerBound:
    return lower_bound(problem, starts=4)
