"""OMPL control-based planners on exactly our problem, as an outside baseline.

State space: R^(3n) (x, y, theta of every object; headings bounded loosely, they are angles).
Control: (action index in [0, K), push length in [min, max]) with K the (object, primitive)
pairs; one control step = one push. Propagator: our forward model (PlanningProblem.apply); a push
that breaks a push constraint (ball path, reach, intermediate poses) propagates to a state off the
table, which our validity checker then rejects. Goal: a GoalRegion whose distance is
C(s) - C_goal (C_goal: the lower bound), so with the threshold never met the planner runs its
whole budget and returns the state of lowest cost it found (OMPL's approximate solution).

Path cost: what each push changes our objective by (`ObjectiveChange`), so the cost of a node is
its state's objective less the start's, and SST keeps in each witness region the node that is best
by our objective (with OMPL's default, path length, it keeps the one with the fewest pushes: tset3
at 3 s, 77 % above the bound against 26 %).

OMPL 1.7.0 is pinned, not 2.0.1: the 2.0.1 wheel's nanobind bindings have no constructor for
ompl.control.SST or ompl.base.State ("no constructor defined"; ompl/ompl PR #1442), and 1.7.0's
Boost.Python ones have both. Each run is a forked child process of its own: OMPL's random seed is
process-wide and takes effect only before its first random number (so a seed selects a run only
in a fresh process), and the 1.7.0 wheel corrupts the heap when a process that imported it exits
("free(): invalid next size", even after a bare `import ompl.util`); the child leaves by
os._exit, and the caller never imports OMPL.
"""

from __future__ import annotations

import multiprocessing
import os
import time
import traceback
from multiprocessing.connection import Connection

import numpy as np

from tsrrt_planner.errors import PlannerError
from tsrrt_planner.problem import PlanningProblem
from tsrrt_planner.task_space_rrt import PlanResult, PlanStep, simulate

OFF_TABLE = -100.0
PLANNERS = ("rrt", "sst")


def plan_with_ompl(problem: PlanningProblem, planner: str = "rrt", seed: int = 0,
                   time_budget_s: float = 10.0, lower_bound_cost: float | None = None
                   ) -> PlanResult:
    """Run OMPL's control `planner` ("rrt" or "sst") on the problem in a child process; see the
    module docstring."""
    if planner not in PLANNERS:
        raise PlannerError(f"unknown OMPL planner {planner!r}; known: {list(PLANNERS)}")
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    child = context.Process(target=_plan_in_child, daemon=True, args=(
        sender, problem, planner, seed, time_budget_s, lower_bound_cost))
    child.start()
    sender.close()
    try:
        outcome, value = receiver.recv()
    except EOFError:
        child.join()
        raise PlannerError(f"OMPL's {planner} ended without a result (exit code "
                           f"{child.exitcode})") from None
    child.join()
    if outcome == "error":
        raise PlannerError(f"OMPL's {planner} failed:\n{value}")
    return value


def _plan_in_child(sender: Connection, *arguments) -> None:
    """Send ("result", PlanResult) or ("error", traceback) and leave without OMPL's teardown."""
    try:
        sender.send(("result", _plan(*arguments)))
    except BaseException:  # noqa: BLE001 - whatever happens, the parent must hear of it
        sender.send(("error", traceback.format_exc()))
    finally:
        sender.close()
        os._exit(0)


def _plan(problem: PlanningProblem, planner: str, seed: int, time_budget_s: float,
          lower_bound_cost: float | None) -> PlanResult:
    from ompl import base as ob
    from ompl import control as oc
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    ou.RNG.setSeed(seed + 1)  # OMPL rejects 0
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

    setup.setStateValidityChecker(ob.StateValidityCheckerFn(valid))
    setup.setStatePropagator(oc.StatePropagatorFn(propagate))
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

    class ObjectiveChange(ob.OptimizationObjective):
        """A push costs what it changes the objective by, so a node's path cost is its
        state's objective (less the start's): SST keeps, in each witness region, the node
        whose state is best by our objective."""

        def motionCost(self, s1, s2):
            return ob.Cost(float(problem.objective.cost(read(s2)))
                           - float(problem.objective.cost(read(s1))))

    setup.setGoal(LowCost(information))
    setup.setOptimizationObjective(ObjectiveChange(information))
    start = ob.State(space)
    for k, value in enumerate(problem.start.ravel()):
        start[k] = float(value)
    setup.setStartState(start)
    setup.setPlanner(oc.SST(information) if planner == "sst" else oc.RRT(information))
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
