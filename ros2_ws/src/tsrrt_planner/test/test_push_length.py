"""Planned push lengths: up to 10 cm for an object whose pushes are consistent, no longer than
learned (5 cm) for one that slips and turns, or whose longer push turned it outside its
prediction in the closed loop (problem.longest_push)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tsrrt_common.scenario import load_scenario
from tsrrt_planner.bench import default_models
from tsrrt_planner.model_learning import ModelStore
from tsrrt_planner.problem import MAX_PLANNED_PUSH, PlanningProblem, longest_push
from tsrrt_planner.task_space_rrt import TASK_SPACE_RRT


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("clean")


def scattered(models: ModelStore, object_id: str, side_std: float) -> ModelStore:
    """`models` with the object's translation pushes slipping sideways by `side_std` (std)."""
    store = ModelStore(classes=models.classes)
    for (owner, primitive), model in models.models.items():
        if owner == object_id and primitive <= 4:
            m2 = model.m2.copy()
            m2[1 if primitive <= 2 else 0] = side_std**2 * model.count
            model = dataclasses.replace(model, m2=m2)
        store.add(model)
    return store


def test_consistent_objects_may_be_pushed_twice_as_far_as_learned(scenario):
    models = ModelStore.load(default_models(scenario))
    assert [longest_push(models, spec) for spec in scenario.objects] == [MAX_PLANNED_PUSH] * 3


def test_an_object_that_slips_is_pushed_no_further_than_learned(scenario):
    models = scattered(ModelStore.load(default_models(scenario)), "eraser", 0.005)
    problem = PlanningProblem(scenario, models)
    eraser = problem.objects.ids.index("eraser")
    learned = models.get("eraser", 1).push_length
    assert problem.max_lengths[eraser] == pytest.approx(learned)
    assert problem.max_lengths[problem.objects.ids.index("scale")] == MAX_PLANNED_PUSH
    # a push from the start, 1 cm shorter and 1 cm longer than learned, that both problems
    # would allow but for the length
    lengths = np.array([learned - 0.01, learned + 0.01])
    consistent = PlanningProblem(scenario, ModelStore.load(default_models(scenario)))
    primitive = next(p for p in range(1, 7) if consistent.pushes_valid(
        consistent.start, np.full(2, eraser), np.full(2, p), lengths).all())
    valid = problem.pushes_valid(problem.start, np.full(2, eraser), np.full(2, primitive),
                                 lengths)
    assert valid.tolist() == [True, False]
    result = TASK_SPACE_RRT(problem, "tsrrt", seed=0, time_budget_s=None, max_nodes=400)
    eraser_lengths = [step.push_length for step in result.steps if step.object_id == "eraser"]
    assert eraser_lengths and max(eraser_lengths) <= learned + 1e-9


def test_an_object_held_to_the_learned_length_is_pushed_no_further(scenario):
    models = ModelStore.load(default_models(scenario))
    learned = models.get("eraser", 1).push_length
    models.cap_push("eraser", learned)
    assert [longest_push(models, spec) for spec in scenario.objects] == [
        learned if spec.id == "eraser" else MAX_PLANNED_PUSH for spec in scenario.objects]
