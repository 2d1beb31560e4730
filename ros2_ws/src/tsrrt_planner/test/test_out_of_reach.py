"""An object the arm cannot push where it stands needs no models: the task is planned around it.

The plate stands at x = 0.22 m, where every approach point is inside the elbow's near limit of
the executor's reach map (x >= 0.33 m straight ahead); the eraser is well within reach.
"""

from __future__ import annotations

import dataclasses

import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import load_scenario
from tsrrt_executor.reachability import default_map
from tsrrt_planner.errors import ModelFileError
from tsrrt_planner.problem import PlanningProblem, out_of_reach
from tsrrt_planner.push_rule import learn_all

SCENARIO = """
format: 1
name: out_of_reach
table: {center: [0.40, 0.0], size: [0.48, 0.52], height: 0.0, friction: 0.5}
objects:
  - {id: eraser, class: eraser, mass: 0.08, friction: 0.55, color: [0.8, 0.2, 0.2],
     pose: [0.44, -0.12, 0.0]}
  - {id: plate, class: plate, mass: 0.30, friction: 0.30, color: [0.9, 0.9, 0.9],
     pose: [0.22, 0.0, 0.0]}
objective:
  terms:
    - {type: distance_to_point, weight: 1.0, objects: all, point: [0.45, 0.0]}
"""


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "out_of_reach.yaml"
    path.write_text(SCENARIO)
    return load_scenario(str(path))


def test_out_of_reach_follows_the_reach_map(scenario) -> None:
    reach = default_map()
    assert out_of_reach(scenario.object("plate"), reach)
    assert not out_of_reach(scenario.object("eraser"), reach)
    moved_in = dataclasses.replace(scenario.object("plate"), pose=Pose2D(0.45, 0.0, 0.0))
    assert not out_of_reach(moved_in, reach)


def test_an_object_out_of_reach_needs_no_models_and_gets_no_pushes(scenario) -> None:
    store = learn_all([scenario.object("eraser")], seed=0)
    problem = PlanningProblem(scenario, store, default_map())
    assert problem.available[0].any() and not problem.available[1].any()


def test_an_object_within_reach_still_needs_models(scenario) -> None:
    store = learn_all([scenario.object("plate")], seed=0)
    with pytest.raises(ModelFileError, match="eraser: no models"):
        PlanningProblem(scenario, store, default_map())
