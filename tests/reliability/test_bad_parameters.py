"""Bad parameters: refused at declaration (the node does not start) or when set at runtime.

At startup each node is given one bad value (`-p name:=value`, over its parameter file): it must
exit with code 1 and one FATAL line naming the parameter and the allowed range or choices, or
the file and field, never a traceback; all of them start at once, on the module's domain. At
runtime, a set_parameters call with a bad value is refused with a reason, and the node keeps
its previous value.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.integration

rclpy = pytest.importorskip("rclpy")
from rcl_interfaces.msg import Parameter as ParameterMessage  # noqa: E402
from rcl_interfaces.srv import GetParameters, SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

CATEGORY = "parameters"

MISSING_FILE = "/nonexistent/tsrrt/scenario.yaml"
# Written by the fixture: a scenario with NaN in a pose, and one whose objective is contradictory.
NAN_FILE, BAD_OBJECTIVE_FILE = "nan_pose.yaml", "bad_objective.yaml"

STARTUP_CASES = [
    ("sim physics rate below its range", "tsrrt_sim", "sim_node", "physics_hz:=1.0",
     "Parameter physics_hz out of range Min: 60.0, Max: 2000.0, value: 1.0"),
    ("sim scenario file that does not exist", "tsrrt_sim", "sim_node",
     f"scenario:={MISSING_FILE}", f"{MISSING_FILE}: (file): no such file"),
    ("sim camera rate of the wrong type", "tsrrt_sim", "sim_node", "camera_rate_hz:=fast",
     "Trying to set parameter 'camera_rate_hz' to 'fast' of type 'STRING', expecting type "
     "'DOUBLE'"),
    ("perception depth threshold above its range", "tsrrt_perception", "perception_node",
     "depth_threshold:=5.0", "Parameter depth_threshold out of range Min: 0.001, Max: 0.1"),
    ("perception minimum area below its range", "tsrrt_perception", "perception_node",
     "min_area_px:=0", "Parameter min_area_px out of range. Min: 10, Max: 100000, value: 0"),
    ("perception unknown image reliability", "tsrrt_perception", "perception_node",
     "image_reliability:=sometimes",
     "image_reliability must be one of ['best_effort', 'reliable'], got 'sometimes'"),
    ("perception scenario with NaN in a pose", "tsrrt_perception", "perception_node",
     f"scenario:={NAN_FILE}", "objects[0].pose[0]: must be finite, got nan"),
    ("executor push speed below its range", "tsrrt_executor", "executor_node",
     "push_speed:=-0.1", "Parameter push_speed out of range Min: 0.005, Max: 0.1"),
    ("executor timeout of the wrong type", "tsrrt_executor", "executor_node",
     "server_timeout:=soon", "Trying to set parameter 'server_timeout' to 'soon'"),
    ("planner unknown planner", "tsrrt_planner", "planner_node", "planner:=astar",
     "planner must be one of ['paper', 'paper-nogd', 'tsrrt', 'greedy'], got 'astar'"),
    ("planner unknown stopping rule", "tsrrt_planner", "planner_node",
     "stopping_rule:=sometimes", "stopping_rule must be one of ['confidence', 'variance']"),
    ("planner max_trials below its range", "tsrrt_planner", "planner_node", "max_trials:=1",
     "Parameter max_trials out of range. Min: 2, Max: 1000, value: 1"),
    ("planner seed below its range", "tsrrt_planner", "planner_node", "seed:=-5",
     "Parameter seed out of range. Min: -1"),
    ("planner scenario with a contradictory objective", "tsrrt_planner", "planner_node",
     f"scenario:={BAD_OBJECTIVE_FILE}",
     "distance_to_point: point must be [x, y] or 'table_center', got [0.4]"),
]


def write_bad_scenarios(folder: Path) -> None:
    """Two variants of the shipped tset3 file, each with one fault."""
    document = yaml.safe_load(resources.files("tsrrt_common").joinpath(
        "scenarios", "tset3.yaml").read_text())
    document["objects"][0]["pose"] = [float("nan"), 0.0, 0.0]
    (folder / NAN_FILE).write_text(yaml.safe_dump(document))
    document = yaml.safe_load(resources.files("tsrrt_common").joinpath(
        "scenarios", "tset3.yaml").read_text())
    document["objective"]["terms"].append({"type": "distance_to_point", "weight": 1.0,
                                           "point": [0.4]})
    (folder / BAD_OBJECTIVE_FILE).write_text(yaml.safe_dump(document))


@pytest.fixture(scope="module")
def refusals(launch, tmp_path_factory) -> dict[str, object]:
    """Every startup case as a process, all started at once."""
    folder = tmp_path_factory.mktemp("bad_scenarios")
    write_bad_scenarios(folder)
    started = {}
    for what, package, node, parameter, _ in STARTUP_CASES:
        for name in (NAN_FILE, BAD_OBJECTIVE_FILE):
            parameter = parameter.replace(f":={name}", f":={folder / name}")
        started[what] = launch.start(package, node, parameter)
    return started


@pytest.mark.parametrize("what, parameter, code, fragment", [
    pytest.param(what, parameter, "exit 1, FATAL log", fragment, id=what)
    for what, _, _, parameter, fragment in STARTUP_CASES])
def test_bad_startup_parameter_is_refused_naming_it(refusals, what, parameter, code, fragment):
    process = refusals[what]
    returncode = process.wait_exit(timeout=120.0)
    log = process.log()
    assert returncode == 1, log
    assert "[FATAL]" in log and "cannot start: " in log, log
    assert fragment in log, log
    assert "Traceback" not in log, log


RUNTIME_CASES = [
    ("perception publish rate above its range", "perception_node", "publish_rate", 1000.0,
     "Parameter publish_rate out of range Min: 1.0, Max: 100.0, value: 1000.0"),
    ("perception minimum area of the wrong type", "perception_node", "min_area_px", 2.5,
     "Wrong parameter type, expected 'Type.INTEGER' got 'Type.DOUBLE'"),
    ("executor push speed above its range", "executor_node", "push_speed", 2.0,
     "Parameter push_speed out of range Min: 0.005, Max: 0.1, value: 2.0"),
    ("executor tool error of the wrong type", "executor_node", "max_tool_error", "big",
     "Wrong parameter type, expected 'Type.DOUBLE' got 'Type.STRING'"),
    ("planner unknown planner", "planner_node", "planner", "astar",
     "planner must be one of ['paper', 'paper-nogd', 'tsrrt', 'greedy'], got 'astar'"),
    ("planner unknown stopping rule", "planner_node", "stopping_rule", "sometimes",
     "stopping_rule must be one of ['confidence', 'variance'], got 'sometimes'"),
    ("planner negative planning budget", "planner_node", "planning_budget_s", -1.0,
     "Parameter planning_budget_s out of range Min: 0.05, Max: 600.0, value: -1.0"),
    ("sim read-only real-time factor", "sim_node", "real_time_factor", 5.0,
     "Trying to set a read-only parameter: real_time_factor"),
    ("sim read-only scenario", "sim_node", "scenario", "tset3",
     "Trying to set a read-only parameter: scenario"),
]


@pytest.fixture(scope="module")
def running(refusals, launch, graph_probe):
    """The four nodes with valid parameters (after the refusals, which use the same names)."""
    for process in refusals.values():
        process.wait_exit(timeout=120.0)
    launch.start("tsrrt_sim", "sim_node", "scenario:=clean", "real_time_factor:=1.0")
    launch.start("tsrrt_perception", "perception_node", "scenario:=clean")
    launch.start("tsrrt_executor", "executor_node")
    launch.start("tsrrt_planner", "planner_node", "scenario:=clean")
    return graph_probe


def parameter_value(probe, node: str, name: str):
    client = probe.create_client(GetParameters, f"/{node}/get_parameters")
    answer = probe.call(client, GetParameters.Request(names=[name]), timeout=60.0,
                        resend_after=10.0)
    return Parameter.from_parameter_msg(ParameterMessage(name=name,
                                                         value=answer.values[0])).value


@pytest.mark.parametrize("what, node, name, value, code, fragment", [
    pytest.param(what, node, name, value, "SetParametersResult successful=false", fragment,
                 id=what)
    for what, node, name, value, fragment in RUNTIME_CASES])
def test_bad_runtime_parameter_is_refused_and_the_old_value_kept(running, what, node, name,
                                                                 value, code, fragment):
    before = parameter_value(running, node, name)
    client = running.create_client(SetParameters, f"/{node}/set_parameters")
    answer = running.call(client, SetParameters.Request(
        parameters=[Parameter(name, value=value).to_parameter_msg()]), timeout=60.0,
        resend_after=10.0)
    assert not answer.results[0].successful
    assert fragment in answer.results[0].reason, answer.results[0].reason
    assert parameter_value(running, node, name) == before


def test_nodes_survive_the_bad_parameters(running, launch):
    nodes = launch.processes[len(STARTUP_CASES):]
    assert [p.name for p in nodes] == ["sim_node", "perception_node", "executor_node",
                                       "planner_node"]
    for process in nodes:
        assert process.running, process.log()
        assert "Traceback" not in process.log(), process.log()
