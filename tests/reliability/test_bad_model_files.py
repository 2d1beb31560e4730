"""Corrupt or mismatched forward-model files: refused with the reason, never overwritten.

First the loader (`ModelStore.load`, what planner_node reads at startup), one fault per case in
the shipped `clean` models; then three planner_node processes, each given a bad file through its
`models_path` parameter: the node keeps running and logs the reason, every action that needs the
models says what is wrong with the file, learning refuses to start, and the file stays
byte-identical with no temporary file left beside it.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
import yaml

rclpy = pytest.importorskip("rclpy")
from rclpy.action import ActionClient  # noqa: E402

from tsrrt_common.scenario import load_scenario  # noqa: E402
from tsrrt_interfaces.action import LearnModels, PlanTask, RunTask  # noqa: E402
from tsrrt_planner.errors import ModelFileError  # noqa: E402
from tsrrt_planner.model_learning import ModelStore  # noqa: E402

CATEGORY = "model files"
SHIPPED = resources.files("tsrrt_planner").joinpath("data", "models")
BASE: dict[str, Any] = yaml.safe_load(SHIPPED.joinpath("clean.yaml").read_text())


def changed(change: Callable[[dict[str, Any]], Any]) -> str:
    document = copy.deepcopy(BASE)
    change(document)
    return yaml.safe_dump(document)


def model(document: dict[str, Any], object_id: str = "scale", primitive: int = 1
          ) -> dict[str, Any]:
    return document["objects"][object_id]["primitives"][primitive]


def clean_objects() -> list[tuple[str, str, str]]:
    return [(o.id, o.object_class, o.shape) for o in load_scenario("clean").objects]


def test_the_base_file_is_valid() -> None:
    ModelStore.from_document(BASE, "clean.yaml").check_covers(clean_objects())


FILE_CASES: list[tuple[str, str | bytes, str]] = [
    ("not YAML", "objects: {scale: [", "not valid YAML"),
    ("a Python object tag (code execution attempt)",
     "!!python/object/apply:os.system ['touch pwned']\n", "not valid YAML"),
    ("binary garbage", b"\x80\xff\x00\x13garbage", "not UTF-8 text"),
    ("empty file", "", "(top level): expected a mapping"),
    ("another file format", changed(lambda d: d.update(format="tsrrt-scenario")),
     "format: expected 'tsrrt-forward-models', got 'tsrrt-scenario'"),
    ("unknown version", changed(lambda d: d.update(version=2)),
     "version: unsupported version 2"),
    ("other units", changed(lambda d: d.update(units={"position": "cm", "angle": "deg"})),
     "units: expected {position: m, angle: rad}"),
    ("no objects", changed(lambda d: d.update(objects={})),
     "objects: expected a non-empty mapping of object ids"),
    ("NaN in a mean", changed(lambda d: model(d).update(mean=[math.nan, 0.0, 0.0])),
     "objects.scale.primitives.1.mean: expected 3 finite numbers"),
    ("mean with two numbers", changed(lambda d: model(d).update(mean=[0.01, 0.0])),
     "objects.scale.primitives.1.mean: expected 3 finite numbers"),
    ("negative sum of squares", changed(lambda d: model(d).update(m2=[-1.0, 0.0, 0.0])),
     "objects.scale.primitives.1.m2: sums of squared deviations cannot be negative"),
    ("zero trials", changed(lambda d: model(d).update(count=0)),
     "objects.scale.primitives.1.count: expected an integer >= 1, got 0"),
    ("primitive 9", changed(lambda d: d["objects"]["scale"]["primitives"].update({9: model(d)})),
     "objects.scale.primitives.9: primitive must be an integer 1-6, got 9"),
    ("huge push length", changed(lambda d: model(d).update(push_length=3.0)),
     "objects.scale.primitives.1.push_length: expected a length in"),
    ("model without m2", changed(lambda d: model(d).pop("m2")),
     "objects.scale.primitives.1: expected exactly push_length, count, mean, m2"),
    ("object without a class", changed(lambda d: d["objects"]["scale"].pop("class")),
     "objects.scale: expected the fields 'class' and 'primitives', and optionally "
     "'longest_push'"),
    ("push cap of 50 cm", changed(lambda d: d["objects"]["scale"].update(longest_push=0.5)),
     "objects.scale.longest_push: expected a length in"),
]


@pytest.mark.parametrize("what, content, code, fragment", [
    pytest.param(what, content, "ModelFileError", fragment, id=what)
    for what, content, fragment in FILE_CASES])
def test_corrupt_model_file_is_refused_naming_the_field(tmp_path, what, content, code,
                                                        fragment):
    path = tmp_path / "models.yaml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(ModelFileError) as caught:
        ModelStore.load(path)
    assert str(caught.value).startswith(f"{path}: ")
    assert fragment in str(caught.value)
    assert not (tmp_path / "pwned").exists() and not Path("pwned").exists()


@pytest.mark.parametrize("what, code, fragment", [
    ("a directory instead of a file", "ModelFileError", "cannot read (Is a directory)")])
def test_unreadable_model_path_is_refused(tmp_path, what, code, fragment):
    with pytest.raises(ModelFileError) as caught:
        ModelStore.load(tmp_path)
    assert fragment in str(caught.value)


MISMATCH_CASES = [
    ("models of another scenario (tset3 for clean)", "tset3", "scale: no models"),
    ("models learned for another class",
     changed(lambda d: d["objects"]["scale"].update({"class": "eraser"})),
     "scale: models are for class 'eraser', the object is a 'scale'"),
    ("models missing a primitive", changed(lambda d: d["objects"]["scale"]["primitives"].pop(5)),
     "scale: no model for primitives [5]"),
]


@pytest.mark.parametrize("what, models, code, fragment", [
    pytest.param(what, models, "ModelFileError", fragment, id=what)
    for what, models, fragment in MISMATCH_CASES])
def test_mismatched_models_are_refused_naming_the_object(tmp_path, what, models, code, fragment):
    path = tmp_path / "models.yaml"
    path.write_text(SHIPPED.joinpath(f"{models}.yaml").read_text() if models == "tset3"
                    else models)
    store = ModelStore.load(path)                      # well-formed: it loads
    with pytest.raises(ModelFileError) as caught:
        store.check_covers(clean_objects())
    assert fragment in str(caught.value)


# ------------------------------------------------------------------ through planner_node
ACTIONS = {"plan_task": PlanTask, "learn_models": LearnModels, "run_task": RunTask}
BAD_FILES: dict[str, str | bytes] = {
    "corrupt": changed(lambda d: model(d).update(mean=[math.nan, 0.0, 0.0])),
    "binary": b"\x80\xff\x00\x13garbage",
    "mismatched": SHIPPED.joinpath("tset3.yaml").read_text(),
}
STARTUP_PROBLEM = {"corrupt": "objects.scale.primitives.1.mean: expected 3 finite numbers",
                   "binary": "not UTF-8 text"}


class BadModelPlanner:
    """A planner_node on a domain of its own, started with one bad model file."""

    def __init__(self, launch, probe_on_domain, folder: Path, content: str | bytes) -> None:
        folder.mkdir()
        self.path = folder / "clean.yaml"
        if isinstance(content, bytes):
            self.path.write_bytes(content)
        else:
            self.path.write_text(content)
        self.original = self.path.read_bytes()
        env = launch.other_domain_env()
        self.process = launch.start("tsrrt_planner", "planner_node", "scenario:=clean",
                                    f"models_path:={self.path}", env=env)
        self.probe = probe_on_domain(int(env["ROS_DOMAIN_ID"]))
        self.actions = {name: ActionClient(self.probe, action, f"/planner/{name}")
                        for name, action in ACTIONS.items()}

    def run(self, action: str):
        goal = ACTIONS[action].Goal()
        return self.probe.execute(self.actions[action], goal, timeout=60.0).result


@pytest.fixture(scope="module")
def planners(launch, probe_on_domain, tmp_path_factory) -> dict[str, BadModelPlanner]:
    """All three start at once (their startup dominates the module's time)."""
    root = tmp_path_factory.mktemp("bad_models")
    started = {name: BadModelPlanner(launch, probe_on_domain, root / name, content)
               for name, content in BAD_FILES.items()}
    for planner in started.values():
        for client in planner.actions.values():
            assert client.wait_for_server(timeout_sec=90.0), planner.process.log()
    return started


NODE_CASES = [
    ("unreadable model file: PlanTask", "corrupt", "plan_task", "NO_MODELS",
     "the model file could not be read"),
    ("unreadable model file: LearnModels", "corrupt", "learn_models", "EXECUTION_FAILED",
     "is not overwritten"),
    ("unreadable model file: RunTask", "corrupt", "run_task", "LEARNING_FAILED",
     "is not overwritten"),
    ("binary model file: PlanTask", "binary", "plan_task", "NO_MODELS", "not UTF-8 text"),
    ("binary model file: RunTask", "binary", "run_task", "LEARNING_FAILED",
     "is not overwritten"),
    ("models of another scenario: PlanTask", "mismatched", "plan_task", "NO_MODELS",
     "scale: no models"),
]


@pytest.mark.integration
@pytest.mark.parametrize("what, file, action, code, fragment", [
    pytest.param(*case, id=case[0]) for case in NODE_CASES])
def test_planner_refuses_to_work_with_a_bad_model_file(planners, what, file, action, code,
                                                       fragment):
    planner = planners[file]
    result = planner.run(action)
    assert result.error_code == getattr(type(result), code), result.error_msg
    assert fragment in result.error_msg
    if file in STARTUP_PROBLEM:
        assert STARTUP_PROBLEM[file] in result.error_msg


@pytest.mark.integration
@pytest.mark.parametrize("file", list(BAD_FILES))
def test_bad_model_file_is_kept_and_the_node_runs(planners, file):
    planner = planners[file]
    assert planner.process.running, planner.process.log()
    assert planner.path.read_bytes() == planner.original
    assert [p.name for p in planner.path.parent.iterdir()] == [planner.path.name]
    log = planner.process.log()
    assert "Traceback" not in log, log
    if file in STARTUP_PROBLEM:
        assert STARTUP_PROBLEM[file] in log and "will not overwrite it" in log, log
