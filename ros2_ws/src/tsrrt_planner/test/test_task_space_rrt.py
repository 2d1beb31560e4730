"""Planner invariants (Fig. 4): valid states, model-consistent paths, anytime, determinism."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import load_scenario, parse_scenario
from tsrrt_planner.bench import default_models, jittered_problem, resolve_scenario
from tsrrt_planner.errors import Cancelled, PlannerError
from tsrrt_planner.kernels import min_cost_assignment
from tsrrt_planner.lower_bound import local_minimum, lower_bound, relative_gap, swap_refine
from tsrrt_planner.model_learning import ModelStore
from tsrrt_planner.problem import PlanningProblem, shortest_turn
from tsrrt_planner.push_rule import learn_all
from tsrrt_planner.rearrange import RearrangeMemo, object_path
from tsrrt_planner.task_space_rrt import (
    FAR_FROM_TARGETS,
    GD_FAILURES_TOLERATED,
    MIN_STEER_GAIN,
    MODES,
    PAIR_COST_TOLERANCE,
    RESTART_AT,
    RESTART_FAR,
    SHORTCUT_NEAR,
    SHORTCUT_SHARE,
    SHORTCUT_SHARE_FAR,
    TASK_SPACE_RRT,
    GiveUpRule,
    PlannerConfig,
    PlanResult,
    PlanStep,
    SoftDeadline,
    StallRule,
    _Search,
    _Stop,
    _TsrrtSearch,
    absorb_pushes,
    assignment,
    can_move,
    equivalent_targets,
    heading_steps,
    interchangeable_groups,
    lost_turn,
    merge_runs,
    polish_push,
    replay_from,
    shorten_runs,
    simulate,
    steer_push,
    track_plan,
    turned_towards,
)


def tsrrt_search(problem: PlanningProblem, max_nodes: int | None = 100,
                 target: np.ndarray | None = None, time_budget_s: float | None = None,
                 **options: Any) -> _TsrrtSearch:
    """The tsrrt search itself, for tests of its steps (weights as TASK_SPACE_RRT gives them;
    `options` are _TsrrtSearch's other keyword arguments)."""
    weights = np.where(problem.objects.is_disc, 0.0, problem.objects.half_length)
    return _TsrrtSearch(problem, "tsrrt", 0, PlannerConfig(), time_budget_s, max_nodes, None,
                        None, weights, target=target, **options)


def best_steering_push(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
                       weights: np.ndarray) -> tuple[int, int, float] | None:
    """STEER's push by brute force, one candidate at a time: of the valid candidates (each
    push's closed-form length, clipped, times 1, 0.97, 0.75, 0.5 or 0.25) that remove more
    than MIN_STEER_GAIN of their object's squared error, the one that removes the most of it
    (the error's heading reduced before the push, the pose affine in the push's length)."""
    best, best_gain = None, -math.inf
    for o, primitive in zip(problem.action_objects, problem.action_primitives, strict=True):
        per_metre = problem.apply(state, int(o), int(primitive), 1.0)[o] - state[o]
        error = target[o] - state[o]
        error[2] = shortest_turn(error[2], problem.angle_period[o])
        w2 = np.array([1.0, 1.0, weights[o] ** 2])
        ideal = (w2 * error * per_metre).sum() / max((w2 * per_metre ** 2).sum(), 1e-12)
        if ideal < problem.min_length:
            continue
        before = (w2 * error ** 2).sum()
        for fraction in (1.0, 0.97, 0.75, 0.5, 0.25):
            length = max(min(ideal, problem.max_lengths[o]) * fraction, problem.min_length)
            gain = before - (w2 * (error - length * per_metre) ** 2).sum()
            valid = problem.pushes_valid(state, np.array([o]), np.array([primitive]),
                                         np.array([length]))[0]
            enough = gain > max(MIN_STEER_GAIN * before, 1e-10)
            if valid and enough and gain > best_gain + 1e-12:
                best, best_gain = (int(o), int(primitive), float(length)), gain
    return best


def test_steer_push_takes_the_valid_push_that_gains_most(problem):
    """steer_push (its candidates compiled in kernels.steer_candidates) against a brute-force
    search over the same candidates, from random states towards random targets."""
    rng = np.random.default_rng(3)
    weights = np.where(problem.objects.is_disc, 0.0, problem.objects.half_length)
    pushes = 0
    for _ in range(40):
        state = problem.start + rng.normal(0.0, [0.01, 0.01, 0.1], problem.start.shape)
        target = state + rng.normal(0.0, [0.05, 0.05, 0.5], state.shape)
        push = steer_push(problem, state, target, weights)
        expected = best_steering_push(problem, state, target, weights)
        assert (push is None) == (expected is None)
        if push is not None:
            pushes += 1
            assert push[:2] == expected[:2] and push[2] == pytest.approx(expected[2])
    assert pushes >= 20


def replay(problem: PlanningProblem, result) -> np.ndarray:
    """States of the plan recomputed from the models, checking every push on the way."""
    index = {object_id: i for i, object_id in enumerate(problem.objects.ids)}
    state, states = problem.start, [problem.start]
    for step in result.steps:
        o = index[step.object_id]
        assert problem.pushes_valid(state, np.array([o]), np.array([step.primitive]),
                                    np.array([step.push_length]))[0], step
        state = problem.apply(state, o, step.primitive, step.push_length)
        states.append(state)
    return np.array(states)


def test_one_push_applied_is_the_models_prediction(problem):
    """`apply` repeats `predict`'s arithmetic on scalars, for speed; the two must agree."""
    rng = np.random.default_rng(3)
    state = problem.start.copy()
    state[:, 2] = rng.uniform(-np.pi, np.pi, problem.n)
    for o, p in zip(problem.action_objects, problem.action_primitives, strict=True):
        length = float(rng.uniform(0.005, 0.08))
        after = problem.apply(state, int(o), int(p), length)
        predicted = problem.predict(state, np.array([o]), np.array([p]), np.array([length]))
        np.testing.assert_allclose(after[o], predicted[0], rtol=0, atol=1e-12)
        others = np.arange(problem.n) != o
        np.testing.assert_array_equal(after[others], state[others])


@pytest.mark.parametrize("mode", MODES)
def test_plans_are_valid_and_consistent_with_the_models(problem, bound, mode):
    result = TASK_SPACE_RRT(problem, mode, seed=1, time_budget_s=None, max_nodes=150,
                            lower_bound_cost=bound.cost, target=bound.state)
    states = replay(problem, result)
    np.testing.assert_allclose(result.states, states, atol=1e-12)
    x_min, y_min, x_max, y_max = problem.scenario.table.bounds
    for state in states:
        assert problem.state_valid(state)
        assert np.all((state[:, 0] > x_min) & (state[:, 0] < x_max))
        assert np.all((state[:, 1] > y_min) & (state[:, 1] < y_max))
    np.testing.assert_allclose(result.costs, problem.objective.cost(states))
    assert result.best_cost <= result.costs[0]
    assert result.stop_reason in ("nodes", "converged")
    assert result.nodes <= 150


@pytest.mark.parametrize("mode", MODES)
def test_anytime_best_is_monotone(problem, bound, mode):
    result = TASK_SPACE_RRT(problem, mode, seed=2, time_budget_s=None, max_nodes=120,
                            lower_bound_cost=bound.cost, target=bound.state)
    times, nodes, costs = map(np.array, zip(*result.trace, strict=True))
    assert np.all(np.diff(costs) < 0)
    assert np.all(np.diff(times) >= 0) and np.all(np.diff(nodes) > 0)


@pytest.mark.parametrize("mode", ["paper", "tsrrt"])
def test_deterministic_for_a_seed(problem, bound, mode):
    runs = [TASK_SPACE_RRT(problem, mode, seed=seed, time_budget_s=None, max_nodes=100,
                           target=bound.state) for seed in (5, 5, 6)]
    assert runs[0].steps == runs[1].steps
    np.testing.assert_array_equal(runs[0].states, runs[1].states)
    assert runs[0].steps != runs[2].steps or mode == "tsrrt"


def test_the_nearest_node_is_rho_s_argmin_over_the_root_and_the_epoch(problem):
    """The compiled nearest neighbour answers as numpy's argmin of rho: over the whole tree,
    and after a restart over the root and the nodes added since."""
    search = tsrrt_search(problem)
    rng = np.random.default_rng(0)
    for _ in range(40):
        search.tree.add(0, problem.start + rng.normal(0.0, 0.05, problem.start.shape),
                        (0, 1, 0.01), 0.0)
    for epoch_start in (1, 25):
        search.epoch_start = epoch_start
        nodes = np.r_[0, epoch_start:search.tree.size]
        for _ in range(20):
            sample = problem.start + rng.normal(0.0, 0.05, problem.start.shape)
            expected = nodes[np.argmin(search.rho(search.tree.states[nodes], sample))]
            assert search.nearest_neighbor(sample) == expected
    assert _Search.nearest_neighbor(search, search.tree.states[10]) == 10


def test_the_memo_leaves_the_search_unchanged(problem, bound, monkeypatch):
    """REARRANGE's memo saves searches and checks only: without it the plan is the same."""
    asked, searched = [], []

    class Counting(RearrangeMemo):
        def object_path(self, *args, **kwargs):
            asked.append(1)
            return super().object_path(*args, **kwargs)

    def counted(*args, **kwargs):
        searched.append(1)
        return object_path(*args, **kwargs)

    def plan(memo: type[RearrangeMemo], **options) -> PlanResult:
        monkeypatch.setattr("tsrrt_planner.task_space_rrt.RearrangeMemo",
                            lambda problem: memo(problem, **options))
        return TASK_SPACE_RRT(problem, "tsrrt", seed=3, time_budget_s=None, max_nodes=300,
                              target=bound.state)

    monkeypatch.setattr("tsrrt_planner.rearrange.object_path", counted)
    remembered = plan(Counting)
    assert len(searched) < len(asked)
    forgotten = plan(RearrangeMemo, size=0)
    assert remembered.steps == forgotten.steps and remembered.nodes == forgotten.nodes


def test_improved_mode_reaches_the_bound_on_tset3(problem, bound):
    result = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=None, max_nodes=600,
                            lower_bound_cost=bound.cost, target=bound.state)
    assert result.gap() < 0.02


def test_improved_mode_takes_the_eraser_around_the_obstacle():
    """The paper's obstacle task: the eraser goes round the fixed hole punch to the goal point.
    REARRANGE's blocker questions had taken the obstacle's row of the shapes for a movable
    object's, and searches of this scenario ended in an IndexError (seeds 1 and 2 within 100
    nodes)."""
    scenario = load_scenario("obstacle")
    problem = PlanningProblem(scenario, learn_all(scenario.objects, seed=0))
    bound = lower_bound(problem, starts=4)
    for seed in range(3):
        result = TASK_SPACE_RRT(problem, "tsrrt", seed=seed, time_budget_s=None,
                                max_nodes=100, lower_bound_cost=bound.cost, target=bound.state)
        for state in replay(problem, result):
            assert problem.state_valid(state)
        assert result.best_cost < 0.01 * problem.objective.cost(problem.start)


def test_without_a_target_the_search_grows_where_directgd_fails_from_the_start():
    """A tset6 start (the bench's jittered start 3) from which DIRECTGD ends infeasible: with
    no `target` the search used to retry it from its only node for its whole budget (1 node
    in 3 s); it must grow the tree towards random states until a descent succeeds."""
    scenario = load_scenario("tset6")
    problem = jittered_problem(scenario, ModelStore.load(default_models(scenario)),
                               (0.02, 0.2), seed=3)
    assert not local_minimum(problem, problem.start, PlannerConfig().gd_iterations)[2]
    result = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=20.0, max_nodes=150)
    assert result.nodes == 150
    # it descends (seeds 0-5 on an AVX-512 machine: by 0.46-1.11; the search is chaotic, and
    # floating point differs between CPUs)
    assert result.best_cost < problem.objective.cost(problem.start) - 0.4


def test_shortest_within_trades_a_little_cost_for_fewer_pushes(problem, bound):
    """The plan to the shallowest node near the best: on tset3 (200 nodes, seed 0) the best
    node is 33 pushes deep, one within 1 % of the bound is 10 deep."""
    tolerance = 0.01 * abs(bound.cost)
    best, shortest = (TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=None, max_nodes=200,
                                     target=bound.state, shortest_within=within)
                      for within in (0.0, tolerance))
    assert len(shortest.steps) < len(best.steps)
    assert shortest.best_cost <= best.best_cost + tolerance
    np.testing.assert_allclose(shortest.states, replay(problem, shortest), atol=1e-12)


def test_a_push_cost_trades_cost_for_fewer_pushes(problem, bound):
    """Charged for its pushes, the plan goes to a shallower node of the same tree: one more
    push must gain that much to be worth it."""
    push_cost = 0.001 * abs(bound.cost)
    best, charged = (TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=None, max_nodes=200,
                                    target=bound.state, push_cost=cost)
                     for cost in (0.0, push_cost))
    assert [c for _, _, c in charged.trace[:-1]] == [c for _, _, c in best.trace[:-1]]
    assert len(charged.steps) < len(best.steps)
    assert charged.costs[-1] <= best.costs[-1] + push_cost * len(best.steps)
    np.testing.assert_allclose(charged.states, replay(problem, charged), atol=1e-12)


@pytest.mark.parametrize("argument", ["shortest_within", "push_cost"])
def test_a_negative_node_choice_is_an_error(problem, argument):
    with pytest.raises(PlannerError, match=argument):
        TASK_SPACE_RRT(problem, "tsrrt", max_nodes=10, **{argument: -1.0})


def test_a_soft_deadline_stops_a_search_only_once_its_best_is_good_enough(problem, bound):
    reached = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=60.0, max_nodes=20000,
                             target=bound.state, soft_deadline=SoftDeadline(0.3, math.inf))
    assert reached.stop_reason == "time" and reached.elapsed_s < 30.0
    never = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=60.0, max_nodes=400,
                           target=bound.state, soft_deadline=SoftDeadline(0.3, -math.inf))
    assert never.stop_reason == "nodes"


def test_a_search_gives_up_only_when_it_has_found_nothing_better_than_its_rule(problem, bound):
    # a node budget the search cannot use up within the rule's 0.3 s (an AVX-512 machine made
    # 400 nodes in less)
    hopeless = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=60.0, max_nodes=20000,
                              target=bound.state, give_up=GiveUpRule(0.3, -math.inf))
    assert hopeless.stop_reason == "nothing found" and hopeless.elapsed_s < 30.0
    # still a plan from the best state found: the finishing polish runs as for any stop
    np.testing.assert_allclose(hopeless.states, replay(problem, hopeless), atol=1e-12)
    found = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=60.0, max_nodes=400,
                           target=bound.state, give_up=GiveUpRule(0.3, math.inf))
    assert found.stop_reason == "nodes"


def test_cancel_and_progress(problem):
    event = threading.Event()
    seen = []

    def progress(info):
        seen.append(info)
        if info.nodes >= 30:
            event.set()

    result = TASK_SPACE_RRT(problem, "paper-nogd", seed=0, time_budget_s=30.0,
                            progress=progress, cancel=event)
    assert result.stop_reason == "cancelled"
    assert seen and all(b.elapsed_s >= a.elapsed_s for a, b in zip(seen, seen[1:], strict=False))
    result = TASK_SPACE_RRT(problem, "paper-nogd", seed=0, time_budget_s=30.0,
                            cancel=lambda: True)
    assert result.stop_reason == "cancelled" and len(result.steps) == 0


def test_time_budget_stops(problem):
    result = TASK_SPACE_RRT(problem, "paper-nogd", seed=0, time_budget_s=0.2)
    assert result.stop_reason == "time" and result.elapsed_s < 2.0


@pytest.mark.parametrize("mode", MODES)
def test_a_good_enough_state_stops_the_search(problem, bound, mode):
    full = TASK_SPACE_RRT(problem, mode, seed=1, time_budget_s=None, max_nodes=150,
                          lower_bound_cost=bound.cost, target=bound.state)
    start_cost = float(full.costs[0])
    good_enough = start_cost - 0.2 * (start_cost - full.best_cost)
    stopped = TASK_SPACE_RRT(problem, mode, seed=1, time_budget_s=None, max_nodes=150,
                             lower_bound_cost=bound.cost, target=bound.state,
                             good_enough_cost=good_enough)
    assert stopped.stop_reason == "recovered"
    assert stopped.best_cost <= good_enough and stopped.nodes < full.nodes


def test_a_stalled_search_stops(problem, bound):
    """Any improvement is too little against a huge tolerance: the search stops once the
    window has passed (above its ceiling, the far window); against a tolerance of zero it never
    stalls, nor above its ceiling without a far window or above the far window's cost."""
    stalled = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=30.0,
                             lower_bound_cost=bound.cost, target=bound.state,
                             stall=StallRule(0.3, 1e9))
    assert stalled.stop_reason == "stalled" and 0.3 <= stalled.elapsed_s < 5.0
    far = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=30.0,
                         lower_bound_cost=bound.cost, target=bound.state,
                         stall=StallRule(0.3, 1e9, ceiling=bound.cost - 1.0, far_window_s=1.5))
    assert far.stop_reason == "stalled" and 1.5 <= far.elapsed_s < 6.0
    no_gain_yet = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=1.0,
                                 lower_bound_cost=bound.cost, target=bound.state,
                                 stall=StallRule(0.3, 1e9, ceiling=bound.cost - 1.0,
                                                 far_window_s=0.3, far_below=bound.cost - 1.0))
    assert no_gain_yet.stop_reason == "time"
    for patient in (StallRule(0.3, 0.0), StallRule(0.3, 1e9, ceiling=bound.cost - 1.0)):
        result = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=1.0,
                                lower_bound_cost=bound.cost, target=bound.state, stall=patient)
        assert result.stop_reason == "time"


@pytest.mark.parametrize("kwargs,message", [
    ({"mode": "astar"}, "unknown planner mode"),
    ({"stall": StallRule(0.0, 0.1)}, "stall rule needs windows"),
    ({"stall": StallRule(1.0, -0.1)}, "stall rule needs windows"),
    ({"stall": StallRule(1.0, 0.1, far_window_s=0.0)}, "stall rule needs windows"),
    ({"time_budget_s": None}, "give a time budget"),
    ({"time_budget_s": -1.0}, "time budget must be > 0"),
    ({"max_nodes": 0}, "node budget"),
    ({"target": np.zeros((2, 3))}, "target must have shape"),
])
def test_bad_arguments(problem, kwargs, message):
    with pytest.raises(PlannerError, match=message):
        TASK_SPACE_RRT(problem, **kwargs)


def test_overlapping_start_is_rejected():
    scenario = load_scenario("tset3")
    models = learn_all(scenario.objects)
    moved = replace(scenario, objects=tuple(replace(o, pose=scenario.objects[0].pose)
                                            for o in scenario.objects))
    with pytest.raises(PlannerError, match="start state violates"):
        PlanningProblem(moved, models)


def test_lower_bound_is_feasible_and_below_start(problem, bound):
    assert problem.state_valid(bound.state + 0.0) or problem.checker.constraint_values(
        bound.state).min() > -1e-5
    assert bound.cost <= problem.objective.cost(problem.start)
    state, cost, feasible = local_minimum(problem, problem.start)
    assert feasible and cost <= problem.objective.cost(problem.start) + 1e-12


def test_a_local_minimum_keeps_held_objects_where_they_are(problem):
    held = np.zeros(problem.n, bool)
    held[1] = True
    state, cost, feasible = local_minimum(problem, problem.start, held=held)
    assert feasible and cost <= problem.objective.cost(problem.start) + 1e-12
    np.testing.assert_array_equal(state[1], problem.start[1])
    assert np.abs(state[~held] - problem.start[~held]).max() > 1e-3


def test_a_local_minimum_keeps_pinned_objects_on_their_line(problem):
    pinned = np.zeros((problem.n, 2))
    pinned[1] = (math.cos(0.3), math.sin(0.3))
    state, cost, feasible = local_minimum(problem, problem.start, pinned=pinned)
    assert feasible and cost <= problem.objective.cost(problem.start) + 1e-12
    moved = state[1, :2] - problem.start[1, :2]
    assert abs(moved @ pinned[1]) < 1e-6
    assert np.linalg.norm(moved) > 1e-3


def test_stranded_pushes_name_the_unreachable_face(tset6):
    """tset6's platter_2 starts where the arm reaches three of its four faces: the direction
    returned is that of the fourth face's push."""
    count, direction = tset6.stranded_pushes(tset6.start)
    assert count.tolist() == [0] * 5 + [1]
    np.testing.assert_array_equal(direction[:5], 0.0)
    assert np.linalg.norm(direction[5]) == pytest.approx(1.0)
    reached = tset6._approaches_reached(np.array([5]), tset6.start[[5]])[0]
    missing = int(np.nonzero(~reached & tset6.available[5, :4])[0][0])
    step = tset6.apply(tset6.start, 5, missing + 1, 0.02)[5, :2] - tset6.start[5, :2]
    assert step @ direction[5] == pytest.approx(np.linalg.norm(step), rel=1e-3)


def test_directgd_keeps_an_object_the_arm_cannot_get_behind_on_its_line(tset6):
    """A target that moves platter_2 along the push the arm cannot make is out of the search's
    reach; across it the platter is free, which lets the descent reach targets as good as the
    free one's."""
    count, direction = tset6.stranded_pushes(tset6.start)
    search = tsrrt_search(tset6)
    state, cost = search.directgd(0)
    moved = state[5, :2] - tset6.start[5, :2]
    assert abs(moved @ direction[5]) < 1e-6
    assert cost < tset6.objective.cost(tset6.start)
    free, _, _ = local_minimum(tset6, tset6.start, PlannerConfig().gd_iterations)
    assert abs((free[5, :2] - tset6.start[5, :2]) @ direction[5]) > 0.01


def test_directgd_runs_more_often_while_the_best_node_is_far_from_every_target(tset6):
    search = tsrrt_search(tset6)
    state, cost = search.directgd(0)
    search.add_target(state, cost)
    assert search.lead_cost > cost + 0.05 * abs(cost)    # the start, 78 % above the bound
    assert search.gd_period() == PlannerConfig().gd_period // 4
    search.lead_cost = cost
    assert search.gd_period() == PlannerConfig().gd_period


def test_directgd_starts_once_from_each_best_node_near_the_targets(tset6):
    search = tsrrt_search(tset6)
    state, cost = search.directgd(0)
    search.add_target(state, cost)
    search.polish(search.rearrange(0, search.choose_target(tset6.start)))
    assert search.tree.size > 10 and search.lead == search.best != 0
    assert search.far_from_targets()    # far: a random node each time, often not the best
    assert {search.descent_start() for _ in range(20)} != {search.lead}
    search.lead_cost = cost             # near: the best node, once
    assert search.descent_start() == search.lead
    assert len({search.descent_start() for _ in range(20)}) > 1
    search.lead = 1 if search.lead != 1 else 2   # a new best node: from it, once
    assert search.descent_start() == search.lead


def test_directgd_backs_off_after_descents_that_end_infeasible(tset6):
    """tset12's 36-DOF descents from its start end inside an overlap after gd_iterations;
    past the few tolerated in a row, each such descent doubles the wait for the next, and a
    feasible one (tset6) resets it."""
    scenario = resolve_scenario("tset12")
    tset12 = PlanningProblem(scenario, learn_all(scenario.objects, seed=0))
    search = tsrrt_search(tset12, target=tset12.start)
    search.lead_cost = search.targets[0].cost   # near the target: the plain period
    targets = len(search.targets)
    for failures in range(1, GD_FAILURES_TOLERATED + 3):
        search.descend_from(0)
        assert search.gd_failures == failures
        assert search.gd_period() == (2 ** max(failures - GD_FAILURES_TOLERATED, 0)
                                      * PlannerConfig().gd_period)
    assert len(search.targets) == targets
    search = tsrrt_search(tset6)
    search.gd_failures = 3
    search.descend_from(0)
    assert search.gd_failures == 0 and search.targets


def test_a_restart_extends_only_the_root_and_the_new_nodes_and_keeps_the_best(tset6):
    search = tsrrt_search(tset6, max_nodes=400)
    state, cost = search.directgd(0)
    search.add_target(state, cost)
    search.polish(search.rearrange(0, search.choose_target(tset6.start)))
    best, best_cost, size = search.best, search.best_cost, search.tree.size
    assert size > 10 and search.lead == best != 0
    search.restart()
    assert search.lead == 0 and search.epoch_start == size
    assert {search.random_node() for _ in range(20)} == {0}     # nothing grown since
    assert search.nearest_neighbor(search.tree.states[best]) == 0
    while search.tree.size < size + 20:
        search.extend_towards_a_target()
    parents = search.tree.parent[size:search.tree.size]
    assert ((parents == 0) | (parents >= size)).all()
    assert search.lead >= size and search.lead_cost == search.tree.cost[search.lead]
    assert search.best_cost <= best_cost                       # the plan's best is kept
    assert search.best == best or search.best >= size


def test_with_a_node_budget_the_restart_counts_nodes_not_seconds(problem):
    """A node budget makes a search repeatable; the restart must not look at the clock then."""
    both = tsrrt_search(problem, max_nodes=400, time_budget_s=1e-9)
    assert both.budget_spent() == pytest.approx(1 / 400)
    assert tsrrt_search(problem, max_nodes=None, time_budget_s=1e-9).budget_spent() > 1


@pytest.mark.parametrize("scenario_name, restarts", [("tset12", True), ("tset3", False)])
def test_a_search_restarts_once_only_while_far_from_the_targets(scenario_name, restarts):
    """At RESTART_AT of its node budget tset12's search is still more than RESTART_FAR above
    its best target and starts over from the root; tset3's has reached it and goes on."""
    scenario = resolve_scenario(scenario_name)
    tested = PlanningProblem(scenario, learn_all(scenario.objects, seed=0))
    optimum = lower_bound(tested, starts=2)
    search = tsrrt_search(tested, max_nodes=600, target=optimum.state)
    with pytest.raises(_Stop):
        search.run()
    assert search.restarted == restarts
    if restarts:
        assert RESTART_AT * 600 <= search.epoch_start < 600     # at the first round past it
        assert search.lead >= search.epoch_start
        assert search.best_cost <= search.tree.cost[:search.epoch_start].min()
    else:
        assert search.epoch_start == 1 and search.lead == search.best
        assert search.best_cost <= optimum.cost + RESTART_FAR * abs(optimum.cost)


@pytest.mark.parametrize("answers_before_cancel", [0, 2])
def test_a_cancelled_lower_bound_raises_instead_of_returning_a_partial_one(
        problem, answers_before_cancel):
    asked = []

    def cancel() -> bool:
        asked.append(True)
        return len(asked) > answers_before_cancel

    with pytest.raises(Cancelled, match="cancelled after"):
        lower_bound(problem, starts=4, cancel=cancel)
    assert len(asked) == answers_before_cancel + 1   # it stopped at the first True


@pytest.fixture(scope="module")
def eraser_between() -> tuple[PlanningProblem, np.ndarray, float]:
    """clean's objective gathers three boxes side by side: the local minimum descended to
    from the eraser between the scale and the remote (the remote in the middle is better)."""
    scenario = load_scenario("clean")
    problem = PlanningProblem(scenario, learn_all(scenario.objects, seed=0))
    ids = problem.objects.ids
    scale, remote, eraser = (ids.index(name) for name in ("scale", "remote", "eraser"))
    start = problem.start.copy()
    start[[scale, remote, eraser]] = [[0.45, -0.09, 0.0], [0.45, 0.053, 0.0], [0.45, 0.0, 0.0]]
    state, cost, feasible = local_minimum(problem, start, max_iterations=150)
    assert feasible and state[scale, 1] < state[eraser, 1] < state[remote, 1]
    return problem, state, cost


def test_swapping_neighbours_finds_the_better_order_of_a_cluster(eraser_between):
    problem, state, cost = eraser_between
    remote = problem.objects.ids.index("remote")
    refined, refined_cost, descents = swap_refine(problem, state, cost, deadline=math.inf)
    assert descents >= 1 and refined_cost < cost - 1e-3
    assert problem.checker.constraint_values(refined).min() > -1e-5
    middle = np.argsort(refined[:, 1])[1]
    assert middle == remote


def test_swap_refine_stops_when_cancelled(eraser_between):
    problem, state, cost = eraser_between
    with pytest.raises(Cancelled, match="after 0 exchanges"):
        swap_refine(problem, state, cost, deadline=math.inf, cancel=lambda: True)


@pytest.mark.parametrize("cost, bound, gap", [
    (-1.9, -2.0, 0.05), (0.105, 0.1, 0.05), (0.3, 0.0, None), (0.3, 1e-7, None),
    (0.3, None, None), (0.3, float("nan"), None)])
def test_relative_gap_is_none_where_it_means_nothing(cost, bound, gap):
    """Against a zero optimum (the obstacle task's goal point) any cost is an infinite relative
    gap; the benchmark, the reports and the messages then give no gap rather than 10^9 %."""
    if gap is None:
        assert relative_gap(cost, bound) is None
    else:
        assert relative_gap(cost, bound) == pytest.approx(gap)


def test_matching_permutes_only_interchangeable_objects(problem):
    groups = interchangeable_groups(problem)
    assert [list(g) for g in groups] == [[0, 1]]  # the two plates
    target = problem.start[[1, 0, 2]]
    order = assignment(groups, target, problem.start)
    np.testing.assert_array_equal(target[order], problem.start)


@pytest.mark.parametrize("size", range(1, 10))
def test_compiled_assignment_is_scipys_even_among_ties(size):
    """The search matches a few dozen targets per extension with a compiled assignment; plans
    depend on which of equally short matchings it picks, so it picks scipy's: among the many
    ties of integer costs too. Decimal costs reach equal totals by sums in different orders,
    where scipy versions differ (1.17 no longer shifts the costs by their minimum): there the
    total is scipy's."""
    rng = np.random.default_rng(size)
    rows = np.arange(size)
    for trial in range(600):
        cost = (rng.random((size, size)), rng.integers(0, 3, (size, size)).astype(float),
                np.round(rng.random((size, size)), 1))[trial % 3]
        mine, scipys = min_cost_assignment(cost), linear_sum_assignment(cost)[1]
        if trial % 3 < 2:
            np.testing.assert_array_equal(mine, scipys)
        else:
            assert cost[rows, mine].sum() == pytest.approx(cost[rows, scipys].sum())


def two_boxes_one_push() -> PlanningProblem:
    """An eraser on its goal point and a remote 4 cm short of its own, both boxes straight."""
    scenario = parse_scenario({
        "format": 1, "name": "two_boxes_one_push",
        "table": {"center": [0.45, 0.0], "size": [0.34, 0.52]},
        "objects": [{"id": "eraser", "class": "eraser", "pose": [0.52, -0.12, 0.0]},
                    {"id": "remote", "class": "remote", "pose": [0.45, 0.09, 0.0]}],
        "objective": {"terms": [
            {"type": "distance_to_point", "weight": 1.0, "objects": {"ids": ["eraser"]},
             "point": [0.52, -0.12]},
            {"type": "distance_to_point", "weight": 1.0, "objects": {"ids": ["remote"]},
             "point": [0.45, 0.05]},
            {"type": "orthogonality", "weight": 0.05, "objects": "all"}]}}, "test")
    return PlanningProblem(scenario, learn_all(scenario.objects, seed=0))


def test_heading_steps_name_the_turns_in_place_that_keep_the_cost(problem, bound):
    """tset3's plates are discs in a spread term (any heading), its platter is under
    orthogonality (quarter turns); a box whose heading a term reads otherwise may not turn."""
    steps = heading_steps(problem, bound.state, bound.cost)
    assert steps.tolist() == [0.0, 0.0, math.pi / 2]
    tilted = bound.state.copy()
    tilted[2, 2] += 0.3   # off orthogonal: a quarter turn keeps that, other turns do not
    assert heading_steps(problem, tilted, float(problem.objective.cost(tilted)))[2] == \
        pytest.approx(math.pi / 2)
    state = bound.state.copy()
    state[2, 2] += 3 * math.pi / 2 + 0.1   # the platter's nearest equal heading: 3 quarter turns
    state[0, 2] = 1.0
    turned = turned_towards(bound.state, np.array([0.0, np.inf, math.pi / 2]), state)
    assert turned[:, 2] == pytest.approx([1.0, bound.state[1, 2],
                                          bound.state[2, 2] + 3 * math.pi / 2])
    np.testing.assert_array_equal(turned[:, :2], bound.state[:, :2])


def test_a_target_turned_by_a_quarter_turn_is_reached_without_turning():
    """The lower bound may return an optimum with both boxes turned by 90 degrees (it did on
    two_boxes: 1e-10 below the straight one); the plan is still the remote's one push, not a
    detour that turns both boxes (the soak test's 18- and 24-push plans; here 11-46 pushes
    when the target's headings were steered to as found). The shortest plan within 1 mm of the
    best, as a task loop converging at 5 % would ask for."""
    two_boxes = two_boxes_one_push()
    target = np.array([[0.52, -0.12, -math.pi / 2], [0.45, 0.05, math.pi / 2]])
    for seed in (0, 1, 2):
        result = TASK_SPACE_RRT(two_boxes, "tsrrt", seed=seed, max_nodes=600,
                                lower_bound_cost=0.0, target=target, shortest_within=0.001)
        assert len(result.steps) <= 3, (seed, result.steps)
        assert result.costs[-1] < 0.002


def test_a_disc_is_pushed_straight_along_the_table_axes():
    """Perception keeps a disc at heading 0, so the plan must too (the shipped tset6 plate
    models turn a plate 0.004-0.011 rad per push, which would tilt its later pushes away from
    the table axes the executor pushes along), and a disc is symmetric about its push line:
    the models' 2 mm of side drift, the same way for pushes 1 and 2, would walk it sideways
    by pushing it back and forth."""
    scenario = load_scenario("tset6")
    models = ModelStore.load(default_models(scenario))
    assert abs(models.models[("plate_1", 2)].mean[2]) > 0.005
    assert models.models[("plate_1", 1)].mean[1] * models.models[("plate_1", 2)].mean[1] > 0
    tset6 = PlanningProblem(scenario, models)
    plate = tset6.objects.ids.index("plate_1")
    state = tset6.start
    for primitive, length in ((1, 0.04), (2, 0.04), (3, 0.03)):
        state = tset6.apply(state, plate, primitive, length)
    assert state[plate, 2] == 0.0
    moved = state[plate, :2] - tset6.start[plate, :2]
    along = tset6.rates[plate, :4, :2]
    assert moved == pytest.approx([0.04 * (along[0, 0] + along[1, 0]), 0.03 * along[2, 1]])
    assert along[[0, 1], 1].tolist() == [0.0, 0.0] and along[[2, 3], 0].tolist() == [0.0, 0.0]


def test_push_constraints_reject_unreachable_and_blocked_pushes(problem):
    from tsrrt_planner.reachability import AnnulusReachability

    state = problem.start.copy()
    objects, primitives = problem.action_objects, problem.action_primitives
    lengths = np.full(len(objects), 0.01)
    assert problem.pushes_valid(state, objects, primitives, lengths).any()
    far = PlanningProblem(problem.scenario, learn_all(problem.scenario.objects),
                          reachability=AnnulusReachability(0.9, 1.0))
    assert not far.pushes_valid(state, objects, primitives, lengths).any()
    # put plate_2 right beside plate_1 along the direction primitive 2 pushes plate_1
    u = problem.push_directions(state, np.array([0]), np.array([2]))[0]
    state[1, :2] = state[0, :2] + 0.11 * u[:2] / np.linalg.norm(u[:2])
    assert problem.state_valid(state)
    assert problem.pushes_valid(state, np.array([0]), np.array([2]), np.array([0.002]))[0]
    assert not problem.pushes_valid(state, np.array([0]), np.array([2]), np.array([0.05]))[0]


def test_an_object_wedged_at_the_near_edge_cannot_move(problem):
    """plate_2 at the near edge in front of the base, the platter 6 mm beside it: the ball
    can get neither behind it nor to its platter side (the reach, with its margin, starts at
    x = 0.35 m there), ahead of it the push would leave the table, and the one push left
    would bring it within the margin of the platter. Move the platter 3 cm away, or the plate
    out from the edge, and it can move again."""
    state = np.array([[0.57, 0.20, 0.0], [0.331, -0.02, 0.0], [0.40, -0.121, 0.0]])
    assert problem.state_valid(state)
    assert not can_move(problem, state, 1)
    assert can_move(problem, state, 0) and can_move(problem, state, 2)
    away = state.copy()
    away[2, 1] -= 0.03
    assert can_move(problem, away, 1)
    out = state.copy()
    out[1:, 0] += 0.12
    assert can_move(problem, out, 1)


@pytest.fixture(scope="module")
def clean() -> PlanningProblem:
    scenario = load_scenario("clean")
    return PlanningProblem(scenario, learn_all(scenario.objects, seed=0))


def test_a_box_beside_a_neighbour_cannot_turn(clean):
    """clean's eraser 10 degrees off, 4 mm beside the remote: the ball fits on neither long
    face's side that would turn it back, so the turn is lost; 11 cm further out it is not."""
    grid = np.geomspace(clean.min_length, clean.max_length, 10)
    beside = np.array([[0.448, -0.084, math.pi], [0.449, 0.005, -0.019],
                       [0.456, 0.066, -0.167]])
    assert clean.state_valid(beside)
    assert lost_turn(clean, beside, 2, grid) > 0.0
    away = beside.copy()
    away[2, 1] += 0.11
    assert lost_turn(clean, away, 2, grid) == 0.0
    plates = load_scenario("tset3")
    discs = PlanningProblem(plates, learn_all(plates.objects, seed=0))
    assert lost_turn(discs, discs.start, 0, grid) == 0.0   # a disc has no heading to lose


def test_polishing_turns_a_box_before_pushing_it_in_beside_a_neighbour(clean):
    """Pushing the eraser in towards the remote lowers the cost most, but leaves it unable to
    turn by more than that push gains: polishing turns it first."""
    grid = np.geomspace(clean.min_length, clean.max_length, 10)
    state = np.array([[0.448, -0.084, math.pi], [0.449, 0.005, -0.019],
                      [0.456, 0.116, -0.3]])
    objects = np.repeat(clean.action_objects, len(grid))
    primitives = np.repeat(clean.action_primitives, len(grid))
    lengths = np.tile(grid, len(clean.action_objects))
    valid = clean.pushes_valid(state, objects, primitives, lengths)
    after = [clean.apply(state, int(o), int(p), float(length)) for o, p, length
             in zip(objects[valid], primitives[valid], lengths[valid], strict=True)]
    greedy = int(np.argmin(clean.objective.cost(np.array(after))))
    assert (objects[valid][greedy], primitives[valid][greedy]) == (2, 4)
    gain = clean.objective.cost(state) - clean.objective.cost(after[greedy])
    assert lost_turn(clean, after[greedy], 2, grid) > gain
    push = polish_push(clean, state, grid)
    assert push is not None and push[:2] == (2, 5)
    assert clean.objective.cost(clean.apply(state, *push)) < clean.objective.cost(state)


@pytest.fixture(scope="module")
def tset6() -> PlanningProblem:
    scenario = load_scenario("tset6")
    return PlanningProblem(scenario, learn_all(scenario.objects, seed=0))


def test_targets_that_send_a_stranded_object_where_nothing_pushes_it_are_left_out(tset6):
    """platter_2 starts in the blind spot, where the arm cannot get behind it: a target
    further out along that push is out of reach from here; aside or back is not."""
    search, state = tsrrt_search(tset6), tset6.start
    stranded, direction = tset6.stranded_pushes(state)
    assert stranded.tolist() == [0, 0, 0, 0, 0, 1]
    out, aside, back = state.copy(), state.copy(), state.copy()
    out[5, :2] += 0.05 * direction[5]
    aside[5, :2] += 0.05 * np.array([-direction[5, 1], direction[5, 0]])
    back[5, :2] -= 0.05 * direction[5]
    targets = np.array([out, aside, back, state])
    assert search.leaves_stranded_in_line(state, targets).tolist() == [False, True, True, True]


def starting_at(problem: PlanningProblem, poses: dict[str, tuple[float, float, float]]
                ) -> PlanningProblem:
    """`problem`'s scenario started from `poses` (every object's), with the same models."""
    scenario = problem.scenario
    objects = tuple(replace(spec, pose=Pose2D(*poses[spec.id])) for spec in scenario.objects)
    return PlanningProblem(replace(scenario, objects=objects),
                           learn_all(scenario.objects, seed=0))


def test_rearrange_places_a_row_along_an_edge_without_parking(tset6):
    """Two plates go to a row along the far edge, side by side at the margin. Aimed 2 mm in
    from the edges, the corner plate would come within the margin of its neighbour and each
    would wait for the other; ordered by the arrangement itself, both go straight there (with
    the inset aims: 8 parkings, 20 pushes, one plate 2.4 cm short)."""
    poses = {"plate_1": (0.57, 0.09, 0.0), "plate_2": (0.465, 0.09, 0.0),
             "plate_3": (0.33, -0.21, 0.0), "plate_4": (0.33, 0.21, 0.0),
             "platter_1": (0.50, -0.15, 0.0), "platter_2": (0.40, -0.02, 0.0)}
    problem = starting_at(tset6, poses)
    corner, beside = (problem.objects.ids.index(name) for name in ("plate_1", "plate_2"))
    _, _, x_max, y_max = problem.scenario.table.bounds
    radius = problem.objects.half_length[corner]
    arrangement = problem.start.copy()
    arrangement[corner, :2] = x_max - radius, y_max - radius
    arrangement[beside, :2] = x_max - 3 * radius - problem.checker.margin, y_max - radius
    search = tsrrt_search(problem, max_nodes=1000)
    parkings = []
    park = search.park
    search.park = lambda *args: parkings.append(args) or park(*args)
    end = search.tree.states[search.rearrange(0, arrangement)]
    assert not parkings
    np.testing.assert_allclose(end[[corner, beside], :2], arrangement[[corner, beside], :2],
                               atol=0.004)


def test_rearrange_swaps_targets_to_get_a_walled_in_plate_out(tset6):
    """plate_1 stands on the +y side of the platters, its corner (by the base, at -y) on the
    other side: the platters wall it in, the far corner plates close the strip past them, and
    no parking pose for a platter clears its way (tset6 seed 24's search sat there, 23 %
    above the bound). plate_2's far corner is in reach once plate_2 has gone, so plate_1 takes
    it; plate_2 then takes plate_3's, down the strip, and plate_3 the free corner by the base."""
    poses = {"plate_1": (0.408, 0.139, 0.0), "plate_2": (0.57, 0.21, 0.0),
             "plate_3": (0.57, -0.21, 0.0), "plate_4": (0.33, 0.208, 0.0),
             "platter_1": (0.455, -0.001, -1.57), "platter_2": (0.357, 0.002, 1.545)}
    problem = starting_at(tset6, poses)
    ids = problem.objects.ids
    arrangement = problem.start.copy()
    corners = {"plate_1": (0.33, -0.21), "plate_2": (0.57, 0.21), "plate_3": (0.57, -0.21),
               "plate_4": (0.33, 0.21)}
    for name, corner in corners.items():
        arrangement[ids.index(name), :2] = corner
    search = tsrrt_search(problem, max_nodes=2000)
    swaps = []
    swap = search.swap_targets
    search.swap_targets = lambda *args, **kwargs: (swaps.append(swap(*args, **kwargs))
                                                   or swaps[-1])
    end = search.tree.states[search.rearrange(0, arrangement)]
    assert swaps.count(True) == 2
    plates = [ids.index(name) for name in corners]
    ends = {tuple(np.round(end[i, :2], 2)) for i in plates}
    assert ends == {(0.57, 0.21), (0.57, -0.21), (0.33, -0.21), (0.33, 0.21)}
    assert problem.state_valid(end)


def test_polishing_looks_past_the_pushes_that_would_cross_the_edge(tset6):
    """tset6 with every plate 2 mm short of its corner: the 64 pushes that lower the cost most
    are the longer ones into the corners, all past the edges. Polishing leaves out the pushes
    that end off the table before it takes the best 64, and finds the 2-mm push that a search
    over every candidate finds."""
    grid = np.geomspace(tset6.min_length, tset6.max_length, 10)
    short = np.array([[0.332, -0.208, 0.0], [0.568, 0.208, 0.0], [0.57, -0.208, 0.0],
                      [0.33, 0.208, 0.0], [0.446, 0.0, -1.562], [0.329, 0.0, 1.56]])
    assert tset6.state_valid(short)
    assert polish_push(tset6, short, grid, on_table_first=False) is None
    push = polish_push(tset6, short, grid)
    assert push is not None and push[2] == pytest.approx(tset6.min_length)
    assert push == polish_push(tset6, short, grid, limit=None)
    assert tset6.objective.cost(tset6.apply(short, *push)) < tset6.objective.cost(short)


def test_a_plan_ends_where_no_push_lowers_the_cost(tset6):
    """With shortest_within 0 the plan's end is polished over every candidate push (before,
    each of seeds 0-3 at 150 nodes ended a 2-5 mm push short of a corner). Every push the
    search may make: with a target it keeps the face rule, which rules out pushes that strand
    an object's faces out of the arm's reach (seeds 0 and 1 end where such pushes are left)."""
    bound = lower_bound(tset6, starts=4)
    searched = tset6.with_face_allowance(equivalent_targets(tset6, bound.state),
                                         interchangeable_groups(tset6))
    grid = np.geomspace(tset6.min_length, tset6.max_length, 10)
    for seed in (0, 1):
        result = TASK_SPACE_RRT(tset6, "tsrrt", seed=seed, max_nodes=150,
                                lower_bound_cost=bound.cost, target=bound.state)
        assert polish_push(searched, result.states[-1], grid, limit=None) is None
    assert result.trace[-1][2] <= result.best_cost   # the anytime trace has its gain too


def test_a_finishing_push_is_folded_into_the_earlier_push_it_completes(problem):
    """A disc's 2-mm push after a 3-cm push of the same primitive (another object's push in
    between) becomes one 3.2-cm push to the same end; a turning box's is kept (lengthening
    its earlier push would not end where the two pushes do)."""
    plate, other, platter = 0, 1, 2
    steps = [(plate, 3, 0.03), (other, 3, 0.02), (plate, 3, 0.002)]
    absorbed = absorb_pushes(problem, steps, first=2)
    assert absorbed == [(plate, 3, pytest.approx(0.032)), (other, 3, 0.02)]
    np.testing.assert_allclose(simulate(problem, absorbed)[-1], simulate(problem, steps)[-1],
                               atol=1e-12)
    turning = [(platter, 1, 0.03), (plate, 3, 0.02), (platter, 1, 0.002)]
    assert problem.rates[platter, 0, 2] != 0.0
    assert absorb_pushes(problem, turning, first=2) == turning


def test_shortening_stops_when_the_result_is_due(problem):
    """Folding, merging and shortening runs replay the plan from each change, about the square
    of its length: after a 10-s budget they took a 787-push tset12 plan to 18 s. Told to stop,
    each returns the plan as it stands."""
    plate, other = 0, 1
    folds = [(plate, 3, 0.03), (other, 3, 0.02), (plate, 3, 0.002)]
    merges = [(plate, 3, 0.01), (plate, 3, 0.01), (other, 3, 0.02)]
    weights = np.where(problem.objects.is_disc, 0.0, problem.objects.half_length)
    runs = [(plate, 3, 0.01)] * 4
    assert absorb_pushes(problem, folds, first=2) != folds
    assert merge_runs(problem, merges) != merges
    assert shorten_runs(problem, runs, weights, np.inf) != runs
    assert absorb_pushes(problem, folds, first=2, stop=lambda: True) == folds
    assert merge_runs(problem, merges, stop=lambda: True) == merges
    assert shorten_runs(problem, runs, weights, np.inf, stop=lambda: True) == runs


def test_no_push_of_a_plan_folds_into_an_earlier_one(tset6):
    """The returned plan has each push folded into the latest earlier push of its object and
    primitive where that keeps it valid and ending no worse, not only the finishing pushes:
    the search's POLISH and REARRANGE's paths leave short pushes mid-plan that finish an
    earlier one."""
    bound = lower_bound(tset6, starts=4)
    searched = tset6.with_face_allowance(equivalent_targets(tset6, bound.state),
                                         interchangeable_groups(tset6))
    index = {object_id: i for i, object_id in enumerate(tset6.objects.ids)}
    for seed in (0, 1):
        result = TASK_SPACE_RRT(tset6, "tsrrt", seed=seed, max_nodes=300,
                                lower_bound_cost=bound.cost, target=bound.state)
        steps = [(index[step.object_id], step.primitive, step.push_length)
                 for step in result.steps]
        assert absorb_pushes(searched, steps, first=1) == steps


def test_tracking_a_plan_from_its_own_start_repeats_it(problem):
    steps = [(0, 3, 0.03), (1, 3, 0.02), (0, 1, 0.01)]
    planned = list(simulate(problem, steps))
    weights = np.where(problem.objects.is_disc, 0.0, problem.objects.half_length)
    pushes, states = track_plan(problem, problem.start, steps, planned, weights)
    assert [(o, p) for o, p, _ in pushes] == [(o, p) for o, p, _ in steps]
    np.testing.assert_allclose([length for _, _, length in pushes],
                               [length for _, _, length in steps], atol=1e-12)
    np.testing.assert_allclose(states, planned, atol=1e-12)


def test_a_plan_tracked_from_a_millimetre_off_still_ends_at_its_poses(problem):
    """A push that ends 0.2 mm short of where it turns invalid (the table edge, a neighbour),
    replayed as it was from a start 1 mm further along, is invalid; re-aimed at the pose it
    gave its object, it is shortened and ends there."""
    weights = np.where(problem.objects.is_disc, 0.0, problem.objects.half_length)
    # a plate's push that turns invalid before its longest length
    plate, primitive = next(
        (o, p) for o in np.nonzero(problem.objects.is_disc)[0] for p in (1, 2, 3, 4)
        if problem.pushes_valid(problem.start, np.array([o, o]), np.array([p, p]), np.array(
            [problem.min_length, problem.max_lengths[o]])).tolist() == [True, False])

    def valid(state: np.ndarray, length: float) -> bool:
        return bool(problem.pushes_valid(state, np.array([plate]), np.array([primitive]),
                                         np.array([length]))[0])

    low, high = problem.min_length, problem.max_lengths[plate]
    for _ in range(40):
        low, high = ((low + high) / 2, high) if valid(problem.start, (low + high) / 2) else (
            low, (low + high) / 2)
    steps = [(plate, primitive, low - 0.0002)]
    planned = list(simulate(problem, steps))
    off = problem.apply(problem.start, plate, primitive, 0.001)
    assert replay_from(problem, off, steps) is None
    pushes, states = track_plan(problem, off, steps, planned, weights)
    assert pushes[0][2] == pytest.approx(low - 0.0012, abs=1e-9)
    np.testing.assert_allclose(states[-1], planned[-1], atol=1e-9)


@pytest.mark.parametrize("mode", MODES)
def test_a_warm_started_plan_is_no_worse_than_its_warm_start(problem, bound, mode):
    previous = TASK_SPACE_RRT(problem, "tsrrt", seed=3, time_budget_s=None, max_nodes=300,
                              lower_bound_cost=bound.cost, target=bound.state)
    # A budget so small that the search alone gets nowhere near the previous plan.
    cold = TASK_SPACE_RRT(problem, mode, seed=4, time_budget_s=None, max_nodes=5)
    warm = TASK_SPACE_RRT(problem, mode, seed=4, time_budget_s=None,
                          max_nodes=len(previous.steps) + 5, warm_start=previous.steps)
    assert cold.best_cost > previous.best_cost
    # shortening the plan may give up a little of its cost for fewer pushes
    assert warm.best_cost <= previous.best_cost + PAIR_COST_TOLERANCE * abs(previous.best_cost)
    replay(problem, warm)


def test_a_warm_start_is_kept_up_to_its_first_invalid_push(problem):
    previous = TASK_SPACE_RRT(problem, "greedy", seed=0, time_budget_s=None, max_nodes=400)
    assert len(previous.steps) >= 2
    first = previous.steps[0]
    # Pushing a different object with a push that leaves the table is invalid from the start.
    invalid = replace(first, push_length=problem.max_length * 100)
    result = TASK_SPACE_RRT(problem, "greedy", seed=0, time_budget_s=None, max_nodes=2,
                            warm_start=(first, invalid, *previous.steps[1:]))
    assert result.nodes == 2          # the root and the first push, nothing after the invalid one
    assert result.best_cost == pytest.approx(float(previous.costs[1]))


def test_a_warm_start_with_an_unknown_object_is_an_error(problem):
    step = TASK_SPACE_RRT(problem, "greedy", seed=0, time_budget_s=None, max_nodes=3).steps[0]
    with pytest.raises(PlannerError, match="unknown objects \\['teapot'\\]"):
        TASK_SPACE_RRT(problem, "greedy", time_budget_s=1.0,
                       warm_start=[replace(step, object_id="teapot")])


def test_a_replan_heads_for_the_previous_goal_first(problem, bound):
    previous = TASK_SPACE_RRT(problem, "tsrrt", seed=3, time_budget_s=None, max_nodes=300,
                              lower_bound_cost=bound.cost, target=bound.state)
    # Without a target and with few nodes the search only polishes; given the previous plan's
    # goal it rearranges there and ends near that plan's cost.
    alone = TASK_SPACE_RRT(problem, "tsrrt", seed=5, time_budget_s=None, max_nodes=60)
    guided = TASK_SPACE_RRT(problem, "tsrrt", seed=5, time_budget_s=None, max_nodes=60,
                            previous_goal=previous.states[-1])
    assert guided.best_cost < alone.best_cost
    assert guided.best_cost <= previous.best_cost + 0.05 * abs(previous.best_cost)
    replay(problem, guided)
    with pytest.raises(PlannerError, match="previous_goal must have shape"):
        TASK_SPACE_RRT(problem, "tsrrt", time_budget_s=1.0, previous_goal=np.zeros((2, 3)))


def test_a_warm_start_ends_at_its_lowest_cost(problem):
    previous = TASK_SPACE_RRT(problem, "greedy", seed=0, time_budget_s=None, max_nodes=400)
    assert previous.stop_reason == "converged"    # at a local minimum: every push goes uphill
    final, index = previous.states[-1], {o: i for i, o in enumerate(problem.objects.ids)}
    uphill = next(
        PlanStep(problem.objects.ids[o], int(p), problem.nominal_length)
        for o, p in zip(problem.action_objects, problem.action_primitives, strict=True)
        if problem.pushes_valid(final, np.array([o]), np.array([p]),
                                np.array([problem.nominal_length]))[0])
    assert problem.objective.cost(problem.apply(
        final, index[uphill.object_id], uphill.primitive, uphill.push_length)) > (
            previous.best_cost)
    result = TASK_SPACE_RRT(problem, "greedy", seed=0, time_budget_s=None, max_nodes=400,
                            warm_start=(*previous.steps, uphill))
    assert result.nodes == len(previous.steps) + 1     # the uphill push was left out
    assert result.best_cost == pytest.approx(previous.best_cost)


KERNELS_AFTER_A_PLAN = """
import numba
from tsrrt_common.scenario import load_scenario
from tsrrt_planner import collision, objectives, problem, reachability, rearrange, task_space_rrt
from tsrrt_planner.push_rule import learn_all
from tsrrt_planner.task_space_rrt import TASK_SPACE_RRT, compile_search_kernels

def signatures():
    return {f"{module.__name__}.{name}": len(kernel.signatures)
            for module in (collision, objectives, problem, reachability, rearrange,
                           task_space_rrt)
            for name, kernel in vars(module).items()
            if isinstance(kernel, numba.core.registry.CPUDispatcher)}

scenario = load_scenario("tset3")
planning = problem.PlanningProblem(scenario, learn_all(scenario.objects, seed=0))
compile_search_kernels(planning)
before = signatures()
TASK_SPACE_RRT(planning, "tsrrt", 0, max_nodes=60, time_budget_s=None)
print({name: (before[name], count) for name, count in signatures().items()
       if count != before[name]})
"""


def test_a_plan_compiles_no_kernel_of_its_own():
    """Every numba kernel is compiled (or loaded from numba's cache) before a search's clock
    starts: on a fresh install the push checks' and REARRANGE's took 1.2 s of a first plan.
    In a process of its own, where nothing has been compiled yet."""
    run = subprocess.run([sys.executable, "-c", KERNELS_AFTER_A_PLAN], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "{}", f"compiled during the plan: {run.stdout}"


def test_the_search_keeps_the_shortening_share_only_near_the_best_target(problem):
    """tsrrt leaves SHORTCUT_SHARE of a time budget for shortening only once its best node is
    within SHORTCUT_NEAR of the best target (FAR_FROM_TARGETS when the plan's length counts);
    above that it searches until SHORTCUT_SHARE_FAR is left."""
    bound = lower_bound(problem, starts=2)
    limits = {}
    for push_cost in (0.0, 1e-3):
        search = tsrrt_search(problem, max_nodes=None, target=bound.state, time_budget_s=10.0,
                              push_cost=push_cost)
        for share in (0.5 * SHORTCUT_NEAR, 2.0 * SHORTCUT_NEAR, 2.0 * FAR_FROM_TARGETS):
            search.best_cost = bound.cost + share * abs(bound.cost)
            limits[push_cost, share] = search.search_time_limit() / 10.0
    near, far = pytest.approx(1.0 - SHORTCUT_SHARE), pytest.approx(1.0 - SHORTCUT_SHARE_FAR)
    assert limits == {(0.0, 0.5 * SHORTCUT_NEAR): near, (0.0, 2.0 * SHORTCUT_NEAR): far,
                      (0.0, 2.0 * FAR_FROM_TARGETS): far, (1e-3, 0.5 * SHORTCUT_NEAR): near,
                      (1e-3, 2.0 * SHORTCUT_NEAR): near, (1e-3, 2.0 * FAR_FROM_TARGETS): far}
