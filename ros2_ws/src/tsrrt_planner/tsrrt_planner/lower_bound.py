"""The objective minimised over continuous poses, ignoring how objects get there.

`lower_bound` runs a local constrained optimiser (SLSQP: analytic objective gradient, sparse
finite-difference constraint Jacobian from collision.py) from several starts - the start state,
then uniformly random poses on the table - under the planner's own constraints: footprints on the
table and apart by the same margin. Pushing, reachability and the ball path are ignored, so no
plan can end in a state it does not allow.

It is a *bound* only as good as the multi-start search: the objective is non-convex, so the
value is the best local minimum found. Random starts rarely find the order of a tight cluster:
on clean, 12-16 starts put the eraser between the scale and the remote (0.0855) where the remote
in the middle is 1.8 % better (found by 32 starts, 2.2 s). So the best minimum is refined by
swapping: the positions of two neighbouring objects of different kinds are exchanged and the
result descended again, repeated while it improves (`swap_refine`).

Gap = (C - C_lb) / |C_lb|; a negative gap would mean the planner found a better minimum than
the multi-start did (reported as is, never hidden).

`local_minimum` is also the planners' DIRECTGD: gradient-based descent from a tree node to the
nearest constrained local minimum.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from tsrrt_planner.errors import Cancelled
from tsrrt_planner.problem import PlanningProblem

FEASIBILITY_TOLERANCE = 1e-5  # metres; SLSQP stops a hair outside active constraints
ZERO_OPTIMUM = 1e-6  # |lower bound| at or below which a relative gap means nothing
SWAP_GAIN = 1e-6  # relative improvement that makes swap_refine keep an exchange
NEIGHBOUR_GAP = 0.02  # metres between bounding circles within which swap_refine swaps objects


def relative_gap(cost: float, bound: float | None) -> float | None:
    """Gap = (C - C_lb) / |C_lb|; None without a finite bound, or against a zero optimum (the
    obstacle task's goal point), where every cost short of it would be an infinite gap."""
    if bound is None or not math.isfinite(bound) or abs(bound) <= ZERO_OPTIMUM:
        return None
    return (cost - bound) / abs(bound)


def local_minimum(problem: PlanningProblem, state: np.ndarray, max_iterations: int = 60,
                  held: np.ndarray | None = None, pinned: np.ndarray | None = None
                  ) -> tuple[np.ndarray, float, bool]:
    """Constrained local minimum near `state` (n, 3), the objects `held` (n,) bool, if given,
    kept where they are, and those with a nonzero row of `pinned` (n, 2) kept where they are
    along that direction (free across it and in heading).

    Returns:
        (state (n, 3), cost, feasible): feasible is False when SLSQP ended outside the
        constraints (the caller should not use such a state as a target).
    """
    shape = state.shape
    objective, checker = problem.objective, problem.checker
    free = np.ones(state.size, bool) if held is None else np.repeat(~held, shape[1])

    def full(x: np.ndarray) -> np.ndarray:
        whole = state.ravel().copy()
        whole[free] = x
        return whole.reshape(shape)

    def cost(x: np.ndarray) -> float:
        return objective.cost(full(x))

    def gradient(x: np.ndarray) -> np.ndarray:
        return objective.gradient(full(x)).ravel()[free]

    constraints = [{"type": "ineq", "fun": lambda x: checker.constraint_values(full(x)),
                    "jac": lambda x: checker.constraint_jacobian(full(x))[:, free]}]
    rows = [] if pinned is None else np.nonzero(np.abs(pinned).sum(axis=1) > 0)[0]
    if len(rows):
        along = np.zeros((len(rows), state.size))   # d . (position - start) = 0 per row
        for k, i in enumerate(rows):
            along[k, 3 * i:3 * i + 2] = pinned[i]
        along = along[:, free]
        start = along @ state.ravel()[free]
        constraints.append({"type": "eq", "fun": lambda x: along @ x - start,
                            "jac": lambda x: along})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = minimize(cost, state.ravel()[free], jac=gradient, constraints=constraints,
                          method="SLSQP", options={"maxiter": max_iterations, "ftol": 1e-10})
    found = full(result.x)
    feasible = bool(checker.constraint_values(found).min() >= -FEASIBILITY_TOLERANCE)
    return found, float(objective.cost(found)), feasible


def random_state(problem: PlanningProblem, rng: np.random.Generator) -> np.ndarray:
    """Uniform poses (n, 3) with every centre on the table (overlaps allowed). Discs get
    heading 0, as everywhere in the planner: nothing turns them back (their heading costs
    nothing), and a plate's optimum at a random heading in a corner near the base strands one of
    its faces, which makes the face rule (`with_face_allowance`) let it lose one."""
    x_min, y_min, x_max, y_max = problem.scenario.table.bounds
    n = problem.n
    return np.column_stack([rng.uniform(x_min, x_max, n), rng.uniform(y_min, y_max, n),
                            np.where(problem.objects.is_disc, 0.0,
                                     rng.uniform(-np.pi, np.pi, n))])


@dataclass(frozen=True)
class LowerBound:
    """Best continuous minimum found and how it was found."""

    cost: float
    state: np.ndarray  # (n, 3)
    starts: int
    feasible_starts: int
    seconds: float


def lower_bound(problem: PlanningProblem, starts: int = 16, seed: int = 0,
                time_limit_s: float = 30.0,
                cancel: Callable[[], bool] = lambda: False) -> LowerBound:
    """Multi-start constrained minimisation of the objective (see the module docstring).
    `cancel` is asked before every descent; True raises Cancelled (a partial multi-start is
    no bound to keep). A descent takes up to a second or two, the whole bound up to
    `time_limit_s` (tset6 with learned models: 22 s), too long for a node that must stop."""
    rng = np.random.default_rng(seed)
    began = time.perf_counter()
    best_state, best_cost, feasible_count, tried = None, np.inf, 0, 0
    for k in range(starts):
        if cancel():
            raise Cancelled(f"lower bound cancelled after {k} of {starts} starts")
        if k and time.perf_counter() - began > time_limit_s:
            break
        start = problem.start if k == 0 else random_state(problem, rng)
        found, cost, feasible = local_minimum(problem, start, max_iterations=150)
        tried += 1
        if feasible:
            feasible_count += 1
            if cost < best_cost:
                best_state, best_cost = found, cost
    if best_state is None:
        best_state, best_cost = problem.start, float(problem.objective.cost(problem.start))
    else:
        best_state, best_cost, _ = swap_refine(problem, best_state, best_cost,
                                               began + time_limit_s, cancel)
    return LowerBound(best_cost, best_state, tried, feasible_count,
                      time.perf_counter() - began)


def swap_refine(problem: PlanningProblem, state: np.ndarray, cost: float, deadline: float,
                cancel: Callable[[], bool] = lambda: False) -> tuple[np.ndarray, float, int]:
    """Exchange the positions of two neighbouring objects of different kinds (headings stay)
    and descend again; keep the first exchange that is feasible and better, until none is (or
    the perf_counter `deadline` passes). Neighbours only: their order is what multi-starts
    get wrong, and a tset6 plate in a corner never gains from a platter's place (8 descents,
    2.5 s). Returns the state, its cost and the descents made; `cancel` as in lower_bound."""
    kinds = [(spec.object_class, spec.shape, spec.length, spec.width)
             for spec in problem.scenario.objects]
    objects = problem.objects
    reach = np.hypot(objects.half_length, np.where(objects.is_disc, 0.0, objects.half_width))
    descents, improved = 0, True
    while improved and time.perf_counter() < deadline:
        improved = False
        apart = np.linalg.norm(state[:, None, :2] - state[None, :, :2], axis=-1)
        pairs = [(i, j) for i in range(problem.n) for j in range(i + 1, problem.n)
                 if kinds[i] != kinds[j]
                 and apart[i, j] <= reach[i] + reach[j] + NEIGHBOUR_GAP]
        for i, j in pairs:
            if time.perf_counter() >= deadline:
                break
            if cancel():
                raise Cancelled(f"lower bound cancelled after {descents} exchanges")
            swapped = state.copy()
            swapped[[i, j], :2] = state[[j, i], :2]
            found, found_cost, feasible = local_minimum(problem, swapped, max_iterations=150)
            descents += 1
            if feasible and found_cost < cost - SWAP_GAIN * max(abs(cost), ZERO_OPTIMUM):
                state, cost, improved = found, found_cost, True
                break
    return state, cost, descents
