"""OMPL control-based planners on exactly our problem, as an outside baseline.

State space: R^(3n) (x, y, theta of every object; headings bounded loosely, they are angles).
Control: (action index in [0, K), push length in [min, max]) with K the (object, primitive)
pairs; one control step = one push. Propagator: our forward model (PlanningProblem.apply); a push
that breaks a push constraint (ball path, reach, intermediate poses) propagates to a state off the
table, which our validity checker then rejects. Goal: a GoalRegion whose distance is
C(s) - C_goal (C_goal: the lower bound), so with the threshold never met the planner runs its
whole budget and returns the state of lowest cost it found (OMPL's approximate solution).

The issue asks for OMPL's control SST. The pip wheel of OMPL 2.0.1 binds ompl.control.SST without
a constructor ("no constructor defined"; ompl/ompl PR #1442 adds the missing bindings), so
`plan_with_ompl(..., planner="sst")` raises PlannerError saying so, and the benchmark also offers
"ompl-rrt", OMPL's control RRT, which the wheel can construct.
"""

from __future__ import annotations

import time

import numpy as np

from tsrrt_planner.errors import PlannerError
from tsrrt_planner.problem import PlanningProblem
from tsrrt_planner.task_space_rrt import PlanResult, PlanStep, simulate

OFF_TABLE = -100.0


def plan_with_ompl(problem: PlanningProblem, planner: str = "rrt", seed: int = 0,
                   time_budget_s: float = 10.0, lower_bound_cost: float | None = None
                   ) -> PlanResult:
    """Run OMPL's control `planner` ("rrt" or "sst") on the problem; see the module docstring."""
    from ompl import base as ob
    from ompl import control as oc
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    ou.RNG.setSeed(seed + 1)  # OMPL rejects 0; its seed is process-wide and set once
    n, dimension = problem.n, 3 * problem.n
    x_min, y_min, x_max, y_max = problem.scenario.table.bounds
    space = ob.RealVectorStateSpace(dimension)
    bounds = ob.RealVectorBounds(dimension)
    for i in range(n):
        for d, (low, high) in enumerate([(x_min, x_max), (y_min, y_max),
                                         (-8 * np.pi, 8 * np.pi)]):
            bounds.setLow(3 * i + d, low)
            bounds.setHigh(3 * i + d, high)
    space.setBounds(bounds)
    actions = len(problem.action_objects)
    control_space = oc.RealVectorControlSpace(space, 2)
    control_bounds = ob.RealVectorBounds(2)
    control_bounds.setLow(0, 0.0)
    control_bounds.setHigh(0, float(actions))
    control_bounds.setLow(1, problem.min_length)
    control_bounds.setHigh(1, problem.max_length)
    control_space.setBounds(control_bounds)
    setup = oc.SimpleSetup(control_space)

    began = time.perf_counter()
    start_cost = float(problem.objective.cost(problem.start))
    trace: list[tuple[float, int, float]] = [(0.0, 1, start_cost)]
    counter = {"nodes": 1, "best": start_cost}

    def read(state) -> np.ndarray:
        return np.array([state[k] for k in range(dimension)]).reshape(n, 3)

    def decode(control) -> tuple[int, int, float]:
        k = min(int(control[0]), actions - 1)
        return (int(problem.action_objects[k]), int(problem.action_primitives[k]),
                float(control[1]))

    def propagate(start, control, duration, result) -> None:
        state = read(start)
        o, p, length = decode(control)
        if problem.pushes_valid(state, np.array([o]), np.array([p]), np.array([length]))[0]:
            new = problem.apply(state, o, p, length)
            counter["nodes"] += 1
            cost = float(problem.objective.cost(new))
            if cost < counter["best"]:
                counter["best"] = cost
                trace.append((time.perf_counter() - began, counter["nodes"], cost))
        else:
            new = state.copy()
            new[0, 0] = OFF_TABLE
        for k, value in enumerate(new.ravel()):
            result[k] = float(value)

    def valid(state) -> bool:
        values = read(state)
        return bool(values[0, 0] != OFF_TABLE and problem.state_valid(values))

    setup.setStateValidityChecker(valid)
    setup.setStatePropagator(propagate)
    information = setup.getSpaceInformation()
    information.setPropagationStepSize(1.0)
    information.setMinMaxControlDuration(1, 1)
    goal_cost = lower_bound_cost if lower_bound_cost is not None else -np.inf

    class LowCost(ob.GoalRegion):
        def __init__(self, si) -> None:
            super().__init__(si)
            self.setThreshold(0.0)

        def distanceGoal(self, state) -> float:
            return max(float(problem.objective.cost(read(state))) - goal_cost, 1e-12)

    setup.setGoal(LowCost(information))
    start = space.allocState()
    for k, value in enumerate(problem.start.ravel()):
        start[k] = float(value)
    setup.setStartState(start)
    if planner == "sst":
        try:
            setup.setPlanner(oc.SST(information))
        except TypeError as error:
            raise PlannerError(f"OMPL's control SST cannot be constructed from Python in this "
                               f"OMPL build ({error}); use ompl-rrt") from None
    elif planner == "rrt":
        setup.setPlanner(oc.RRT(information))
    else:
        raise PlannerError(f"unknown OMPL planner {planner!r}; known: ['rrt', 'sst']")
    setup.solve(float(time_budget_s))
    steps: list[tuple[int, int, float]] = []
    if setup.haveSolutionPath():
        path = setup.getSolutionPath()
        steps = [decode(path.getControl(k)) for k in range(path.getControlCount())]
    states = simulate(problem, steps)
    return PlanResult(
        mode=f"ompl-{planner}", seed=seed,
        steps=tuple(PlanStep(problem.objects.ids[o], p, length) for o, p, length in steps),
        states=states, costs=np.asarray(problem.objective.cost(states)),
        nodes=counter["nodes"], elapsed_s=time.perf_counter() - began, trace=tuple(trace),
        stop_reason="time", lower_bound=lower_bound_cost)
