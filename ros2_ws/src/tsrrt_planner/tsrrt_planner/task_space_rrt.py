"""TASK_SPACE_RRT (Sec. III-C, Fig. 4, Eq. 11): planning pushes through the objective's landscape.

Four planners share the tree, the forward model, the constraints and the anytime bookkeeping:

``paper``  Fig. 4 as printed. Actions are (object, primitive) pushes of the nominal 5 cm.
    Every `gd_period` iterations DIRECTGD(T) descends from the newest leaf to a constrained local
    minimum s_GD (lower_bound.local_minimum); if s_GD is better than the best tree node,
    RRT_CONNECT extends the tree towards it until an extension fails. Each iteration samples
    s_GD with probability 1 - epsilon (epsilon = 0.8) and RANDOM_CONFIG() otherwise, picks
    NEAREST_NEIGHBOR under rho (Eq. 11, orientation weighted by the scenario's
    orientation_weight, 40 as printed, in metres and radians), sorts all state-action pairs by
    rho to the sample and adds the first collision-free one closer than its parent.
``paper-nogd``  the same without DIRECTGD and RRT_CONNECT: the Fig. 10 "without GD" variant.
``greedy``  hill climbing: repeatedly take the valid nominal push that lowers the cost most.
``tsrrt``  the improved default (see `_TsrrtSearch`): variable push lengths steered in closed form
    (the model is affine in push length), targets from the continuous optimum matched to each node
    by permuting interchangeable objects and from DIRECTGD restarted at varied nodes, objective
    line-search polishing, escaping random pushes when stuck, and shortcutting and merging of
    the returned plan's pushes (in the last 15 % of a time budget). Its metric weighs each
    box's heading by its half-length (the arc its end sweeps), so one radian is not worth 40
    metres.

All planners are deterministic for a seed (given the same node budget), stop at a time or node
budget or when cancelled, report progress, and return the best state found with its plan.
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from tsrrt_planner.errors import PlannerError
from tsrrt_planner.kernels import nearest_assignments, nearest_under_rho, steer_candidates
from tsrrt_planner.lower_bound import local_minimum, random_state, relative_gap
from tsrrt_planner.problem import PlanningProblem, shortest_turn
from tsrrt_planner.rearrange import (
    OFF_THE_TABLE,
    RearrangeMemo,
    clear_of_way,
    compile_kernels,
    corridor_blocks,
    frees_a_push,
    object_error,
    parking_poses,
    pose_error,
    target_free,
)

MODES = ("paper", "paper-nogd", "tsrrt", "greedy")
Push = tuple[int, int, float]  # (object index, primitive, push length)
MIN_STEER_GAIN = 0.2  # share of an object's squared error a steering push must remove
# of a steering push's closed-form length, tried in turn when it is blocked (read-only; not
# rearrange.STEER_FRACTIONS, the A*'s)
STEER_RETRY_FRACTIONS = np.array([1.0, 0.97, 0.75, 0.5, 0.25])
STEER_RETRY_FRACTIONS.flags.writeable = False
NEAR_OPTIMAL = 0.005  # targets within this share of the best target's cost count as optimal
FAR_FROM_TARGETS = 0.05  # share of the best target's cost above it where DIRECTGD runs more often
RESTART_AT = 1 / 3  # share of the search's budget (time or nodes) at which a far search restarts
RESTART_FAR = 0.15  # share of the best target's cost above it that counts as far for a restart
GD_FAILURES_TOLERATED = 3  # DIRECTGD descents in a row that may end infeasible before it waits
GD_BACK_OFF_LIMIT = 4    # doublings of DIRECTGD's period after more of them
REARRANGE_TOLERANCE = 0.004  # metres (weighted rho) at which REARRANGE counts an object placed
STUCK_TURN = 0.001  # metres of arc at a box's ends below which a turn it can't make is no loss
SEARCH_EXPANSIONS = 48  # REARRANGE: A* expansions per object and attempt
LAST_RESORT_EXPANSIONS = 160  # ... when no object got to its target with the usual budget
TARGET_INSET = 0.002  # metres: REARRANGE aims this far inside the table edges (POLISH ends)
STRANDED_ADVANCE = 0.01  # metres a target may ask an object to go where nothing can push it
PARKING_TOLERANCE = 0.01  # metres: how close a parked object must get to its parking pose
# REARRANGE may park one object once per OBJECTS_PER_PARKING objects on the table (at least
# MIN_PARKINGS times), and spend PARKING_SEARCHES_PER_PARKING A* searches per parking allowed
# on one parking attempt: the more objects, the more of them stand in one object's way. Twice
# and 4 searches on tset12 (12 objects) left median 43.7 % (6 seeds, 10 s); four times and 8
# searches, 33.4 %. Four times on clean (3 objects) made its plans 60-217 pushes long
# instead of 30-69 for the same gaps.
OBJECTS_PER_PARKING = 3
MIN_PARKINGS = 2
PARKING_SEARCHES_PER_PARKING = 2
MAX_CANDIDATES = 4  # objects REARRANGE tries to place in one step (A* each)
MIRROR_TOLERANCE = 1e-9  # relative cost change that still counts a mirror image as equal
SHORTCUT_TOLERANCE = 1e-4  # relative cost a shortcut may give up for fewer pushes
PLAN_COST_TOLERANCE = 3e-3  # relative cost a plan may give up by stopping early
CUT_POLISH_PUSHES = 8  # polishing pushes after such a cut
SHORTCUT_SHARE = 0.25  # share of a time budget tsrrt keeps for shortening its plan
SHORTCUT_SHARE_FAR = 0.1  # ... while the best node is far above the targets (search_time_limit)
SHORTCUT_NEAR = 0.01  # share of the best target's cost: SHORTCUT_SHARE kept within it
PAIR_ATTEMPTS_PER_PUSH = 20  # random shortcut attempts per push of the plan, at most
PAIR_LONGEST_SPAN = 40  # pushes: the longest stretch of a plan one random shortcut replaces
PAIR_PUSHES_PER_OBJECT = 4  # steering pushes one object may take in a random shortcut
PAIR_TOLERANCE = 0.002  # metres (weighted rho) at which a random shortcut counts an object there
PAIR_COST_TOLERANCE = 1e-3  # relative cost random shortcuts may give up together
FOLD_SHARE = 0.3  # of the time left when random shortcuts begin, kept for folding pushes
TRACK_FRACTIONS = (1.0, 0.9, 0.75, 0.5)  # of a re-aimed push length, tried when it is blocked
TRACK_REPAIR_PUSHES = 2  # steering pushes that may bring an object back onto its planned pose
TRACK_REPAIR_TOLERANCE = 0.001  # metres (weighted rho) at which such a repair stops
Progress = Callable[["ProgressInfo"], None]
Cancel = Callable[[], bool] | threading.Event


@dataclass(frozen=True)
class Target:
    """A local minimum the tsrrt search steers towards."""
    cost: float
    state: np.ndarray   # (n, 3)
    heading_steps: np.ndarray   # (n,) turns in place that keep the cost (`heading_steps`)


@dataclass(frozen=True)
class PlannerConfig:
    """Tunables; defaults are the paper's where it gives one."""

    epsilon: float = 0.8          # Fig. 4: probability of RANDOM_CONFIG
    gd_period: int = 20           # paper: iterations between DIRECTGD calls
    gd_iterations: int = 30       # SLSQP iterations of one DIRECTGD call
    connect_steps: int = 60       # longest RRT_CONNECT / steering run (tsrrt: 20)
    polish_steps: int = 60        # tsrrt: longest objective line-search run
    length_grid: int = 10         # tsrrt: push lengths tried in a line search


@dataclass(frozen=True)
class ProgressInfo:
    elapsed_s: float
    nodes: int
    best_cost: float


@dataclass(frozen=True)
class StallRule:
    """Stop a search whose best cost has improved by less than `tolerance` in the last
    `window_s` seconds, once that best is at or below `ceiling` (a replan keeps searching until
    it is near what the plan it replaces promised), or in the last `far_window_s` seconds
    while it is above it but at or below `far_below` (a longer wait: far from the ceiling the
    search finds its way down in steps seconds apart; and a search that has found no gain worth
    executing, above `far_below`, is left to its budget or a GiveUpRule)."""

    window_s: float
    tolerance: float
    ceiling: float = math.inf
    far_window_s: float = math.inf
    far_below: float = math.inf


@dataclass(frozen=True)
class SoftDeadline:
    """Stop a search at `seconds` if its best cost is at or below `cost` by then, else as soon
    as it is (within the time budget): a task's first plan, which chooses the basin the task
    ends in, gets more time only when it has not yet found a good one."""

    seconds: float
    cost: float


@dataclass(frozen=True)
class GiveUpRule:
    """Stop a search at `seconds` if its best cost is still above `cost`: from where a task's
    plans end, a search that has found nothing worth executing by then rarely does later
    (docs/planner.md, "Closed loop"), and every second it goes on the robot waits."""

    seconds: float
    cost: float


@dataclass(frozen=True)
class PlanStep:
    """One push: object id, primitive 1-6, push length in metres."""

    object_id: str
    primitive: int
    push_length: float


@dataclass(frozen=True)
class PlanResult:
    """Best plan found.

    Attributes:
        states: (m + 1, n, 3) predicted states along the plan, from the start.
        costs: (m + 1,) objective along the plan.
        trace: (elapsed_s, nodes, best_cost) each time the best cost improved.
        stop_reason: "time", "nodes", "cancelled", "converged", "recovered", "stalled" or
            "nothing found".
    """

    mode: str
    seed: int
    steps: tuple[PlanStep, ...]
    states: np.ndarray
    costs: np.ndarray
    nodes: int
    elapsed_s: float
    trace: tuple[tuple[float, int, float], ...]
    stop_reason: str
    lower_bound: float | None = None

    @property
    def best_cost(self) -> float:
        return float(self.costs[-1])

    def gap(self, cost: float | None = None) -> float | None:
        """lower_bound.relative_gap of `cost` (default the final one)."""
        return relative_gap(self.best_cost if cost is None else cost, self.lower_bound)


class Tree:
    """Search tree over joint object states, in growable arrays."""

    def __init__(self, root: np.ndarray, cost: float, capacity: int = 4096) -> None:
        self.states = np.empty((capacity, *root.shape))
        self.parent = np.empty(capacity, int)
        self.action = np.empty((capacity, 3))  # object, primitive, length
        self.cost = np.empty(capacity)
        self.size = 0
        self.add(-1, root, (-1, -1, 0.0), cost)

    def add(self, parent: int, state: np.ndarray, action: tuple[int, int, float],
            cost: float) -> int:
        if self.size == len(self.cost):
            grow = len(self.cost)
            self.states = np.concatenate([self.states, np.empty_like(self.states[:grow])])
            self.parent = np.concatenate([self.parent, np.empty(grow, int)])
            self.action = np.concatenate([self.action, np.empty((grow, 3))])
            self.cost = np.concatenate([self.cost, np.empty(grow)])
        index = self.size
        self.states[index], self.parent[index] = state, parent
        self.action[index], self.cost[index] = action, cost
        self.size += 1
        return index

    def depths(self) -> np.ndarray:
        """(size,) pushes from the root to each node (a parent is always added first)."""
        depth = np.zeros(self.size, int)
        for index in range(1, self.size):
            depth[index] = depth[self.parent[index]] + 1
        return depth

    def path(self, index: int) -> list[int]:
        """Node indices from the root to `index`."""
        nodes = []
        while index >= 0:
            nodes.append(index)
            index = int(self.parent[index])
        return nodes[::-1]


class _Stop(Exception):
    """Raised inside a search when the budget is spent or the caller cancelled."""

    def __init__(self, reason: str) -> None:
        self.reason = reason


class _Search:
    """Shared machinery: the tree, the metric, extensions, budget and anytime best."""

    def __init__(self, problem: PlanningProblem, mode: str, seed: int, config: PlannerConfig,
                 time_budget_s: float | None, max_nodes: int | None, progress: Progress | None,
                 cancel: Cancel | None, orientation_weights: np.ndarray,
                 good_enough_cost: float | None = None,
                 stall: StallRule | None = None, shortest_within: float = 0.0,
                 soft_deadline: SoftDeadline | None = None,
                 give_up: GiveUpRule | None = None, push_cost: float = 0.0) -> None:
        self.problem, self.mode, self.seed, self.config = problem, mode, seed, config
        self.finishing_problem = problem   # what the pushes after the search are checked on
        self.good_enough_cost = good_enough_cost
        self.stall = stall
        self.soft_deadline = soft_deadline
        self.give_up = give_up
        self.shortest_within = shortest_within
        self.push_cost = push_cost
        self.rng = np.random.default_rng(seed)
        self.time_budget_s, self.max_nodes = time_budget_s, max_nodes
        self.deadline_s = time_budget_s  # the result is due then (tsrrt searches for less)
        self.search_share = 1.0  # of a budget, the part spent searching (tsrrt: the rest shortens)
        self.progress = progress
        self.cancelled = (cancel.is_set if isinstance(cancel, threading.Event) else cancel)
        self.began = time.perf_counter()
        self.weights = orientation_weights  # (n,)
        self.length_grid = np.geomspace(problem.min_length, problem.max_length,
                                        config.length_grid)   # push lengths of line searches
        start_cost = float(problem.objective.cost(problem.start))
        self.tree = Tree(problem.start, start_cost)
        self.best, self.best_cost = 0, start_cost
        self.trace: list[tuple[float, int, float]] = [(0.0, 1, start_cost)]
        self.checks = 0

    # -------------------------------------------------------------- bookkeeping
    def elapsed(self) -> float:
        return time.perf_counter() - self.began

    def check_budget(self) -> None:
        self.checks += 1
        if self.cancelled is not None and self.cancelled():
            raise _Stop("cancelled")
        if self.max_nodes is not None and self.tree.size >= self.max_nodes:
            raise _Stop("nodes")
        if self.time_budget_s is not None and self.elapsed() >= self.search_time_limit():
            raise _Stop("time")
        if self.stall is not None and self.stalled(self.stall):
            raise _Stop("stalled")
        soft = self.soft_deadline
        if (soft is not None and self.best_cost <= soft.cost
                and self.elapsed() >= soft.seconds * self.search_share):
            self.deadline_s = soft.seconds
            raise _Stop("time")
        give_up = self.give_up
        if (give_up is not None and self.best_cost > give_up.cost
                and self.elapsed() >= give_up.seconds):
            self.deadline_s = self.elapsed()   # nothing to shorten: the plan is not worth it
            raise _Stop("nothing found")
        if self.progress is not None and self.checks % 50 == 0:
            self.progress(ProgressInfo(self.elapsed(), self.tree.size, self.best_cost))

    def search_time_limit(self) -> float:
        """Seconds into the time budget at which the search stops (the rest shortens)."""
        return self.time_budget_s

    def past_deadline(self) -> bool:
        """Whether the result is due: the time budget is over or the caller cancelled. The
        shortening after the search stops here, whatever it has left to fold."""
        return ((self.cancelled is not None and self.cancelled())
                or (self.deadline_s is not None and self.elapsed() >= self.deadline_s))

    def stalled(self, rule: StallRule) -> bool:
        now = self.elapsed()
        if self.best_cost <= rule.ceiling:
            window = rule.window_s
        elif self.best_cost <= rule.far_below:
            window = rule.far_window_s
        else:
            return False
        if now < window:
            return False
        then = bisect.bisect_right(self.trace, now - window, key=lambda entry: entry[0])
        return self.trace[max(then - 1, 0)][2] - self.best_cost < rule.tolerance

    def add_node(self, parent: int, state: np.ndarray, action: tuple[int, int, float]) -> int:
        self.check_budget()
        cost = float(self.problem.objective.cost(state))
        index = self.tree.add(parent, state, action, cost)
        if cost < self.best_cost:
            self.best, self.best_cost = index, cost
            self.trace.append((self.elapsed(), self.tree.size, cost))
            if self.progress is not None:
                self.progress(ProgressInfo(self.elapsed(), self.tree.size, cost))
            if self.good_enough_cost is not None and cost <= self.good_enough_cost:
                raise _Stop("recovered")
        return index

    def follow(self, node: int, path: list[Push]) -> int:
        """Add the pushes of `path` to the tree from `node`; returns the last node."""
        for push in path:
            node = self.add_node(node, self.problem.apply(self.tree.states[node], *push), push)
        return node

    def warm_start(self, steps: list[Push]) -> None:
        """Add the prefix of `steps` that is valid from the start, up to its lowest cost, as a
        branch of the tree: replanning after a divergence keeps what the last plan knew. Not
        beyond its lowest cost: from a state the old plan did not expect (an object bumped
        away), its pushes may wander off, and a branch that ends uphill of its best is a
        detour the closed loop refuses to execute (steps_worth_executing)."""
        problem, state, valid = self.problem, self.tree.states[0], []
        for o, p, length in steps:
            if not problem.pushes_valid(state, np.array([o]), np.array([p]),
                                        np.array([length]))[0]:
                break
            state = problem.apply(state, o, p, length)
            valid.append(((o, p, length), state))
        costs = [self.tree.cost[0], *problem.objective.cost(
            np.array([state for _, state in valid]).reshape(-1, *state.shape))]
        node = 0
        for push, state in valid[:int(np.argmin(costs))]:
            node = self.add_node(node, state, push)

    # -------------------------------------------------------------- Eq. 11 and sampling
    def rho(self, states: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Eq. 11: weighted distance (...,) of states (..., n, 3) to target (n, 3)."""
        delta = states - target
        angle = self.problem.angle_error(delta[..., 2]) * self.weights
        return np.sqrt((delta[..., :2] ** 2).sum(axis=(-1, -2)) + (angle**2).sum(axis=-1))

    def nearest_neighbor(self, sample: np.ndarray) -> int:
        return self.nearest_from(1, sample)

    def nearest_from(self, first: int, sample: np.ndarray) -> int:
        """The node nearest `sample` under rho among the root and nodes `first` onwards."""
        return nearest_under_rho(self.tree.states, first, self.tree.size,
                                 np.ascontiguousarray(sample, float), self.weights,
                                 self.problem.angle_period)

    def random_config(self) -> np.ndarray:
        return random_state(self.problem, self.rng)

    def directgd(self, node: int) -> tuple[np.ndarray, float] | None:
        """DIRECTGD: constrained gradient descent from a node; None if it ends infeasible."""
        self.check_budget()
        state, cost, feasible = local_minimum(self.problem, self.tree.states[node],
                                              self.config.gd_iterations)
        return (state, cost) if feasible else None

    def extend(self, near: int, sample: np.ndarray, lengths: np.ndarray) -> int | None:
        """Add the first valid state-action pair (sorted by rho to the sample) that is closer
        than its parent; `lengths` (k,) per action in problem.action_* order."""
        problem, state = self.problem, self.tree.states[near]
        objects, primitives = problem.action_objects, problem.action_primitives
        poses = problem.predict(state, objects, primitives, lengths)
        candidates = np.repeat(state[None], len(objects), axis=0)
        candidates[np.arange(len(objects)), objects] = poses
        distance = self.rho(candidates, sample)
        order = np.argsort(distance, kind="stable")
        order = order[distance[order] < self.rho(state, sample) - 1e-12]
        for chunk in np.array_split(order, max(1, math.ceil(len(order) / 8))):
            if len(chunk) == 0:
                continue
            valid = problem.pushes_valid(state, objects[chunk], primitives[chunk],
                                         lengths[chunk])
            if valid.any():
                k = chunk[int(np.argmax(valid))]
                return self.add_node(near, candidates[k],
                                     (int(objects[k]), int(primitives[k]), float(lengths[k])))
        return None

    # -------------------------------------------------------------- result
    def result(self, stop_reason: str, lower_bound: float | None) -> PlanResult:
        path = self.tree.path(self.chosen_node())
        actions = self.tree.action[path[1:]]
        steps = [(int(a[0]), int(a[1]), float(a[2])) for a in actions]
        if self.mode == "tsrrt":
            # each push folded into an earlier one it finishes, as the finishing pushes are
            stop = self.past_deadline
            steps = absorb_pushes(self.problem, self.shortcut(steps), first=1, stop=stop)
            finished = absorb_pushes(self.finishing_problem, steps + self.finishing_polish(steps),
                                     first=len(steps), stop=stop)
            # what the finish folded into may let pushes of the plan fold as well
            finished = absorb_pushes(self.finishing_problem, finished, first=1, stop=stop)
            # asked for a short plan, take the finish only where it is free
            if not self.counts_pushes() or len(finished) <= len(steps):
                steps = finished
        states = simulate(self.problem, steps)
        costs = np.asarray(self.problem.objective.cost(states))
        if costs[-1] < self.trace[-1][2]:   # the finishing polish's gain, at the time it came
            self.trace.append((self.elapsed(), self.tree.size, float(costs[-1])))
        return PlanResult(
            mode=self.mode, seed=self.seed,
            steps=tuple(PlanStep(self.problem.objects.ids[o], p, length)
                        for o, p, length in steps),
            states=states, costs=costs,
            nodes=self.tree.size, elapsed_s=self.elapsed(), trace=tuple(self.trace),
            stop_reason=stop_reason, lower_bound=lower_bound)

    def counts_pushes(self) -> bool:
        """Whether the plan's length counts in where it goes (`shortest_within`, `push_cost`)."""
        return self.shortest_within > 0.0 or self.push_cost > 0.0

    def chosen_node(self) -> int:
        """The best node, or with `shortest_within` the node with the fewest pushes among
        those within that of the best cost (the cheapest of them); with `push_cost`, costs are
        charged that much per push (tree depth) first, and the least charged cost is the best.
        With the budget of a task's first plan the best node may lie at the end of a long
        detour that gains next to nothing over a state one push away (two_boxes: a 28-push
        plan to 0.0009 where 0.0009 was one push away), and a robot pays for every push."""
        if not self.counts_pushes():
            return self.best
        costs = self.tree.cost[: self.tree.size]
        depths = self.tree.depths()
        charged = costs + self.push_cost * depths
        near = np.nonzero(charged <= charged.min() + self.shortest_within)[0]
        return int(near[np.lexsort((costs[near], depths[near]))[0]])

    def finishing_polish(self, steps: list[Push]) -> list[Push]:
        """POLISH of the plan's end state over every candidate push, not the best 64. By a
        table edge the pushes that gain most are the longer ones, past it: in a tset6 end
        state the best 64 were all such, and the plan left every plate 2 mm short of its corner
        (3.8 % above the bound, 3.1 % after the five 2-mm pushes it had missed). The search
        keeps the limit: polishing that deep all along sent 6 of 16 tset6 seeds (350 nodes)
        into the walled-in basin against 3. Near the targets it leaves out the pushes off the
        table first (`polish`).

        Its pushes (and the folds after it) may move a stranded object further in
        (`finishing_problem`, no retreat limit): 2 mm short of tset12's far corners a plate is
        stranded, and the shortest push, 2 mm, is more than the limit's 1 mm. At node budgets
        (tset12 seeds 0-31 at 3000, tset6 seeds 0-39 at 1500) no plan ended higher; tset12's
        mean gap fell from 14.44 to 14.23 %, seed 22's from 2.18 to 1.63 %, and tset6's plans
        from a median 95 to 91 pushes (more of the finish folds into earlier pushes)."""
        return polish_pushes(self.finishing_problem, simulate(self.problem, steps)[-1],
                             self.length_grid, self.config.polish_steps, limit=None)

    def shortcut(self, steps: list[Push]) -> list[Push]:
        """Shorten the plan: re-steer from an early state of the plan straight to its final
        state (then polish), keeping the result when it has fewer pushes and ends within
        SHORTCUT_TOLERANCE of the original cost; then shorten runs of pushes on one object,
        merge runs of the same push, and shortcut random pairs of states (`shortcut_pairs`,
        in the SHORTCUT_SHARE of the time budget the search leaves). Before that, a plan is
        cut at its first state within PLAN_COST_TOLERANCE of its end cost and polished from
        there, when that is shorter: each push costs the robot a second or more, a 0.3 %
        better end rarely pays for it."""
        problem = self.problem
        states = simulate(problem, steps)
        costs = np.asarray(problem.objective.cost(states))
        final_cost = float(costs[-1])
        allowed = final_cost + SHORTCUT_TOLERANCE * max(abs(final_cost), 1e-12)
        near_final = final_cost + PLAN_COST_TOLERANCE * max(abs(final_cost), 1e-12)
        first_near = int(np.argmax(costs <= near_final))
        if first_near < len(steps):
            # a plan that got near its end cost early, then took a detour (parking objects)
            # to gain a little: stop there and polish instead
            polished = polish_pushes(problem, states[first_near], self.length_grid,
                                     CUT_POLISH_PUSHES)
            if first_near + len(polished) < len(steps):
                steps = steps[:first_near] + polished
                states = simulate(problem, steps)
                final_cost = float(problem.objective.cost(states[-1]))
                allowed = final_cost + SHORTCUT_TOLERANCE * max(abs(final_cost), 1e-12)
        for k in sorted({0, len(steps) // 4, len(steps) // 2}):
            if self.past_deadline():
                break
            state, replacement = states[k], []
            while len(replacement) < len(steps) - k:
                push = steer_push(problem, state, states[-1], self.weights)
                if push is None:
                    push = polish_push(problem, state, self.length_grid)
                    if push is None:
                        break
                replacement.append(push)
                state = problem.apply(state, *push)
            if (len(replacement) < len(steps) - k
                    and float(problem.objective.cost(state)) <= allowed):
                steps = steps[:k] + replacement
                break
        stop = self.past_deadline
        steps = merge_runs(problem, shorten_runs(problem, steps, self.weights, allowed, stop),
                           stop)
        return merge_runs(problem, self.shortcut_pairs(steps), stop)

    def shortcut_pairs(self, steps: list[Push]) -> list[Push]:
        """Random shortcutting, as for RRT paths: pick two states i < j of the plan and steer
        each object the pushes between them move straight to its pose at j (closed form, at
        most PAIR_PUSHES_PER_OBJECT pushes each, in the order they first move or its reverse);
        keep it when that takes fewer pushes and the rest of the plan, re-aimed at its poses
        (`track_plan`), still ends within PAIR_COST_TOLERANCE of the plan's end cost. A tree
        path zigzags through the detours of every extension it was grown by. Stretches of
        3 to PAIR_LONGEST_SPAN pushes, their lengths drawn log-uniform: of the shortcuts that
        worked on tset6, 77 of 79 replaced fewer than 32 pushes, and a uniform draw spent
        most attempts on longer ones. Up to PAIR_ATTEMPTS_PER_PUSH attempts per push, until
        FOLD_SHARE of the time left is all that is left (absorb_pushes folds in it: with none
        left, a tset12 plan kept 455 pushes where folding had made 372) or the caller cancels."""
        problem = self.problem
        rng = np.random.default_rng(self.seed)
        until = None if self.deadline_s is None else (
            self.deadline_s - FOLD_SHARE * max(self.deadline_s - self.elapsed(), 0.0))
        states = list(simulate(problem, steps))
        final_cost = float(problem.objective.cost(states[-1]))
        allowed = final_cost + PAIR_COST_TOLERANCE * max(abs(final_cost), 1e-12)
        for _ in range(PAIR_ATTEMPTS_PER_PUSH * len(steps)):
            if len(steps) < 3 or self.past_deadline() or (
                    until is not None and self.elapsed() >= until):
                break
            i = int(rng.integers(0, len(steps) - 2))
            longest = min(len(steps) - i, PAIR_LONGEST_SPAN)
            j = i + int(np.rint(np.exp(rng.uniform(np.log(3), np.log(longest)))))
            order = list(dict.fromkeys(o for o, _, _ in steps[i:j]))
            if rng.random() < 0.5:
                order.reverse()
            state, replacement = states[i], []
            for o in order:
                pushes, state = steer_object(problem, state, states[j], self.weights, o,
                                             PAIR_PUSHES_PER_OBJECT, PAIR_TOLERANCE)
                replacement += pushes
            if len(replacement) >= j - i:
                continue
            tracked = track_plan(problem, state, steps[j:], states[j:], self.weights)
            if tracked is None:
                continue
            rest, rest_states = tracked
            if (len(replacement) + len(rest) < len(steps) - i
                    and float(problem.objective.cost(rest_states[-1])) <= allowed):
                steps = steps[:i] + replacement + rest
                states = states[:i] + replay_from(problem, states[i], replacement)[:-1] + (
                    rest_states)
        return steps


def shorten_runs(problem: PlanningProblem, steps: list[Push], weights: np.ndarray,
                 allowed: float, stop: Callable[[], bool] = lambda: False) -> list[Push]:
    """Replace each run of three or more consecutive pushes on one object by fewer pushes
    steered (closed form, that object only) from the run's first state to its last pose, when
    the whole plan then replays validly and ends at cost <= `allowed`. REARRANGE's searched
    paths hug obstacles in short steps that a few long pushes often replace. Stops when `stop`
    says so (the plan as shortened so far)."""
    states = list(simulate(problem, steps))
    k = 0
    while k < len(steps) and not stop():
        end = k
        while end < len(steps) and steps[end][0] == steps[k][0]:
            end += 1
        if end - k >= 3:
            o = steps[k][0]
            goal = states[k].copy()
            goal[o] = states[end][o]
            replacement, _ = steer_object(problem, states[k], goal, weights, o, end - k - 1)
            if replacement and len(replacement) < end - k:
                replayed = replay_from(problem, states[k], replacement + steps[end:])
                if replayed is not None and float(problem.objective.cost(replayed[-1])) <= (
                        allowed):
                    steps = steps[:k] + replacement + steps[end:]
                    states = states[:k] + replayed
                    end = k + len(replacement)
        k = end
    return steps


def merge_runs(problem: PlanningProblem, steps: list[Push],
               stop: Callable[[], bool] = lambda: False) -> list[Push]:
    """Merge consecutive pushes of the same primitive on the same object when the merged plan
    is valid and ends no worse (only the plan from the merge on is re-checked), until `stop`
    says so."""
    states = list(simulate(problem, steps))
    reference = float(problem.objective.cost(states[-1]))
    k = 0
    while k < len(steps) - 1 and not stop():
        (o1, p1, l1), (o2, p2, l2) = steps[k], steps[k + 1]
        if (o1, p1) == (o2, p2) and l1 + l2 <= problem.max_lengths[o1]:
            tail = [(o1, p1, l1 + l2)] + steps[k + 2:]
            replayed = replay_from(problem, states[k], tail)
            if replayed is not None and float(problem.objective.cost(replayed[-1])) <= (
                    reference + 1e-12):
                steps = steps[:k] + tail
                states = states[:k] + replayed
                reference = float(problem.objective.cost(states[-1]))
                continue
        k += 1
    return steps


def absorb_pushes(problem: PlanningProblem, steps: list[Push], first: int,
                  stop: Callable[[], bool] = lambda: False) -> list[Push]:
    """Fold each push from `first` on into the latest earlier push of the same object and
    primitive, lengthened by as much, when the plan stays valid and ends no worse. The
    finishing polish's 2-mm pushes mostly finish what such a push stopped short of (a plate
    aimed 2 mm inside its corner); appended, they made tset6 plans 5-10 pushes longer. So do
    POLISH's and REARRANGE's short pushes mid-plan (a shortened plan is folded from its
    second push: tset6, 40 seeds of 4 s, 50 pushes against 54-58). Passes repeat until one
    folds nothing: a fold changes the states after it and lowers the cost to match, which can
    let a push an earlier pass kept fold too.

    Each fold replays the plan from the push it folds into, so a pass costs about the square of
    the plan's length: a 787-push tset12 plan took 7.6 s of folding after a 10-s budget. It
    stops when `stop` says so, with the pushes folded by then."""
    states = list(simulate(problem, steps))
    reference = float(problem.objective.cost(states[-1]))
    k, folded = first, False
    while (k < len(steps) or folded) and not stop():
        if k >= len(steps):
            k, folded = first, False
            continue
        o, p, length = steps[k]
        earlier = [j for j in range(k) if steps[j][:2] == (o, p)]
        if earlier and steps[earlier[-1]][2] + length <= problem.max_lengths[o] + 1e-12:
            j = earlier[-1]
            tail = [(o, p, steps[j][2] + length)] + steps[j + 1:k] + steps[k + 1:]
            replayed = replay_from(problem, states[j], tail)
            if replayed is not None and float(problem.objective.cost(replayed[-1])) <= (
                    reference + 1e-12):
                steps, states = steps[:j] + tail, states[:j] + replayed
                reference = float(problem.objective.cost(states[-1]))
                folded = True
                continue
        k += 1
    return steps


def track_plan(problem: PlanningProblem, state: np.ndarray, steps: list[Push],
               planned: list[np.ndarray], weights: np.ndarray
               ) -> tuple[list[Push], list[np.ndarray]] | None:
    """Follow a plan's `steps` from `state`, near planned[0] where they began, aiming each push
    at the pose it gave its object in the plan (planned[m + 1]): the same object and primitive,
    the valid length of the planned one, the closed-form one and TRACK_FRACTIONS of it that ends
    nearest. When none is valid, the object is first steered back towards its planned pose
    before the push (TRACK_REPAIR_PUSHES). Returns the pushes and the states [state, ...] they
    lead to, or None when a push cannot be made even then. A shortcut leaves objects a
    millimetre or a fraction of a degree off the plan's poses, and the plan's later pushes,
    replayed as they were, graze a neighbour in a tight end state: tset6's 10-s plans were then
    83 pushes long in the median, 67 when re-aimed."""
    pushes: list[Push] = []
    states = [state]
    for m, (o, p, length) in enumerate(steps):
        push = _aimed_push(problem, states[-1], o, p, length, planned[m + 1][o], weights[o])
        if push is None:
            repair, repaired = steer_object(problem, states[-1], planned[m], weights, o,
                                            TRACK_REPAIR_PUSHES, TRACK_REPAIR_TOLERANCE)
            push = _aimed_push(problem, repaired, o, p, length, planned[m + 1][o], weights[o])
            if not repair or push is None:
                return None
            pushes += repair
            states += replay_from(problem, states[-1], repair)[1:]
        pushes.append(push)
        states.append(problem.apply(states[-1], *push))
    return pushes, states


def _aimed_push(problem: PlanningProblem, state: np.ndarray, index: int, primitive: int,
                length: float, goal: np.ndarray, weight: float) -> Push | None:
    """track_plan's push of object `index` with `primitive` towards its pose `goal` (3,)."""
    u = problem.push_directions(state, np.array([index]), np.array([primitive]))[0]
    error = goal - state[index]
    error[2] = shortest_turn(error[2], problem.angle_period[index])
    w2 = np.array([1.0, 1.0, weight ** 2])
    ideal = float((w2 * error * u).sum() / max((w2 * u * u).sum(), 1e-12))
    lengths = np.unique(np.clip([length, *(ideal * f for f in TRACK_FRACTIONS)],
                                problem.min_length, problem.max_lengths[index]))
    objects, primitives = np.full(len(lengths), index), np.full(len(lengths), primitive)
    valid = problem.pushes_valid(state, objects, primitives, lengths)
    if not valid.any():
        return None
    poses = problem.predict(state, objects[valid], primitives[valid], lengths[valid])
    nearest = int(np.argmin(object_error(problem, index, poses, goal, weight)))
    return index, primitive, float(lengths[valid][nearest])


def replay_from(problem: PlanningProblem, state: np.ndarray, steps: list[Push]
                ) -> list[np.ndarray] | None:
    """States [state, ...] (m + 1) along `steps` from `state`, or None if a push is invalid."""
    states = [state]
    for o, p, length in steps:
        if not problem.pushes_valid(states[-1], np.array([o]), np.array([p]),
                                    np.array([length]))[0]:
            return None
        states.append(problem.apply(states[-1], o, p, length))
    return states


def simulate(problem: PlanningProblem, steps: list[tuple[int, int, float]]) -> np.ndarray:
    """Predicted states (m + 1, n, 3) of a plan of (object index, primitive, length) steps."""
    states = [problem.start]
    for o, p, length in steps:
        states.append(problem.apply(states[-1], o, p, length))
    return np.array(states)


def simulate_from(problem: PlanningProblem, state: np.ndarray, steps: list[Push]) -> np.ndarray:
    """The state (n, 3) `steps` lead to from `state` (predicted, not checked)."""
    for o, p, length in steps:
        state = problem.apply(state, o, p, length)
    return state


def can_move(problem: PlanningProblem, state: np.ndarray, index: int) -> bool:
    """Whether object `index` has any valid push in `state` (the shortest, of every
    primitive): not wedged against neighbours or the table edge, nor in the arm's dead zone."""
    primitives = problem.primitives_of[index]
    return bool(problem.pushes_valid(state, np.full(len(primitives), index), primitives,
                                     np.full(len(primitives), problem.min_length)).any())


class _PaperSearch(_Search):
    """Fig. 4 with nominal-length pushes; mode paper-nogd gives the no-GD variant."""

    def run(self) -> None:
        problem, config = self.problem, self.config
        use_gd = self.mode == "paper"
        lengths = np.full(len(problem.action_objects), problem.nominal_length)
        s_gd = None
        iteration = 0
        while True:
            if use_gd and iteration % config.gd_period == 0:
                found = self.directgd(self.tree.size - 1)  # from the newest leaf
                if found is not None:
                    s_gd = found[0]
                    if found[1] < self.best_cost:
                        self.rrt_connect(s_gd, lengths)
            iteration += 1
            if s_gd is not None and self.rng.random() > config.epsilon:
                sample = s_gd
            else:
                sample = self.random_config()
            self.check_budget()
            self.extend(self.nearest_neighbor(sample), sample, lengths)

    def rrt_connect(self, target: np.ndarray, lengths: np.ndarray) -> None:
        node = self.nearest_neighbor(target)
        for _ in range(self.config.connect_steps):
            added = self.extend(node, target, lengths)
            if added is None:
                return
            node = added


class _GreedySearch(_Search):
    """Hill climbing over nominal pushes: the cheapest valid improving push, until none."""

    def run(self) -> None:
        problem = self.problem
        lengths = np.full(len(problem.action_objects), problem.nominal_length)
        node = self.best   # the root, or the end of the warm start's best prefix
        while True:
            improved = self.best_push(node, lengths)
            if improved is None:
                raise _Stop("converged")
            node = improved

    def best_push(self, node: int, lengths: np.ndarray) -> int | None:
        problem, state = self.problem, self.tree.states[node]
        objects, primitives = problem.action_objects, problem.action_primitives
        candidates = np.repeat(state[None], len(objects), axis=0)
        candidates[np.arange(len(objects)), objects] = problem.predict(state, objects,
                                                                       primitives, lengths)
        costs = problem.objective.cost(candidates)
        order = np.argsort(costs, kind="stable")
        order = order[costs[order] < self.tree.cost[node] - 1e-12]
        self.check_budget()
        if len(order) == 0:
            return None
        valid = problem.pushes_valid(state, objects[order], primitives[order], lengths[order])
        if not valid.any():
            return None
        k = order[int(np.argmax(valid))]
        return self.add_node(node, candidates[k],
                             (int(objects[k]), int(primitives[k]), float(lengths[k])))


class _TsrrtSearch(_Search):
    """The improved planner: an RRT whose samples are targets, with a steering function.

    Targets are local minima of the objective: the continuous optimum (when given) with
    interchangeable objects permuted to the best node's nearest assignment, and DIRECTGD
    restarted from varied nodes. Each round samples either a target (probability 1 - epsilon)
    or a target with one or two objects moved to random poses - the escaping move that pushes a
    blocking object aside at a temporary cost - extends the nearest node towards it with STEER
    (objects one at a time in random order, variable-length pushes whose lengths minimise rho in
    closed form), and POLISHes the best node with line searches on the objective.

    "The best node" in the search's choices is its lead: the best node of its current epoch.
    A search still far from the targets at RESTART_AT of its budget starts over from the root
    once (`restart`); the plan goes to the best node of the whole tree.
    """

    def __init__(self, *args, target: np.ndarray | None,
                 previous_goal: np.ndarray | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.search_share = 1.0 - SHORTCUT_SHARE
        self.far_search_limit_s = None
        if self.time_budget_s is not None:
            self.far_search_limit_s = self.time_budget_s * (1.0 - SHORTCUT_SHARE_FAR)
            self.time_budget_s *= self.search_share
        self.previous_goal = previous_goal
        self.groups = interchangeable_groups(self.problem)
        self.targets: list[Target] = []
        self.best_target_cost = math.inf   # the lowest cost of `targets`
        self.polished: set[int] = set()  # nodes where polishing found nothing more
        self.gd_failures = 0   # DIRECTGD descents in a row that ended infeasible (gd_period)
        self.descended_best = -1   # the last lead node DIRECTGD started from (descent_start)
        self.max_parkings = max(MIN_PARKINGS, self.problem.n // OBJECTS_PER_PARKING)
        # the node the search extends from (`best` but for a restart) and where its epoch
        # begins: nodes before that, but the root, are no longer extended (`restart`)
        self.lead, self.lead_cost = self.best, self.best_cost
        self.epoch_start = 1
        self.restarted = False
        if target is not None:
            self.add_target(np.asarray(target, float),
                            float(self.problem.objective.cost(target)))
            self.problem = self.problem.with_face_allowance(
                [kept.state for kept in self.targets], self.groups)
            # the retreat limit keeps a stranded object where the search's later pushes can
            # still reach it; the plan's end has none, and a plate 2 mm short of a far corner
            # (TARGET_INSET), where the arm reaches neither face that could push it back,
            # could not be finished there (`finishing_polish`)
            self.finishing_problem = self.problem.with_retreat_limit(math.inf)
        self.memo = RearrangeMemo(self.problem)   # REARRANGE's questions, asked again and again

    def run(self) -> None:
        if self.previous_goal is not None:
            # a replan: where the replaced plan was going is known to be reachable by pushing
            self.polish(self.rearrange(0, self.previous_goal))
        if self.targets:
            self.polish(self.rearrange(0, self.choose_target(self.problem.start)))
        self.descend_from(0)
        rounds = 0
        while True:
            rounds += 1
            if not self.restarted and self.budget_spent() >= RESTART_AT and not self.near_targets(
                    self.lead_cost, RESTART_FAR):
                self.restart()
            if not self.targets or rounds % self.gd_period() == 0:
                self.descend_from(self.descent_start())
            if not self.targets:
                # DIRECTGD has ended infeasible from every node so far (without a `target`, a
                # crowded start can do that every time): grow the tree towards RANDOM_CONFIG,
                # as Fig. 4 does, so that its next descent starts from somewhere else.
                sample = self.random_config()
                self.steer(self.nearest_neighbor(sample), sample)
            else:
                self.extend_towards_a_target()
            if self.lead not in self.polished:
                self.polished.add(self.polish(self.lead))

    def add_node(self, parent: int, state: np.ndarray, action: tuple[int, int, float]) -> int:
        """_Search.add_node, keeping the lead: every node added is in the current epoch."""
        index = super().add_node(parent, state, action)
        if self.tree.cost[index] < self.lead_cost:
            self.lead, self.lead_cost = index, float(self.tree.cost[index])
        return index

    def budget_spent(self) -> float:
        """The share of the search's budget spent: of its nodes when it has a node budget,
        else of its time as far from the targets (`search_time_limit`), else 0. A node budget
        makes a search repeatable (the closed loop's `planning_max_nodes`), so with one the
        restart does not look at the clock."""
        if self.max_nodes is not None:
            return self.tree.size / self.max_nodes
        if self.far_search_limit_s is not None:
            return self.elapsed() / self.far_search_limit_s
        return 0.0

    def restart(self) -> None:
        """Start the search over from the root, once, keeping the targets and the tree (the
        best node found so far is still the plan unless the new epoch beats it): from then on
        only the root and the nodes added after this are extended. Where a tset12 search ends
        is mostly settled early: a search still more than RESTART_FAR above the best target
        at RESTART_AT of its budget mostly has an object walled in (platter_3 left in its
        corner by the plates parked around it), and extending that tree rarely gets it out. Of
        96 seeds of 8000 nodes, 57 were more than 15 % above the bound at 3000 nodes and 12 %
        of them ended within 2 % of it, where 21 % of all seeds get within 2 % in a fresh
        search of 5000 nodes. With the restart 43 of the 96 end within 2 %, against 36; on
        seeds the heuristics were not tuned on the gain is small (96-191 at 6000 nodes: 22
        against 22; docs/planner.md, *A restart*)."""
        self.restarted = True
        self.epoch_start = self.tree.size
        self.lead, self.lead_cost = 0, float(self.tree.cost[0])
        self.descended_best = -1

    def random_node(self) -> int:
        """A node of the current epoch or the root, uniformly."""
        index = int(self.rng.integers(self.epoch_start - 1, self.tree.size))
        return 0 if index < self.epoch_start else index

    def nearest_neighbor(self, sample: np.ndarray) -> int:
        """The node of the current epoch (or the root) nearest `sample` under rho."""
        return self.nearest_from(self.epoch_start, sample)

    def descend_from(self, node: int) -> None:
        """DIRECTGD from `node`: its minimum becomes a target; a descent that ends infeasible
        makes the next one wait longer (gd_period)."""
        found = self.directgd(node)
        if found is None:
            self.gd_failures += 1
        else:
            self.gd_failures = 0
            self.add_target(*found)

    def descent_start(self) -> int:
        """Where DIRECTGD starts: a random node (varied nodes, other basins to get out by),
        or the best node once it is within FAR_FROM_TARGETS of the best target, once per best
        node (a descent from the same node finds the same minimum)."""
        if not self.far_from_targets() and self.lead != self.descended_best:
            self.descended_best = self.lead
            return self.lead
        return self.random_node()

    def gd_period(self) -> int:
        """Rounds between DIRECTGD calls: a quarter of gd_period while the best node is more
        than FAR_FROM_TARGETS above the best target. On tset6 such a node has objects walled
        in, and a descent from another node is a target with another arrangement to get out
        by; nearer, the descents' time is better spent on the search (40 seeds: with
        gd_period always 3.05 % at 1 s and 1 % in 2.42 s (median), with half of it while far
        2.45 % and 2.93 s, with a quarter 2.18 % and 2.39 s; half of it always: 1 % in 3.11 s
        over 20 seeds).

        Doubled for each descent in a row that ended infeasible beyond GD_FAILURES_TOLERATED
        (up to GD_BACK_OFF_LIMIT doublings): on tset12 nearly every descent of gd_iterations
        ends a hair inside an overlap, and the descents, two per call, took a quarter of the
        search's time for nothing (32 seeds of 10 s: median gap 18.3 % against 26.5 %, 291
        nodes/s against 183; tset6 and clean unchanged). clean's descents fail one in four, at
        most three in a row, and doubling from the first failure cost it (8 seeds: 2.38 % and
        46 pushes against 2.11 % and 35)."""
        back_off = 2 ** min(max(self.gd_failures - GD_FAILURES_TOLERATED, 0),
                            GD_BACK_OFF_LIMIT)
        if self.far_from_targets():
            return max(1, self.config.gd_period // 4) * back_off
        return self.config.gd_period * back_off

    def far_from_targets(self) -> bool:
        """Whether the lead node is more than FAR_FROM_TARGETS above the best target."""
        return not self.near_targets(self.lead_cost)

    def near_targets(self, cost: float, share: float = FAR_FROM_TARGETS) -> bool:
        """Whether `cost` is within `share` of the best target (True while there is no
        target)."""
        best_target = self.best_target_cost
        return cost <= best_target + share * abs(best_target)

    def search_time_limit(self) -> float:
        """The search stops at 1 - SHORTCUT_SHARE of the time budget, or at 1 -
        SHORTCUT_SHARE_FAR while its best node is more than SHORTCUT_NEAR above the best
        target: a plan that far above them gains more from searching on than from being
        shortened. On tset12 the best cost falls in steps until the end of a 10-s budget
        (seeds 0, 2 and 3 of 20 s: 15.6, 24.7 and 31.5 % above the bound at 8 s, 8.5, 24.7 and
        29.5 % at 10 s), also within 5 % of the bound, where the search stopped at 75 % of
        the budget until session 45. When the plan's length counts (`counts_pushes`: a robot
        pays for every push), shortening keeps its share from FAR_FROM_TARGETS on, as before:
        with SHORTCUT_NEAR there too, two fresh clean demos took 70 and 71 s with 35 and 42
        pushes, against 47 s and 22 pushes for the code before."""
        near = FAR_FROM_TARGETS if self.counts_pushes() else SHORTCUT_NEAR
        if self.near_targets(self.best_cost, near):
            return self.time_budget_s
        return self.far_search_limit_s

    def extend_towards_a_target(self) -> None:
        """One round with targets: from the lead node or a random one, REARRANGE towards the
        target chosen for it and POLISH, or (probability epsilon / 2) STEER towards that target
        with one or two objects moved to random poses."""
        if self.rng.random() < 0.5:
            node = self.lead
        else:
            node = self.random_node()
        target = self.choose_target(self.tree.states[node])
        if self.rng.random() < self.config.epsilon / 2:
            sample = target.copy()
            moved = self.rng.choice(self.problem.n, size=min(2, self.problem.n),
                                    replace=False)[: int(self.rng.integers(1, 3))]
            sample[moved] = self.random_config()[moved]
            self.steer(self.nearest_neighbor(sample), sample)
        else:
            self.polish(self.rearrange(node, target))

    def directgd(self, node: int) -> tuple[np.ndarray, float] | None:
        """DIRECTGD from a node with every object that is short of a face the arm reaches there
        kept in place along that face's push, or held where it is when it is short of more
        than one (if that descent ends infeasible, free). No push moves such an object along
        that line, and the face rule keeps it from being pushed back against it, so a minimum
        that moves it there is a target the search cannot reach: tset6's platter_2 starts in
        the blind spot, every optimum the free descent found had it 2-8 cm further out, and 4
        of 10 seeds sat 23-25 % above the bound for 1-2 s, plate_1 walled in behind platters
        centred for those targets. Held entirely, it gave targets 2.4 % above the bound where
        keeping it along the line alone reaches the bound's cost (docs/planner.md, *Stranded
        objects kept along one line*)."""
        self.check_budget()
        state = self.tree.states[node]
        stranded, direction = self.problem.stranded_pushes(state)
        if stranded.any():
            found, cost, feasible = local_minimum(
                self.problem, state, self.config.gd_iterations, held=stranded > 1,
                pinned=direction * (stranded == 1)[:, None])
            if feasible:
                return found, cost
        return super().directgd(node)

    def add_target(self, state: np.ndarray, cost: float) -> None:
        """Keep a local minimum as a target, with its equally good mirror images and quarter
        turns of its clusters (`equivalent_targets`), and the turns in place that leave each
        object's cost unchanged (`heading_steps`)."""
        for variant in equivalent_targets(self.problem, state):
            self.targets.append(Target(cost, variant, heading_steps(self.problem, variant, cost)))
            self.best_target_cost = min(self.best_target_cost, cost)

    def choose_target(self, state: np.ndarray) -> np.ndarray:
        """A target for extending from `state` (n, 3): usually the near-optimal target (within
        NEAR_OPTIMAL of the best) closest to `state` under rho after matching interchangeable
        objects and turning objects in place to their equally good heading nearest to
        `state`'s, sometimes any target at random (other basins); of them, those that leave
        every stranded object in its line (`leaves_stranded_in_line`) when there are any."""
        best_cost = self.best_target_cost
        near = [target for target in self.targets
                if target.cost <= best_cost + NEAR_OPTIMAL * abs(best_cost)]
        if self.rng.random() < 0.2:
            near = [self.targets[int(self.rng.integers(len(self.targets)))]]
        states = np.array([target.state for target in near])
        orders = assignment(self.groups, states, state)
        matched = np.take_along_axis(states, orders[..., None], axis=1)
        turned = turned_towards(matched, np.take_along_axis(
            np.array([target.heading_steps for target in near]), orders, axis=1), state)
        distances = self.rho(turned, state)
        reachable = self.leaves_stranded_in_line(state, turned)
        if reachable.any():
            distances = np.where(reachable, distances, np.inf)
        k = int(np.argmin(distances))
        if equally_good(self.problem, turned[k], near[k].cost):
            return turned[k]
        # turned one by one, two boxes may overlap: the target as found then
        return matched[k]

    def leaves_stranded_in_line(self, state: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """(k,) False for the targets (k, n, 3) that would move an object of `state` short of
        one face further than STRANDED_ADVANCE along the push it cannot get
        (PlanningProblem.stranded_pushes): nothing can push it there from here. DIRECTGD keeps
        such objects on that line (`directgd`), but the bound and the equivalent variants of
        a target do not: a tset6 search stuck 5 % above the bound went on steering towards
        a variant with the platters side by side across the table, platter_2 (stranded in the
        blind spot) 9.5 cm further out. With approach_blockers' short pushes, 40 tset6 seeds
        reached 1 % in a median 402 nodes against 790 (539 without this rule)."""
        stranded, direction = self.problem.stranded_pushes(state)
        advance = ((targets[..., :2] - state[None, :, :2]) * direction[None]).sum(axis=-1)
        return (advance[:, stranded == 1] <= STRANDED_ADVANCE).all(axis=1)

    def rearrange(self, node: int, target: np.ndarray) -> int:
        """REARRANGE (rearrange.py): move the objects to `target` (inset from the table
        edges) one at a time along searched push paths. Objects whose target would stand in
        another pending object's straight way (corridor_blocks) wait; of the rest, those with
        a free target go first. When none gets there, near the targets, one of them may
        first take the target of a placed object of its kind (swap_targets); else (or when all
        wait on each other) an object in the way is parked; when that fails too, the waiting
        objects are tried. Returns the last node added (or `node`).

        Who waits for whom is decided on the arrangement itself, not on the inset aims: an
        object moved 2 mm in from the edge comes within the margin of its neighbour in a
        row along that edge (tset12's plates, 0.105 m apart), and each of the two then
        stands in the other's way, a cycle that only parking could break. 32 tset12 seeds
        of 10 s: 14.6 % above the bound (median) against 18.4 %, 7 within 5 % against 2."""
        problem = self.problem
        arrangement, target = target.copy(), inset_from_edges(problem, target, TARGET_INSET)

        def error(i: int, state: np.ndarray) -> float:
            return pose_error(problem, i, state[i], target[i], self.weights[i])

        state = self.tree.states[node]
        pending = [i for i in range(problem.n) if error(i, state) > REARRANGE_TOLERANCE]
        parkings: dict[int, int] = {}
        swapped: set[frozenset[int]] = set()   # pairs whose targets swap_targets swapped
        for _ in range(4 * problem.n):
            if not pending:
                break
            state = self.tree.states[node]
            blocks = corridor_blocks(problem, state, arrangement, pending)
            free = dict(zip(pending, target_free(problem, state, arrangement,
                                                 np.array(pending)).all(axis=1), strict=True))
            waits = dict(zip(pending, blocks[np.ix_(pending, pending)].any(axis=1).tolist(),
                             strict=True))
            order = sorted(pending, key=lambda i: (waits[i], not free[i], error(i, state)))
            ready = [i for i in order if not waits[i]]
            swaps = len(swapped)
            swap = None if self.far_from_targets() else functools.partial(
                self.swap_targets, target=target, arrangement=arrangement, order=ready,
                pending=pending, swapped=swapped)
            node, placed = self.place_one(node, target, ready, pending, swap=swap)
            if placed or len(swapped) > swaps:
                continue
            # nothing free to go (or a cycle): park an object in the way, else try the rest
            parked = self.park(node, target, ready or order, pending, parkings)
            if parked is not None:
                node = parked
                continue
            # then those others wait for, as far as they get (out of the way of the targets
            # that would wall them in), and last the waiting ones
            waited_for = [j for j in order if blocks[pending, j].any()]
            moved_from = node
            node, placed = self.place_one(node, target, waited_for, pending)
            if placed or node != moved_from:
                continue
            node, placed = self.place_one(node, target, [i for i in order if i not in ready],
                                          pending)
            if not placed:
                break
        return node

    def swap_targets(self, node: int, target: np.ndarray, arrangement: np.ndarray,
                     order: list[int], pending: list[int], swapped: set[frozenset[int]]
                     ) -> bool:
        """Give one of the first pending objects in `order` the target of a placed object it
        is interchangeable with, when it could reach that target were the other not there;
        the other becomes pending with the first's target (both swapped in `target` and
        `arrangement`, in place). The cost of the target is the same. A plate walled in by
        tset6's platters cannot cross them to the free corner, but reaches the far corner
        beside it once that corner's plate has gone; that plate then goes down the strip past
        the platters to the next corner, whose plate takes the free one: a chain of swaps.
        Each pair swaps once per REARRANGE, and at most n swaps are made (`swapped`).
        REARRANGE swaps only while the best node is near the targets: on tset12, far from them
        nearly throughout, swapping at any distance left the search at 17.8-19.0 % above the
        bound against 15.2 % (32 seeds), though it took tset6 to 1 % in 0.60 s against 1.02 s."""
        problem = self.problem
        state = self.tree.states[node]
        if len(swapped) >= problem.n:
            return False
        for i in order[:MAX_CANDIDATES]:
            group = next((g for g in self.groups if i in g), None)
            if group is None:
                continue
            for j in (int(j) for j in group):
                if j == i or j in pending or frozenset((i, j)) in swapped:
                    continue
                without = state.copy()
                without[j, :2] = OFF_THE_TABLE
                _, reached = self.memo.object_path(without, i, target[j], self.weights[i],
                                                   self.check_budget, REARRANGE_TOLERANCE)
                if reached:
                    target[[i, j]] = target[[j, i]]
                    arrangement[[i, j]] = arrangement[[j, i]]
                    pending.append(j)
                    swapped.add(frozenset((i, j)))
                    return True
        return False

    def place_one(self, node: int, target: np.ndarray, candidates: list[int],
                  pending: list[int], swap: Callable[[int], bool] | None = None
                  ) -> tuple[int, bool]:
        """Move the first of `candidates` that gets to its target there: the first
        MAX_CANDIDATES with the usual search budget, then (the last way through) the first one
        with LAST_RESORT_EXPANSIONS; if none gets there, the first one that got closer moves
        as far as it got, unless that leaves it unable to move (`can_move`): a plate pushed
        part of the way to a corner of tset3's near edge ended where the arm could push it
        only towards the platter, 5 mm off, and the search never got it out (3 of 8 first
        plans from a demo's start 37 % above the bound at 12 s; none with the check), or
        unable to make a turn it could make before (`lost_turn`: clean's scale left 7 degrees
        off beside the remote). Before a partial move, `swap` (swap_targets) may give a
        candidate another target instead; then nothing moves. Returns the last node and whether
        an object was placed."""
        partial: tuple[int, list[Push]] | None = None
        for expansions, tried in ((SEARCH_EXPANSIONS, candidates[:MAX_CANDIDATES]),
                                  (LAST_RESORT_EXPANSIONS, candidates[:1])):
            for i in tried:
                path, reached = self.memo.object_path(
                    self.tree.states[node], i, target[i], self.weights[i], self.check_budget,
                    REARRANGE_TOLERANCE, max_expansions=expansions)
                if reached:
                    pending.remove(i)
                    return self.follow(node, path), True
                if path and partial is None:
                    start = self.tree.states[node]
                    end = simulate_from(self.problem, start, path)
                    if can_move(self.problem, end, i) and (
                            lost_turn(self.problem, end, i, self.length_grid) == 0.0
                            or lost_turn(self.problem, start, i, self.length_grid) > 0.0):
                        partial = (i, path)
        if (swap is not None and swap(node)) or partial is None:
            return node, False
        return self.follow(node, partial[1]), False

    def park(self, node: int, target: np.ndarray, order: list[int], pending: list[int],
             parked: dict[int, int]) -> int | None:
        """Move an object in the way of one of the first pending objects in `order` out of
        that one's way (parking_poses; adding it to `pending`); None when none could move.
        Objects standing where the ball must be for that one's pushes (approach_blockers) go
        first, to a pose that frees one of those pushes; pending objects are parked before
        placed ones, and none more than `max_parkings` times per REARRANGE (`parked` counts
        them), so parking cannot go round in circles."""
        problem = self.problem
        state = self.tree.states[node]
        candidates = []   # (blocked, object to park, pushes of `blocked` its parking must free)
        for blocked in order[:3]:
            # first those that stand where the ball must be for any push towards the target
            at_approach, freed = self.memo.approach_blockers(state, target, blocked,
                                                             self.weights[blocked])
            candidates += [(blocked, j, freed) for j in at_approach[:2]]
            candidates += [(blocked, j, []) for j in self.memo.blockers_of(state, target,
                                                                           blocked)[:2]]
        candidates = [candidate for candidate in candidates
                      if parked.get(candidate[1], 0) < self.max_parkings]
        candidates.sort(key=lambda candidate: candidate[1] not in pending)
        tried: set[int] = set()
        searches = 0
        for blocked, j, freed in candidates:
            if j in tried or searches >= PARKING_SEARCHES_PER_PARKING * self.max_parkings:
                continue
            tried.add(j)
            poses = parking_poses(problem, state, target, j, pending, self.rng, blocked)
            far = np.linalg.norm(poses[:, :2] - state[j, :2], axis=1) > 2 * PARKING_TOLERANCE
            freeing = (pose for pose in poses[far]
                       if frees_a_push(problem, state, j, pose, freed))
            for pose in itertools.islice(freeing, 3):
                searches += 1
                path, reached = self.memo.object_path(state, j, pose, self.weights[j],
                                                      self.check_budget, PARKING_TOLERANCE)
                if path and not reached:
                    # short of the parking pose may still be out of the way
                    end = simulate_from(problem, state, path)[j]
                    reached = bool(clear_of_way(problem, state, target, j, end[None],
                                                blocked)[0]) and frees_a_push(
                        problem, state, j, end, freed)
                if reached and path:
                    if j not in pending:
                        pending.append(j)
                    parked[j] = parked.get(j, 0) + 1
                    return self.follow(node, path)
        return None

    def steer(self, node: int, target: np.ndarray) -> int:
        """Steer the objects one at a time, in a random order, towards their poses in `target`
        (closed-form push lengths); repeat passes while any object still moves, so an object
        blocked in one pass can go once its neighbours have moved. Returns the last node."""
        pushes = 0
        moved = True
        while moved and pushes < self.config.connect_steps:
            moved = False
            for i in self.rng.permutation(self.problem.n):
                while pushes < self.config.connect_steps:
                    self.check_budget()
                    state = self.tree.states[node]
                    push = steer_push(self.problem, state, target, self.weights, int(i))
                    if push is None:
                        break
                    node = self.add_node(node, self.problem.apply(state, *push), push)
                    pushes += 1
                    moved = True
        return node

    def polish(self, node: int) -> int:
        """Line searches on the objective along every push (lengths on a geometric grid).
        Near the targets, pushes that end off the table are left out before the best 64 are
        tried: the 2-mm pushes into tset6's corners then come during the search, not at the
        end of its budget (40 seeds of 4 s: 1 % in 1.06 s against 1.63 s, median). Far from
        them, the 64 best as they come: polishing into the corners early sent 2 of 6 seeds
        into the walled-in basin."""
        for _ in range(self.config.polish_steps):
            self.check_budget()
            push = polish_push(self.problem, self.tree.states[node], self.length_grid,
                               on_table_first=self.near_targets(self.tree.cost[node]))
            if push is None:
                return node
            node = self.add_node(node, self.problem.apply(self.tree.states[node], *push), push)
        return node


def _first_valid(problem: PlanningProblem, state: np.ndarray, objects: np.ndarray,
                 primitives: np.ndarray, lengths: np.ndarray, order: np.ndarray,
                 chunk: int = 16, limit: int | None = 64) -> int | None:
    """Index into the arrays of the first valid push among the first `limit` of `order` (None:
    all), checking in small batches (a crowded state should not cost a check of every push)."""
    order = order[:limit]
    for part in np.array_split(order, max(1, math.ceil(len(order) / chunk))):
        if len(part):
            valid = problem.pushes_valid(state, objects[part], primitives[part], lengths[part])
            if valid.any():
                return int(part[int(np.argmax(valid))])
    return None


def steer_object(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
                 weights: np.ndarray, index: int, max_pushes: int,
                 tolerance: float | None = None) -> tuple[list[Push], np.ndarray]:
    """Up to `max_pushes` steer_push pushes of object `index` alone towards its pose in
    `target`, until none helps (or it is within `tolerance` under object_error); returns the
    pushes and the state they lead to. Shortcuts replace stretches of a plan with these."""
    pushes: list[Push] = []
    while len(pushes) < max_pushes:
        if tolerance is not None and pose_error(problem, index, state[index], target[index],
                                                weights[index]) < tolerance:
            break
        push = steer_push(problem, state, target, weights, index)
        if push is None:
            break
        pushes.append(push)
        state = problem.apply(state, *push)
    return pushes, state


def compile_search_kernels(problem: PlanningProblem) -> None:
    """Compile (or load from numba's cache) the kernels of REARRANGE's A*, of STEER, of
    choose_target's matching and of the nearest neighbour, so that none takes a first search's
    time; scripts/setup.sh runs it after each build (compile_kernels.py)."""
    compile_kernels(problem)
    steer_push(problem, problem.start, problem.start, np.ones(problem.n))
    assignment([np.arange(min(2, problem.n))], problem.start[None], problem.start)
    nearest_under_rho(problem.start[None], 1, 1, problem.start, np.ones(problem.n),
                      problem.angle_period)


def steer_push(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
               weights: np.ndarray, only_object: int | None = None) -> Push | None:
    """The valid push that brings `state` closest to `target` under rho, or None if none
    removes at least MIN_STEER_GAIN of the pushed object's squared error (which stops
    back-and-forth pushes that only gain by side drift). The length of each (object, primitive)
    minimises rho in closed form (the pose is affine in the length); blocked pushes are retried
    shorter. `only_object` restricts the pushes to one object."""
    objects, primitives = problem.action_objects, problem.action_primitives
    if only_object is not None:
        mine = objects == only_object
        objects, primitives = objects[mine], primitives[mine]
    objects, primitives, lengths, order = steer_candidates(
        state, target, weights, objects, primitives, problem.rates, problem.angle_period,
        problem.min_length, problem.max_lengths, STEER_RETRY_FRACTIONS, MIN_STEER_GAIN)
    k = _first_valid(problem, state, objects, primitives, lengths, order)
    return None if k is None else (int(objects[k]), int(primitives[k]), float(lengths[k]))


def polish_pushes(problem: PlanningProblem, state: np.ndarray, grid: np.ndarray,
                  max_pushes: int, limit: int | None = 64) -> list[Push]:
    """Up to `max_pushes` polish_push pushes in a row from `state`, until none lowers the cost."""
    pushes: list[Push] = []
    while len(pushes) < max_pushes:
        push = polish_push(problem, state, grid, limit)
        if push is None:
            break
        pushes.append(push)
        state = problem.apply(state, *push)
    return pushes


def polish_push(problem: PlanningProblem, state: np.ndarray, grid: np.ndarray,
                limit: int | None = 64, on_table_first: bool = True) -> Push | None:
    """The valid push (every object and primitive, lengths from `grid`) that lowers the cost
    most without taking away a turn of its object that would lower it more (`lost_turn`), or
    None if none lowers it, looking only at the `limit` best pushes (None: all) that lower it
    before each lost turn; with `on_table_first`, the best of those that keep their object
    on the table (near an edge the pushes that gain most go past it). Line searches take the
    biggest gain first, so a box off its best heading got pushed in beside a neighbour before
    it was turned, and then the ball no longer fitted between them to turn it: clean's eraser
    stayed 10 degrees off beside the remote, 21 % above the bound (seed 0 of 20 at 250
    nodes)."""
    objects, primitives, lengths, candidates, costs = line_search_pushes(
        problem, state, problem.action_objects, problem.action_primitives, grid)
    cost = float(problem.objective.cost(state))
    order = np.argsort(costs, kind="stable")
    order = order[costs[order] < cost - 1e-10]
    if on_table_first:
        moved = candidates[order, objects[order]]
        order = order[problem.checker.on_table_rows(objects[order], moved)]
    stuck_before: dict[int, bool] = {}
    while len(order):
        chosen = _first_valid(problem, state, objects, primitives, lengths, order, limit=limit)
        if chosen is None:
            return None
        i = int(objects[chosen])
        if i not in stuck_before:
            stuck_before[i] = lost_turn(problem, state, i, grid) > 0.0
        if (stuck_before[i]
                or lost_turn(problem, candidates[chosen], i, grid) <= cost - costs[chosen]):
            return i, int(primitives[chosen]), float(lengths[chosen])
        order = order[int(np.nonzero(order == chosen)[0][0]) + 1:]
    return None


def line_search_pushes(problem: PlanningProblem, state: np.ndarray, objects: np.ndarray,
                       primitives: np.ndarray, grid: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each (object, primitive) push (k,) at every length of `grid` (g,), from `state`: the
    pushes' objects, primitives and lengths (k * g,), the states they predict (k * g, n, 3) and
    those states' costs, not yet checked for validity. `predict`'s arithmetic, with each push's
    direction turned to the world once, not once per length."""
    g = len(grid)
    directions = np.repeat(problem.push_directions(state, objects, primitives), g, axis=0)
    objects, primitives = np.repeat(objects, g), np.repeat(primitives, g)
    lengths = np.tile(grid, len(objects) // g)
    candidates = np.repeat(state[None], len(objects), axis=0)
    candidates[np.arange(len(objects)), objects] = (state[objects]
                                                    + lengths[:, None] * directions)
    return objects, primitives, lengths, candidates, problem.objective.cost(candidates)


def lost_turn(problem: PlanningProblem, state: np.ndarray, index: int,
              grid: np.ndarray) -> float:
    """What box `index` loses by being unable to turn in `state`: the cost gain of its best
    turn (primitives 5-6, lengths from `grid`) when that turns it by STUCK_TURN of arc at its
    ends or more and no turn that lowers the cost is valid; else 0."""
    turns = problem.turns_of[index]
    if not len(turns):
        return 0.0
    objects, primitives, lengths, candidates, costs = line_search_pushes(
        problem, state, problem.action_objects[turns], problem.action_primitives[turns], grid)
    gain = problem.objective.cost(state) - costs
    best = int(np.argmax(gain))
    turn = abs(math.remainder(candidates[best, index, 2] - state[index, 2], 2 * math.pi))
    if gain[best] <= 0 or problem.objects.half_length[index] * turn < STUCK_TURN:
        return 0.0
    lowering = gain > 0
    if problem.pushes_valid(state, objects[lowering], primitives[lowering],
                            lengths[lowering]).any():
        return 0.0
    return float(gain[best])


def inset_from_edges(problem: PlanningProblem, state: np.ndarray, inset: float) -> np.ndarray:
    """`state` (n, 3) with footprints closer than `inset` to a table edge moved inwards to
    `inset`: an optimum on an edge can only be approached from one side, so REARRANGE aims
    just inside it and POLISH closes the last millimetres."""
    rows = np.arange(problem.n)
    clearance = problem.checker.table_clearances_rows(rows, state)  # (n, 4): -x, +x, -y, +y
    short = np.maximum(inset - clearance, 0.0)
    moved = state.copy()
    moved[:, 0] += short[:, 0] - short[:, 1]
    moved[:, 1] += short[:, 2] - short[:, 3]
    return moved


def interchangeable_groups(problem: PlanningProblem) -> list[np.ndarray]:
    """Sets of objects whose poses can be permuted without changing cost or constraints: same
    class and footprint, in exactly the same objective terms."""
    signature: dict[tuple, list[int]] = {}
    specs = problem.scenario.objects
    for i, spec in enumerate(specs):
        terms = tuple(k for k, term in enumerate(problem.objective.terms) if i in term.indices)
        key = (spec.object_class, spec.shape, spec.length, spec.width, terms)
        signature.setdefault(key, []).append(i)
    return [np.array(group) for group in signature.values() if len(group) > 1]


def equivalent_targets(problem: PlanningProblem, state: np.ndarray) -> list[np.ndarray]:
    """`state` (n, 3) and variants that are as good and valid: its mirror images, and quarter
    turns of the objects a distance_to_point term gathers, about that term's point (positions
    and headings turned by +-pi/2; the term and orthogonality cannot tell them apart). A
    cluster of boxes gathered side by side can then be reached stacked instead, which saves
    turning every box by 90 degrees in a crowded spot."""
    cost = float(problem.objective.cost(state))
    variants = [state]
    for term in problem.objective.terms:
        if term.type_name != "distance_to_point" or len(term.indices) < 2:
            continue
        for turn in (np.pi / 2, -np.pi / 2):
            c, s = math.cos(turn), math.sin(turn)
            turned = state.copy()
            offset = state[term.indices, :2] - term.point
            turned[term.indices, 0] = term.point[0] + c * offset[:, 0] - s * offset[:, 1]
            turned[term.indices, 1] = term.point[1] + s * offset[:, 0] + c * offset[:, 1]
            turned[term.indices, 2] = state[term.indices, 2] + turn
            if equally_good(problem, turned, cost):
                variants.append(turned)
    return [image for variant in variants for image in mirror_images(problem, variant)]


def equally_good(problem: PlanningProblem, state: np.ndarray, cost: float) -> bool:
    """True when `state` costs `cost` (within MIRROR_TOLERANCE) and meets the constraints."""
    same = abs(float(problem.objective.cost(state)) - cost) <= MIRROR_TOLERANCE * max(
        abs(cost), 1.0)
    return same and bool(problem.checker.constraint_values(state).min() >= -1e-5)


def mirror_images(problem: PlanningProblem, state: np.ndarray) -> list[np.ndarray]:
    """`state` (n, 3) and those of its mirror images through the table's centre lines (and the
    point reflection through its centre) that are equally good and valid: without static
    obstacles or a named point the objective cannot tell them apart, and a target on the other
    side of the table may be much nearer to the objects."""
    x_min, y_min, x_max, y_max = problem.scenario.table.bounds
    cx, cy = (x_min + x_max) / 2, (y_min + y_max) / 2
    cost = float(problem.objective.cost(state))
    images = [state]
    for flip_x, flip_y in ((True, False), (False, True), (True, True)):
        image = state.copy()
        if flip_x:  # x -> 2 cx - x turns a heading theta into pi - theta
            image[:, 0], image[:, 2] = 2 * cx - image[:, 0], np.pi - image[:, 2]
        if flip_y:  # y -> 2 cy - y turns theta into -theta
            image[:, 1], image[:, 2] = 2 * cy - image[:, 1], -image[:, 2]
        image[:, 2] = (image[:, 2] + np.pi) % (2 * np.pi) - np.pi
        if equally_good(problem, image, cost):
            images.append(image)
    return images


def assignment(groups: list[np.ndarray], targets: np.ndarray, state: np.ndarray) -> np.ndarray:
    """The slots of each of `targets` (..., n, 3) to give each object, `target[order]`:
    interchangeable objects reassigned to minimise their travel from `state` (n, 3). Compiled
    (kernels.nearest_assignments): choose_target matches a few dozen targets per extension,
    and scipy's linear_sum_assignment per target and group took 6 % of a tset12 search."""
    flat = np.ascontiguousarray(targets, dtype=float).reshape(-1, *targets.shape[-2:])
    members = np.concatenate([np.zeros(0, np.int64), *groups]).astype(np.int64)
    starts = np.cumsum([0] + [len(group) for group in groups]).astype(np.int64)
    orders = nearest_assignments(np.ascontiguousarray(state, dtype=float), flat, members,
                                 starts)
    return orders.reshape(*targets.shape[:-1])


def heading_steps(problem: PlanningProblem, state: np.ndarray, cost: float) -> np.ndarray:
    """Per object of `state` (n, 3), the turns in place that leave its cost unchanged: 0 when
    any turn does (no term reads its heading there), pi/2 when quarter turns do (orthogonality
    and alignment read headings modulo pi/2), inf when none does. The lower bound picks one of
    such equally good headings by rounding noise (two_boxes: eraser and remote turned by 90
    degrees at 1e-10 below the unturned optimum), and steering towards it turned the soak's
    one-push task into a 24-push plan. Whether the turned box still fits among its neighbours
    is left to `choose_target`, which checks the state it builds."""
    n = problem.n
    angles = (math.pi / 2, 0.5, math.pi / 4)   # a quarter turn, then two others
    turned = np.repeat(state[None, None], len(angles) * n, axis=0).reshape(len(angles), n, n, 3)
    for k, angle in enumerate(angles):
        turned[k, np.arange(n), np.arange(n), 2] += angle
    costs = problem.objective.cost(turned.reshape(-1, n, 3)).reshape(len(angles), n)
    same = np.abs(costs - cost) <= MIRROR_TOLERANCE * max(abs(cost), 1.0)
    return np.where(same.all(axis=0), 0.0, np.where(same[0], math.pi / 2, np.inf))


def turned_towards(target: np.ndarray, steps: np.ndarray, state: np.ndarray) -> np.ndarray:
    """`target` (..., n, 3) with each object turned in place by its `heading_steps` (..., n)
    to the heading nearest its heading in `state` (n, 3): any heading where steps are 0, none
    where inf."""
    delta = state[:, 2] - target[..., 2]
    quarter = np.isfinite(steps) & (steps > 0)
    step = np.where(quarter, steps, 1.0)
    turned = target.copy()
    turned[..., 2] += np.where(steps == 0, delta, np.where(quarter, np.round(delta / step) * step,
                                                            0.0))
    return turned


def TASK_SPACE_RRT(problem: PlanningProblem, mode: str = "tsrrt", seed: int = 0,
                   time_budget_s: float | None = 10.0, max_nodes: int | None = None,
                   progress: Progress | None = None, cancel: Cancel | None = None,
                   config: PlannerConfig | None = None, lower_bound_cost: float | None = None,
                   target: np.ndarray | None = None,
                   warm_start: Sequence[PlanStep] = (),
                   previous_goal: np.ndarray | None = None,
                   good_enough_cost: float | None = None,
                   stall: StallRule | None = None, shortest_within: float = 0.0,
                   soft_deadline: SoftDeadline | None = None,
                   give_up: GiveUpRule | None = None, push_cost: float = 0.0) -> PlanResult:
    """Plan pushes that lower the objective; returns the best plan found (anytime).

    Models are learned beforehand (Fig. 4 lines 1-2 are LEARN_MODEL, see model_learning), so this
    runs lines 3-14 on `problem`, whose forward models are already in place.

    Args:
        problem: start state, objective, models and constraints.
        mode: one of MODES.
        seed: the search is deterministic for a seed and a node budget.
        time_budget_s: stop after this long (None: no time limit).
        max_nodes: stop at this many tree nodes (None: no limit).
        progress: called now and then, and whenever the best cost improves.
        cancel: a threading.Event or a callable returning True to stop early.
        config: tunables.
        lower_bound_cost: reported in the result for the gap (lower_bound.lower_bound).
        target: tsrrt only: the continuous optimum (n, 3), e.g. lower_bound(...).state.
        warm_start: a previous plan (e.g. the unexecuted rest of one); its prefix that is
            valid from the start, up to its lowest cost, goes into the tree first, so the
            result is no worse than that, but for the PAIR_COST_TOLERANCE that shortening
            the plan may give up.
        previous_goal: tsrrt only: the final state (n, 3) of the plan this one replaces;
            REARRANGE steers there first.
        good_enough_cost: stop as soon as a state this good is found (a replan that has
            recovered what the plan it replaces promised).
        stall: stop once the search stalls (StallRule; stop reason "stalled"). Time-based,
            so not repeatable by seed.
        shortest_within: return the plan with the fewest pushes to a state within this much
            (absolute cost) of the best found, rather than the plan to the best (0).
        soft_deadline: stop early once past its time with a best cost at or below its cost
            (SoftDeadline; stop reason "time"). Time-based, so not repeatable by seed.
        give_up: stop once past its time with a best cost still above its cost (GiveUpRule;
            stop reason "nothing found"); the plan still gets its finishing polish.
            Time-based, so not repeatable by seed.
        push_cost: the plan goes to the node whose cost plus this much per push (its depth in
            the tree) is least (with `shortest_within`: the shallowest within that of it),
            not to the best node: what one more push must gain to be worth the robot's time.
    """
    if mode not in MODES:
        raise PlannerError(f"unknown planner mode {mode!r}; known: {list(MODES)}")
    if time_budget_s is None and max_nodes is None and cancel is None:
        raise PlannerError("give a time budget, a node budget or a cancel signal")
    if time_budget_s is not None and not time_budget_s > 0:
        raise PlannerError(f"time budget must be > 0 s, got {time_budget_s}")
    if max_nodes is not None and max_nodes < 1:
        raise PlannerError(f"node budget must be >= 1, got {max_nodes}")
    config = config or PlannerConfig()
    if not 0.0 <= config.epsilon <= 1.0:
        raise PlannerError(f"epsilon must be within [0, 1], got {config.epsilon}")
    if not shortest_within >= 0.0:
        raise PlannerError(f"shortest_within must be >= 0, got {shortest_within}")
    if not push_cost >= 0.0:
        raise PlannerError(f"push_cost must be >= 0, got {push_cost}")
    if stall is not None and not (stall.window_s > 0 and stall.far_window_s > 0
                                  and stall.tolerance >= 0):
        raise PlannerError(f"a stall rule needs windows > 0 s and a tolerance >= 0, got "
                           f"{stall}")
    for name, state in (("target", target), ("previous_goal", previous_goal)):
        if state is not None and np.shape(state) != problem.start.shape:
            raise PlannerError(f"{name} must have shape {problem.start.shape}, got "
                               f"{np.shape(state)}")
    if mode == "tsrrt":
        weights = np.where(problem.objects.is_disc, 0.0, problem.objects.half_length)
    else:
        weights = np.full(problem.n, problem.scenario.orientation_weight)
    index = {object_id: i for i, object_id in enumerate(problem.objects.ids)}
    unknown = sorted({step.object_id for step in warm_start} - index.keys())
    if unknown:
        raise PlannerError(f"warm start pushes unknown objects {unknown}")
    warm_pushes = [(index[step.object_id], step.primitive, step.push_length)
                   for step in warm_start]
    arguments = (problem, mode, seed, config, time_budget_s, max_nodes, progress, cancel,
                 weights, good_enough_cost, stall, shortest_within, soft_deadline, give_up,
                 push_cost)
    search: _Search
    if mode == "greedy":
        search = _GreedySearch(*arguments)
    elif mode == "tsrrt":
        compile_search_kernels(problem)   # before the search's clock starts
        search = _TsrrtSearch(*arguments, target=target,
                              previous_goal=None if previous_goal is None
                              else np.asarray(previous_goal, dtype=float))
    else:
        search = _PaperSearch(*arguments)
    try:
        search.warm_start(warm_pushes)
        search.run()
    except _Stop as stop:
        return search.result(stop.reason, lower_bound_cost)
    raise AssertionError("searches only end by _Stop")
