"""Objective terms (Sec. III-A) against hand-computed values and finite-difference gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tsrrt_common.scenario import ObjectiveTermSpec, load_scenario
from tsrrt_planner.errors import ObjectiveError
from tsrrt_planner.objectives import Objective, ObjectSet, build_objective

BOUNDS = (0.28, -0.26, 0.62, 0.26)
OBJECTS = ObjectSet(ids=("a", "b", "c", "d"), classes=("plate", "plate", "platter", "platter"),
                    half_length=np.array([0.05, 0.05, 0.08, 0.08]),
                    half_width=np.array([0.05, 0.05, 0.045, 0.045]),
                    is_disc=np.array([True, True, False, False]))


def objective(term: str, ids=("a", "b", "c", "d"), weight: float = 1.0, **params) -> Objective:
    return Objective.from_specs([ObjectiveTermSpec(term, weight, tuple(ids), params)], OBJECTS,
                                BOUNDS)


def finite_difference(obj: Objective, state: np.ndarray, step: float = 1e-6) -> np.ndarray:
    grad = np.zeros_like(state)
    for index in np.ndindex(state.shape):
        plus, minus = state.copy(), state.copy()
        plus[index] += step
        minus[index] -= step
        grad[index] = (obj.cost(plus) - obj.cost(minus)) / (2 * step)
    return grad


def random_state(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0.3, 0.6, 4), rng.uniform(-0.24, 0.24, 4),
                            rng.uniform(-3.0, 3.0, 4)])


STATE = np.array([[0.30, 0.00, 0.0], [0.30, 0.40, 0.0], [0.60, 0.00, 0.1],
                  [0.45, 0.00, 1.5]])


def test_spread_sums_each_pair_once():
    obj = objective("spread", ids=("a", "b", "c"))
    assert obj.cost(STATE) == pytest.approx(-(0.4 + 0.3 + 0.5))


def test_distance_to_table_centre_uses_eq5_centre():
    obj = objective("distance_to_point", ids=("c", "d"), point="table_center")
    assert obj.cost(STATE) == pytest.approx(0.15 + 0.0)


def test_distance_to_named_point():
    obj = objective("distance_to_point", ids=("a",), point=[0.34, 0.03])
    assert obj.cost(STATE) == pytest.approx(0.05)


def test_orthogonality_is_distance_to_nearest_right_angle_and_ignores_discs():
    obj = objective("orthogonality")
    assert obj.cost(STATE) == pytest.approx(0.1 + (math.pi / 2 - 1.5))
    # continuous across pi/2, where the printed |mod(theta, pi/2)| jumps
    below, above = STATE.copy(), STATE.copy()
    below[2, 2], above[2, 2] = math.pi / 2 - 1e-4, math.pi / 2 + 1e-4
    assert abs(obj.cost(below) - obj.cost(above)) < 1e-3


def test_weight_scales_cost():
    assert objective("spread", weight=2.5).cost(STATE) == pytest.approx(
        2.5 * objective("spread").cost(STATE))


def test_table_bounds_penalty():
    obj = objective("table_bounds", ids=("a",), margin=0.03)
    # plate a (r = 0.05) at x = 0.30 touches nothing: clearance to x_min is 0.30 - 0.05 - 0.28
    assert obj.cost(STATE) == pytest.approx((0.03 - (-0.03)) ** 2)
    # rotated platter c at x = 0.60: half extent along x is 0.08 cos 0.1 + 0.045 sin 0.1
    overshoot = 0.60 + 0.08 * math.cos(0.1) + 0.045 * math.sin(0.1) - 0.62
    assert objective("table_bounds", ids=("c",), margin=0.0).cost(STATE) == pytest.approx(
        overshoot**2)


def test_table_bounds_zero_inside_margin():
    state = STATE.copy()
    state[0] = [0.45, 0.0, 0.0]
    assert objective("table_bounds", ids=("a",), margin=0.02).cost(state) == 0.0


def test_cluster_by_class_pairs_same_class_only():
    obj = objective("cluster_by_class")
    assert obj.cost(STATE) == pytest.approx(0.4 + 0.15)


def test_keep_clear_is_shortest_escape():
    obj = objective("keep_clear", ids=("a",), region=[0.28, -0.02, 0.40, 0.10])
    # plate a at (0.30, 0.0), r = 0.05: leaving along -y needs 0.0 + 0.05 - (-0.02) = 0.07
    assert obj.cost(STATE) == pytest.approx(0.07)
    state = STATE.copy()
    state[0, :2] = [0.5, 0.2]
    assert obj.cost(state) == 0.0


def test_align_is_pairwise_right_angle_distance():
    obj = objective("align")
    assert obj.cost(STATE) == pytest.approx(abs((0.1 - 1.5) + math.pi / 2))


@pytest.mark.parametrize("term,params", [
    ("spread", {}), ("distance_to_point", {"point": "table_center"}), ("orthogonality", {}),
    ("table_bounds", {"margin": 0.2}), ("cluster_by_class", {}),
    ("keep_clear", {"region": [0.3, -0.2, 0.6, 0.2]}), ("align", {})])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gradient_matches_finite_differences(term, params, seed):
    obj = objective(term, **params)
    state = random_state(seed)
    np.testing.assert_allclose(obj.gradient(state), finite_difference(obj, state), atol=1e-5)


def test_batched_cost_and_gradient_match_single_states():
    obj = build_objective(load_scenario("tset6"))
    rng = np.random.default_rng(4)
    states = np.stack([np.column_stack([rng.uniform(0.3, 0.6, 6), rng.uniform(-0.2, 0.2, 6),
                                        rng.uniform(-3, 3, 6)]) for _ in range(5)])
    np.testing.assert_allclose(obj.cost(states), [obj.cost(s) for s in states])
    np.testing.assert_allclose(obj.gradient(states), [obj.gradient(s) for s in states])


def numpy_cost(term: str, obj: Objective, state: np.ndarray) -> float:
    """A compiled term's cost of one state as numpy gives it: a contiguous array's sum."""
    t = obj.terms[0]
    if term in ("spread", "cluster_by_class"):
        lengths = np.linalg.norm(state[t.first, :2] - state[t.second, :2], axis=1)
        return t.sign * lengths.sum()
    if term == "distance_to_point":
        return np.linalg.norm(state[t.indices, :2] - t.point, axis=1).sum()
    headings = (state[t.boxes, 2] if term == "orthogonality"
                else state[t.first, 2] - state[t.second, 2])
    return np.abs(headings - math.pi / 2 * np.round(headings / (math.pi / 2))).sum()


@pytest.mark.parametrize("count", [3, 5, 9, 17, 20])
@pytest.mark.parametrize("term,params", [
    ("spread", {}), ("distance_to_point", {"point": [0.41, -0.07]}), ("orthogonality", {}),
    ("cluster_by_class", {}), ("align", {})])
def test_compiled_costs_are_numpys_and_the_same_alone_or_batched(term, params, count):
    """A state's cost must not depend on the batch it is scored in (the search compares a line
    search's costs with the chosen node's), and these terms are compiled kernels: equal to
    numpy's bit for bit, over every path of numpy's pairwise summation (fewer than 8 values,
    8-128, halves: 20 objects make 190 pairs)."""
    rng = np.random.default_rng(count)
    objects = ObjectSet(ids=tuple(f"o{i}" for i in range(count)),
                        classes=tuple(("plate", "platter")[i % 2] for i in range(count)),
                        half_length=rng.uniform(0.02, 0.08, count),
                        half_width=rng.uniform(0.02, 0.05, count),
                        is_disc=np.arange(count) % 4 == 1)
    obj = Objective.from_specs([ObjectiveTermSpec(term, 0.7, objects.ids, params)], objects,
                               BOUNDS)
    states = np.stack([np.column_stack([rng.uniform(0.2, 0.7, count),
                                        rng.uniform(-0.3, 0.3, count),
                                        rng.uniform(-7.0, 7.0, count)]) for _ in range(150)])
    alone = [obj.cost(state) for state in states]
    assert alone == [float(0.7 * numpy_cost(term, obj, state)) for state in states]
    assert obj.cost(states).tolist() == alone
    assert obj.cost(states.reshape(3, 50, count, 3)).ravel().tolist() == alone


def test_scenario_objective_sums_weighted_terms():
    scenario = load_scenario("tset3")
    obj = build_objective(scenario)
    state = np.array([o.pose.as_array() for o in scenario.objects])
    assert obj.cost(state) == pytest.approx(sum(obj.term_costs(state).values()))


@pytest.mark.parametrize("spec,message", [
    (ObjectiveTermSpec("tidy", 1.0, ("a",)), "unknown term type 'tidy'"),
    (ObjectiveTermSpec("spread", float("nan"), ("a", "b")), "terms[0] spread: weight"),
    (ObjectiveTermSpec("spread", -1.0, ("a", "b")), "terms[0] spread: weight"),
    (ObjectiveTermSpec("spread", 1.0, ()), "applies to no object"),
    (ObjectiveTermSpec("spread", 1.0, ("a", "zz")), "unknown objects ['zz']"),
    (ObjectiveTermSpec("spread", 1.0, ("a",)), "needs at least two objects"),
    (ObjectiveTermSpec("cluster_by_class", 1.0, ("a", "c")), "no two of its objects"),
    (ObjectiveTermSpec("align", 1.0, ("a", "b", "c")), "at least two boxes"),
    (ObjectiveTermSpec("distance_to_point", 1.0, ("a",), {"point": [1.0]}), "point must be"),
    (ObjectiveTermSpec("keep_clear", 1.0, ("a",), {"region": [1, 0, 0, 1]}), "region must be"),
    (ObjectiveTermSpec("table_bounds", 1.0, ("a",), {"margin": -1}), "margin must be"),
    (ObjectiveTermSpec("spread", 1.0, ("a", "b"), {"point": [0, 0]}), "unknown parameters"),
])
def test_bad_terms_raise_errors_naming_them(spec, message):
    with pytest.raises(ObjectiveError) as error:
        Objective.from_specs([spec], OBJECTS, BOUNDS)
    assert message in str(error.value)


def test_no_terms_is_an_error():
    with pytest.raises(ObjectiveError, match="no terms"):
        Objective.from_specs([], OBJECTS, BOUNDS)
