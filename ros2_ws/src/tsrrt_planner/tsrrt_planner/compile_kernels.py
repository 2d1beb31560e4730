"""Compile the planner's kernels once: `python -m tsrrt_planner.compile_kernels`.

numba compiles kernels.py on first use (about 10 s on this project's 2-core machines) and caches
the machine code on disk, next to the sources or in numba's user cache. scripts/setup.sh runs
this after every build, so that a first plan or test does not spend that time.
"""

from __future__ import annotations

import time

from tsrrt_common.scenario import load_scenario
from tsrrt_planner.objectives import compile_cost_kernels
from tsrrt_planner.problem import PlanningProblem
from tsrrt_planner.push_rule import learn_all
from tsrrt_planner.task_space_rrt import compile_search_kernels


def main() -> None:
    began = time.perf_counter()
    scenario = load_scenario("obstacle")   # one with a static obstacle: every kernel's types
    problem = PlanningProblem(scenario, learn_all(scenario.objects, seed=0))
    compile_search_kernels(problem)
    compile_cost_kernels()
    print(f"planner kernels ready in {time.perf_counter() - began:.1f} s")


if __name__ == "__main__":
    main()
