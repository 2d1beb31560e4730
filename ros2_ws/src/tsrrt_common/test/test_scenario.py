"""Scenario files: shipped ones load; malformed ones fail naming file, field and problem."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from tsrrt_common.errors import ScenarioError
from tsrrt_common.geometry import convex_polygons_separated
from tsrrt_common.scenario import load_scenario, parse_scenario, shipped_scenarios

VALID: dict[str, Any] = {
    "format": 1,
    "name": "unit",
    "table": {"center": [0.45, 0.0], "size": [0.34, 0.52]},
    "objects": [
        {"id": "a", "class": "eraser", "pose": [0.40, -0.10, 0.0]},
        {"id": "b", "class": "plate", "pose": [0.50, 0.10, 0.0]},
    ],
    "objective": {"terms": [{"type": "spread", "weight": 1.0}]},
}


def _with(path: str, value: Any) -> dict[str, Any]:
    """VALID with the dotted `path` set to value (None deletes it)."""
    data = copy.deepcopy(VALID)
    *parents, last = path.split(".")
    node: Any = data
    for key in parents:
        node = node[int(key)] if isinstance(node, list) else node[key]
    if value is None:
        del node[int(last) if isinstance(node, list) else last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return data


@pytest.mark.parametrize("name", ["clean", "tset3", "tset6", "obstacle"])
def test_shipped_scenarios_load_on_table_without_overlap(name: str) -> None:
    scenario = load_scenario(name)
    x_min, y_min, x_max, y_max = scenario.table.bounds
    everything = scenario.objects + scenario.obstacles
    for spec in everything:
        footprint = spec.footprint()
        assert footprint[:, 0].min() >= x_min and footprint[:, 0].max() <= x_max
        assert footprint[:, 1].min() >= y_min and footprint[:, 1].max() <= y_max
    for i, first in enumerate(everything):
        for second in everything[i + 1:]:
            assert convex_polygons_separated(first.footprint(), second.footprint())


def test_shipped_list_contains_the_papers_four_experiments() -> None:
    assert {"clean", "tset3", "tset6", "obstacle"} <= set(shipped_scenarios())


def test_random_placement_is_deterministic_for_a_seed_and_varies_across_seeds() -> None:
    first = load_scenario("tset6", seed=4)
    again = load_scenario("tset6", seed=4)
    other = load_scenario("tset6", seed=5)
    poses = [o.pose for o in first.objects]
    assert poses == [o.pose for o in again.objects]
    assert poses != [o.pose for o in other.objects]


def test_objects_keep_file_order_and_class_properties() -> None:
    scenario = load_scenario("tset6")
    assert [o.id for o in scenario.objects][:2] == ["plate_1", "plate_2"]
    plate = scenario.object("plate_1")
    assert plate.shape == "cylinder" and plate.symmetry == 0
    assert math.isclose(plate.length, plate.width)


def test_a_disc_gets_heading_zero_and_a_box_keeps_its_own() -> None:
    """A disc has no visible heading, so its pushes go along the table's axes (scenario._heading);
    the random heading is still drawn for it, so the other objects' placements stay put."""
    scenario = parse_scenario(_with("objects.1.pose", [0.50, 0.10, 1.2]), "unit.yaml")
    assert scenario.object("b").pose.theta == 0.0
    assert load_scenario("tset6").object("plate_1").pose.theta == 0.0
    boxed = parse_scenario(_with("objects.0.pose", [0.40, -0.10, 0.7]), "unit.yaml")
    assert boxed.object("a").pose.theta == 0.7
    platters = [load_scenario("tset6").object(f"platter_{k}").pose for k in (1, 2)]
    assert [v for p in platters for v in (p.x, p.y, p.theta)] == pytest.approx(
        [0.4917, -0.1085, -1.6281, 0.3532, -0.1126, 1.4952], abs=1e-4)  # as before discs


def test_obstacles_are_static_and_separate_from_objects() -> None:
    scenario = load_scenario("obstacle")
    assert [o.id for o in scenario.obstacles] == ["hole_punch"]
    assert all(o.static for o in scenario.obstacles)
    assert not any(o.static for o in scenario.objects)


def test_objective_selectors_resolve_to_object_ids() -> None:
    scenario = load_scenario("tset6")
    spread, centre, ortho = scenario.objective
    assert spread.object_ids == ("plate_1", "plate_2", "plate_3", "plate_4")
    assert centre.object_ids == ("platter_1", "platter_2")
    assert centre.params == {"point": "table_center"}
    assert ortho.type == "orthogonality"


def test_seed_override_is_reported() -> None:
    assert load_scenario("clean", seed=42).seed == 42
    assert load_scenario("clean").seed == 3


def test_load_from_a_path(tmp_path: Path) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump(VALID))
    scenario = load_scenario(path)
    assert scenario.name == "unit" and scenario.source == str(path)
    np.testing.assert_allclose(scenario.object("a").pose.as_array(), [0.40, -0.10, 0.0])


MALFORMED = [
    (_with("format", 2), "format", "unsupported format"),
    (_with("name", None), "name", "missing"),
    (_with("table.size", [0.3, -0.5]), "table.size[1]", "must be > 0"),
    (_with("table.center", [0.4]), "table.center", "list of 2 numbers"),
    (_with("objects", []), "objects", "non-empty list"),
    (_with("objects.0.class", "teapot"), "objects[0].class", "unknown class 'teapot'"),
    (_with("objects.0.pose", [0.4, float("nan"), 0.0]), "objects[0].pose[1]", "finite"),
    (_with("objects.0.pose", [0.9, 0.0, 0.0]), "objects[0].pose", "not entirely on the table"),
    (_with("objects.1.pose", [0.40, -0.10, 0.0]), "objects[1].pose", "overlaps a"),
    (_with("objects.1.id", "a"), "objects[1].id", "duplicate id 'a'"),
    (_with("objects.0.mass", -1.0), "objects[0].mass", "must be > 0"),
    (_with("objects.0.mass", "heavy"), "objects[0].mass", "expected a number"),
    (_with("objects.0.size", [0.05, 0.12, 0.03]), "objects[0].size", "must be >= width"),
    (_with("objects.0.color", [2.0, 0.0, 0.0]), "objects[0].color", "within [0, 1]"),
    (_with("objects.0.colour", [1.0, 0.0, 0.0]), "objects[0]", "unknown fields ['colour']"),
    (_with("objective.terms", []), "objective.terms", "non-empty list"),
    (_with("objective.terms.0.type", "tidiness"), "objective.terms[0].type", "unknown term"),
    (_with("objective.terms.0.weight", -2.0), "objective.terms[0].weight", "must be >= 0"),
    (_with("objective.terms.0.weight", float("inf")), "objective.terms[0].weight", "finite"),
    (_with("objective.terms.0.objects", {"class": "platter"}), "objective.terms[0].objects.class",
     "no object of class 'platter'"),
    (_with("objective.terms.0.objects", {"ids": ["zz"]}), "objective.terms[0].objects.ids",
     "unknown object 'zz'"),
    (_with("objective.orientation_weight", 0), "objective.orientation_weight", "must be > 0"),
    (_with("placement", {"seed": -3}), "placement.seed", "non-negative integer"),
    ("just a string", "(top level)", "expected a mapping"),
]


@pytest.mark.parametrize(("data", "field", "problem"), MALFORMED,
                         ids=[f"{case[1]}:{case[2]}" for case in MALFORMED])
def test_malformed_scenario_names_field_and_problem(data: Any, field: str, problem: str) -> None:
    with pytest.raises(ScenarioError) as raised:
        parse_scenario(data, "bad.yaml")
    assert raised.value.source == "bad.yaml"
    assert raised.value.field == field
    assert problem in raised.value.problem


def test_overcrowded_random_placement_fails_clearly() -> None:
    data = copy.deepcopy(VALID)
    data["objects"] = [{"id": f"p{i}", "class": "scale", "pose": "random"} for i in range(12)]
    with pytest.raises(ScenarioError, match="too crowded"):
        parse_scenario(data, "crowded.yaml")


def test_invalid_yaml_and_missing_file_are_reported(tmp_path: Path) -> None:
    broken = tmp_path / "broken.yaml"
    broken.write_text("objects: [unclosed")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(broken)
    with pytest.raises(ScenarioError, match="not a shipped scenario"):
        load_scenario(tmp_path / "absent.yaml")
