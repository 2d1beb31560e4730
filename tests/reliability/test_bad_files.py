"""Malformed or contradictory scenario files, through the loader every node uses.

Each case is one fault in an otherwise valid file (the first test proves the base file loads and
its objective builds), written to disk and loaded with `load_scenario(path)`, as sim_node,
perception_node and planner_node do. The error must be a ScenarioError whose message names the
field (dotted path) and the problem. Objective-term parameters are the planner's to check
(`build_objective`, which planner_node calls at startup): those cases raise ObjectiveError.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from tsrrt_common.errors import ScenarioError
from tsrrt_common.scenario import load_scenario
from tsrrt_planner.errors import ObjectiveError
from tsrrt_planner.objectives import build_objective

CATEGORY = "scenario and objective files"

BASE: dict[str, Any] = {
    "format": 1,
    "name": "reliability",
    "table": {"center": [0.45, 0.0], "size": [0.34, 0.52]},
    "objects": [
        {"id": "eraser_1", "class": "eraser", "pose": [0.36, -0.12, 0.0]},
        {"id": "plate_1", "class": "plate", "pose": [0.50, 0.10, 0.0]},
        {"id": "remote_1", "class": "remote", "pose": [0.52, -0.10, 0.3]},
    ],
    "objective": {"terms": [{"type": "spread", "weight": 1.0},
                            {"type": "distance_to_point", "weight": 1.0,
                             "point": "table_center"}]},
}


def changed(change: Callable[[dict[str, Any]], Any]) -> dict[str, Any]:
    """BASE with one change applied to a deep copy."""
    document = copy.deepcopy(BASE)
    change(document)
    return document


def write(tmp_path: Path, content: dict[str, Any] | str | bytes) -> Path:
    path = tmp_path / "scenario.yaml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content if isinstance(content, str) else yaml.safe_dump(content))
    return path


def objects(document: dict[str, Any]) -> list[dict[str, Any]]:
    return document["objects"]


def terms(document: dict[str, Any]) -> list[dict[str, Any]]:
    return document["objective"]["terms"]


def crowd(document: dict[str, Any]) -> None:
    """Random poses for every object on a table shorter than the remote."""
    for entry in objects(document):
        entry["pose"] = "random"
    document["table"]["size"] = [0.14, 0.14]


def test_the_base_file_is_valid(tmp_path: Path) -> None:
    """Every case below differs from this file in one place only."""
    scenario = load_scenario(write(tmp_path, BASE))
    assert [o.id for o in scenario.objects] == ["eraser_1", "plate_1", "remote_1"]
    build_objective(scenario)


SCENARIO_CASES = [
    ("table missing", lambda d: d.pop("table"), "table: missing"),
    ("object without a pose", lambda d: objects(d)[0].pop("pose"), "objects[0].pose: missing"),
    ("object without a class", lambda d: objects(d)[1].pop("class"),
     "objects[1].class: missing"),
    ("table size is a string", lambda d: d["table"].update(size="large"),
     "table.size: expected a list of 2 numbers"),
    ("mass is a string", lambda d: objects(d)[0].update(mass="heavy"),
     "objects[0].mass: expected a number, got 'heavy'"),
    ("table height is a boolean", lambda d: d["table"].update(height=True),
     "table.height: expected a number, got True"),
    ("NaN in a pose", lambda d: objects(d)[0].update(pose=[math.nan, 0.0, 0.0]),
     "objects[0].pose[0]: must be finite, got nan"),
    ("infinite table centre", lambda d: d["table"].update(center=[math.inf, 0.0]),
     "table.center[0]: must be finite, got inf"),
    ("negative table size", lambda d: d["table"].update(size=[-0.34, 0.52]),
     "table.size[0]: must be > 0, got -0.34"),
    ("negative object size", lambda d: objects(d)[0].update(size=[0.12, -0.05, 0.03]),
     "objects[0].size[1]: must be > 0, got -0.05"),
    ("zero mass", lambda d: objects(d)[2].update(mass=0), "objects[2].mass: must be > 0, got 0"),
    ("box wider than long", lambda d: objects(d)[0].update(size=[0.05, 0.12, 0.03]),
     "objects[0].size: length 0.05 must be >= width 0.12"),
    ("colour component above 1", lambda d: objects(d)[0].update(color=[0.5, 2.0, 0.5]),
     "objects[0].color: RGB components must be within [0, 1]"),
    ("overlapping initial objects", lambda d: objects(d)[1].update(pose=[0.41, -0.09, 0.0]),
     "objects[1].pose: plate_1 overlaps eraser_1"),
    ("object off the table", lambda d: objects(d)[0].update(pose=[0.9, 0.0, 0.0]),
     "objects[0].pose: eraser_1 at [0.9, 0.0, 0.0] is not entirely on the table"),
    ("object across the table edge", lambda d: objects(d)[2].update(pose=[0.45, 0.25, 0.0]),
     "objects[2].pose: remote_1 at [0.45, 0.25, 0.0] is not entirely on the table"),
    ("unknown class", lambda d: objects(d)[0].update({"class": "teapot"}),
     "objects[0].class: unknown class 'teapot'; known: ["),
    ("duplicate id", lambda d: objects(d)[1].update(id="eraser_1"),
     "objects[1].id: duplicate id 'eraser_1'"),
    ("misspelt field", lambda d: objects(d)[0].update(colour=[1, 0, 0]),
     "objects[0]: unknown fields ['colour']"),
    ("empty object list", lambda d: d.update(objects=[]),
     "objects: expected a non-empty list of objects"),
    ("objects given as a mapping", lambda d: d.update(objects={"eraser_1": {}}),
     "objects: expected a non-empty list of objects"),
    ("obstacle overlapping an object",
     lambda d: d.update(obstacles=[{"id": "block", "class": "hole_punch",
                                    "pose": [0.50, 0.10, 0.0]}]),
     "objects[1].pose: plate_1 overlaps block"),
    ("unsupported format version", lambda d: d.update(format=2),
     "format: unsupported format 2; this tsrrt reads 1"),
    ("contradictory placement radii",
     lambda d: d.update(placement={"min_radius": 0.6, "max_radius": 0.3}),
     "placement: min_radius must be smaller than max_radius"),
    ("negative placement seed", lambda d: d.update(placement={"seed": -3}),
     "placement.seed: expected a non-negative integer, got -3"),
    ("random poses on a table too small for them", lambda d: crowd(d), "too crowded"),
    ("unknown objective term", lambda d: terms(d)[0].update(type="tidiness"),
     "objective.terms[0].type: unknown term 'tidiness'; known: ["),
    ("negative term weight", lambda d: terms(d)[0].update(weight=-1.0),
     "objective.terms[0].weight: must be >= 0, got -1.0"),
    ("NaN term weight", lambda d: terms(d)[1].update(weight=math.nan),
     "objective.terms[1].weight: must be finite, got nan"),
    ("term without a weight", lambda d: terms(d)[0].pop("weight"),
     "objective.terms[0].weight: missing"),
    ("no objective terms", lambda d: d["objective"].update(terms=[]),
     "objective.terms: expected a non-empty list of terms"),
    ("parameter the term does not take", lambda d: terms(d)[0].update(point=[0.4, 0.0]),
     "objective.terms[0]: unknown fields ['point']"),
    ("term selecting an absent class",
     lambda d: terms(d)[0].update(objects={"class": "platter"}),
     "objective.terms[0].objects.class: no object of class 'platter' in this scenario"),
    ("term naming an unknown object",
     lambda d: terms(d)[0].update(objects={"ids": ["eraser_1", "stapler"]}),
     "objective.terms[0].objects.ids: unknown object 'stapler'"),
    ("selector with both class and ids",
     lambda d: terms(d)[0].update(objects={"class": "plate", "ids": ["plate_1"]}),
     "objective.terms[0].objects: give exactly one of 'class' or 'ids'"),
]


@pytest.mark.parametrize("what, change, code, fragment", [
    pytest.param(what, change, "ScenarioError", fragment, id=what)
    for what, change, fragment in SCENARIO_CASES])
def test_malformed_scenario_is_refused_naming_the_field(tmp_path, what, change, code, fragment):
    path = write(tmp_path, changed(change))
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    assert type(caught.value).__name__ == code
    message = str(caught.value)
    assert message.startswith(f"{path}: "), message       # the file is named
    assert fragment in message, message


RAW_CASES = [
    ("not YAML", "objects: [\n  {id: a", "(file): not valid YAML"),
    ("a Python object tag (code execution attempt)",
     "!!python/object/apply:os.system ['touch pwned']\n", "(file): not valid YAML"),
    ("binary garbage", b"\x80\xff\x00\x13garbage", "(file): not UTF-8 text"),
    ("empty file", "", "(top level): expected a mapping, got NoneType"),
    ("top level is a list", "- format: 1\n", "(top level): expected a mapping, got list"),
]


@pytest.mark.parametrize("what, content, code, fragment", [
    pytest.param(what, content, "ScenarioError", fragment, id=what)
    for what, content, fragment in RAW_CASES])
def test_unparsable_scenario_file_is_refused(tmp_path, what, content, code, fragment):
    path = write(tmp_path, content)
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    assert fragment in str(caught.value)
    assert not (tmp_path / "pwned").exists() and not Path("pwned").exists()


@pytest.mark.parametrize("what, code, fragment", [
    ("path that is neither a file nor a shipped name", "ScenarioError",
     "(file): no such file and not a shipped scenario; shipped: [")])
def test_missing_scenario_file_lists_the_shipped_ones(tmp_path, what, code, fragment):
    with pytest.raises(ScenarioError) as caught:
        load_scenario(tmp_path / "no_such_scenario.yaml")
    assert fragment in str(caught.value)
    assert "'clean'" in str(caught.value)


OBJECTIVE_CASES = [
    ("distance point that is not [x, y]", lambda d: terms(d)[1].update(point=[0.4]),
     "objective terms[1] distance_to_point: point must be [x, y] or 'table_center', got [0.4]"),
    ("cluster_by_class without two alike objects",
     lambda d: terms(d).append({"type": "cluster_by_class", "weight": 1.0}),
     "no two of its objects share a class"),
    ("align with a single box",
     lambda d: terms(d).append({"type": "align", "weight": 1.0,
                                "objects": {"ids": ["eraser_1", "plate_1"]}}),
     "needs at least two boxes"),
    ("negative table_bounds margin",
     lambda d: terms(d).append({"type": "table_bounds", "weight": 1.0, "margin": -0.01}),
     "margin must be a finite number >= 0, got -0.01"),
    ("keep_clear region with xmin > xmax",
     lambda d: terms(d).append({"type": "keep_clear", "weight": 1.0,
                                "region": [0.6, -0.1, 0.4, 0.1]}),
     "region must be [xmin, ymin, xmax, ymax] with xmin < xmax"),
]


@pytest.mark.parametrize("what, change, code, fragment", [
    pytest.param(what, change, "ObjectiveError", fragment, id=what)
    for what, change, fragment in OBJECTIVE_CASES])
def test_contradictory_objective_is_refused_by_the_planner(tmp_path, what, change, code,
                                                           fragment):
    scenario = load_scenario(write(tmp_path, changed(change)))     # the file itself parses
    with pytest.raises(ObjectiveError) as caught:
        build_objective(scenario)
    assert fragment in str(caught.value)
