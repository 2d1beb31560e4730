"""Bad action goals and service requests, sent to the four nodes running together.

sim_node, perception_node, executor_node and planner_node run as processes on the module's own
ROS domain (`clean`, the planner with a copy of the shipped models). Every goal or request below
must come back with its error code (or success=false) and a message naming the offending field
or value. A scenario that fails to load leaves the loaded one in place, and once the world's
objects have vanished (another scenario loaded), goals that refer to them fail naming them. One
test checks that every service and action server in the graph has cases here, so a new one
cannot go unvalidated; the last checks that no node died and none logged a traceback.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
import yaml

pytestmark = pytest.mark.integration

rclpy = pytest.importorskip("rclpy")
from rclpy.action import ActionClient, get_action_names_and_types  # noqa: E402
from trajectory_msgs.msg import JointTrajectoryPoint  # noqa: E402

from tsrrt_common.robot_model import ARM_JOINT_NAMES, READY_POSTURE  # noqa: E402
from tsrrt_interfaces.action import (  # noqa: E402
    ExecutePrimitive,
    FollowJointTrajectory,
    LearnModels,
    PlanTask,
    RunTask,
)
from tsrrt_interfaces.msg import ObjectStateArray  # noqa: E402
from tsrrt_interfaces.srv import DisturbObject, GetSettledObjects, LoadScenario  # noqa: E402

CATEGORY = "action goals and service requests"
CLEAN_IDS = ["scale", "remote", "eraser"]

ACTIONS = {"/executor/execute_primitive": ExecutePrimitive,
           "/planner/learn_models": LearnModels, "/planner/plan_task": PlanTask,
           "/planner/run_task": RunTask,
           "/arm_controller/follow_joint_trajectory": FollowJointTrajectory}
SERVICES = {"/sim/load_scenario": LoadScenario, "/sim/disturb_object": DisturbObject,
            "/perception/get_settled_objects": GetSettledObjects}
SUCCESS_FALSE = "success=false"


def push(object_id: str, primitive: int, push_length: float = 0.0) -> ExecutePrimitive.Goal:
    return ExecutePrimitive.Goal(object_id=object_id, primitive=primitive,
                                 push_length=push_length)


def trajectory(names: list[str], seconds: list[int]) -> FollowJointTrajectory.Goal:
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = names
    for t in seconds:
        point = JointTrajectoryPoint(positions=list(READY_POSTURE))
        point.time_from_start.sec = t
        goal.trajectory.points.append(point)
    return goal


def scenario_file(name: str) -> Callable[[Path], str]:
    """A request field: the path of a bad scenario file the graph fixture wrote."""
    return lambda folder: str(folder / name)


# (what, server, request (or a function of the bad-file folder), code, fragment)
CASES: list[tuple[str, str, Any, str, str]] = [
    ("unknown object", "/executor/execute_primitive", push("stapler", 1), "UNKNOWN_OBJECT",
     "no object 'stapler' in /perception/objects; known: ['eraser', 'remote', 'scale']"),
    ("empty object id", "/executor/execute_primitive", push("", 1), "UNKNOWN_OBJECT",
     "the goal names no object (empty object_id)"),
    ("primitive 0", "/executor/execute_primitive", push("scale", 0), "INVALID_GOAL",
     "primitive 0 is not one of [1, 2, 3, 4, 5, 6] for a box"),
    ("primitive 7", "/executor/execute_primitive", push("scale", 7), "INVALID_GOAL",
     "primitive 7 is not one of [1, 2, 3, 4, 5, 6] for a box"),
    ("primitive 255", "/executor/execute_primitive", push("remote", 255), "INVALID_GOAL",
     "primitive 255 is not one of [1, 2, 3, 4, 5, 6] for a box"),
    ("negative push length", "/executor/execute_primitive", push("scale", 1, -0.01),
     "INVALID_GOAL", "push length -0.01 m must be in (0, 0.15] m"),
    ("huge push length", "/executor/execute_primitive", push("scale", 2, 5.0), "INVALID_GOAL",
     "push length 5.0 m must be in (0, 0.15] m"),
    ("NaN push length", "/executor/execute_primitive", push("scale", 3, math.nan),
     "INVALID_GOAL", "push length nan m must be in (0, 0.15] m"),
    ("infinite push length", "/executor/execute_primitive", push("eraser", 4, math.inf),
     "INVALID_GOAL", "push length inf m must be in (0, 0.15] m"),
    ("learning an unknown object", "/planner/learn_models",
     LearnModels.Goal(object_ids=["scale", "stapler"]), "UNKNOWN_OBJECT",
     "unknown objects ['stapler']; known: ['scale', 'remote', 'eraser']"),
    ("unknown stopping rule", "/planner/learn_models",
     LearnModels.Goal(stopping_rule="sometimes"), "INVALID_GOAL",
     "unknown stopping rule 'sometimes'; known: 'confidence', 'variance'"),
    ("one trial per primitive", "/planner/learn_models",
     LearnModels.Goal(max_trials_per_primitive=1), "INVALID_GOAL",
     "max_trials_per_primitive must be 0 (the max_trials parameter) or within [2, 1000], "
     "got 1"),
    ("a million trials per primitive", "/planner/learn_models",
     LearnModels.Goal(max_trials_per_primitive=10**6), "INVALID_GOAL",
     "max_trials_per_primitive must be 0 (the max_trials parameter) or within [2, 1000], "
     "got 1000000"),
    ("unknown planner", "/planner/plan_task", PlanTask.Goal(planner="astar"), "INVALID_GOAL",
     "unknown planner 'astar'; known: ['paper', 'paper-nogd', 'tsrrt', 'greedy']"),
    ("NaN planning budget", "/planner/plan_task", PlanTask.Goal(budget_s=math.nan),
     "INVALID_GOAL", "budget_s must be 0 (the planning_budget_s parameter) or within "
     "[0.05, 600], got nan"),
    ("negative planning budget", "/planner/plan_task", PlanTask.Goal(budget_s=-1.0),
     "INVALID_GOAL", "budget_s must be 0 (the planning_budget_s parameter) or within "
     "[0.05, 600], got -1.0"),
    ("week-long planning budget", "/planner/plan_task", PlanTask.Goal(budget_s=604800.0),
     "INVALID_GOAL", "budget_s must be 0 (the planning_budget_s parameter) or within "
     "[0.05, 600], got 604800.0"),
    ("negative task time budget", "/planner/run_task", RunTask.Goal(time_budget_s=-5.0),
     "INVALID_GOAL", "time_budget_s must be 0 (the time_budget_s parameter) or within "
     "[1, 86400], got -5.0"),
    ("ten million pushes", "/planner/run_task", RunTask.Goal(max_pushes=10**7), "INVALID_GOAL",
     "max_pushes must be 0 (the max_pushes parameter) or within [1, 10000], got 10000000"),
    ("infinite replanning budget", "/planner/run_task",
     RunTask.Goal(planning_budget_s=math.inf), "INVALID_GOAL",
     "budget_s must be 0 (the planning_budget_s parameter) or within [0.05, 600], got inf"),
    ("unknown planner for a task", "/planner/run_task", RunTask.Goal(planner="dijkstra"),
     "INVALID_GOAL", "unknown planner 'dijkstra'"),
    ("trajectory without points", "/arm_controller/follow_joint_trajectory",
     trajectory(list(ARM_JOINT_NAMES), []), "INVALID_GOAL", "the trajectory has no points"),
    ("trajectory for an unknown joint", "/arm_controller/follow_joint_trajectory",
     trajectory([*ARM_JOINT_NAMES[:6], "wrist"], [1]), "INVALID_JOINTS",
     "unknown joints ['wrist']"),
    ("trajectory point at a negative time", "/arm_controller/follow_joint_trajectory",
     trajectory(list(ARM_JOINT_NAMES), [-1]), "INVALID_GOAL",
     "time_from_start must be finite and >= 0, got [-1.0]"),
    ("moving an unknown object", "/sim/disturb_object",
     DisturbObject.Request(object_id="stapler", dx=0.01), SUCCESS_FALSE,
     "unknown object 'stapler'; known: ['eraser', 'remote', 'scale']"),
    ("NaN disturbance", "/sim/disturb_object",
     DisturbObject.Request(object_id="scale", dx=math.nan), SUCCESS_FALSE,
     "disturbance must be finite, got (nan, 0.0, 0.0)"),
    ("disturbance off the table", "/sim/disturb_object",
     DisturbObject.Request(object_id="remote", dy=1.0), SUCCESS_FALSE,
     "would put it partly off the table"),
    ("zero settle timeout", "/perception/get_settled_objects",
     GetSettledObjects.Request(timeout_s=0.0), SUCCESS_FALSE,
     "timeout_s must be in (0, 600] and max_speed >= 0; got 0.0, 0.0"),
    ("hour-long settle timeout", "/perception/get_settled_objects",
     GetSettledObjects.Request(timeout_s=3600.0), SUCCESS_FALSE,
     "timeout_s must be in (0, 600] and max_speed >= 0; got 3600.0, 0.0"),
    ("negative settle speed", "/perception/get_settled_objects",
     GetSettledObjects.Request(timeout_s=1.0, max_speed=-1.0), SUCCESS_FALSE,
     "timeout_s must be in (0, 600] and max_speed >= 0; got 1.0, -1.0"),
    ("unknown scenario name", "/sim/load_scenario",
     LoadScenario.Request(scenario="no_such_world", seed=-1), SUCCESS_FALSE,
     "no_such_world: (file): no such file and not a shipped scenario"),
    ("scenario file with NaN in a pose", "/sim/load_scenario", scenario_file("nan.yaml"),
     SUCCESS_FALSE, "objects[0].pose[0]: must be finite, got nan"),
    ("scenario file with overlapping objects", "/sim/load_scenario",
     scenario_file("overlap.yaml"), SUCCESS_FALSE, "objects[1].pose: plate_2 overlaps plate_1"),
    ("binary scenario file", "/sim/load_scenario", scenario_file("binary.yaml"), SUCCESS_FALSE,
     "(file): not UTF-8 text"),
]


def write_bad_scenarios(folder: Path) -> None:
    """Variants of the shipped tset3 file (explicit poses), each with one fault."""
    text = resources.files("tsrrt_common").joinpath("scenarios", "tset3.yaml").read_text()
    document = yaml.safe_load(text)
    assert [o["id"] for o in document["objects"]][:2] == ["plate_1", "plate_2"]
    nan = yaml.safe_load(text)
    nan["objects"][0]["pose"] = [math.nan, 0.0, 0.0]
    (folder / "nan.yaml").write_text(yaml.safe_dump(nan))
    overlap = yaml.safe_load(text)
    overlap["objects"][0]["pose"] = [0.45, 0.0, 0.0]
    overlap["objects"][1]["pose"] = [0.47, 0.0, 0.0]
    (folder / "overlap.yaml").write_text(yaml.safe_dump(overlap))
    (folder / "binary.yaml").write_bytes(b"\x80\xff\x00\x13garbage")


class Graph:
    """The probe's clients of every server, and the simulator's ground truth."""

    def __init__(self, probe, processes, folder: Path) -> None:
        self.probe = probe
        self.processes = processes
        self.folder = folder
        self.actions = {name: ActionClient(probe, action, name)
                        for name, action in ACTIONS.items()}
        self.services = {name: probe.create_client(service, name)
                         for name, service in SERVICES.items()}
        self.truth = probe.record(ObjectStateArray, "/sim/object_states")

    def send(self, server: str, request: Any) -> tuple[Any, str, str]:
        """(response or result, its code's name, its message)."""
        if callable(request):
            request = LoadScenario.Request(scenario=request(self.folder), seed=-1)
        if server in self.services:
            response = self.probe.call(self.services[server], request, timeout=60.0)
            return response, "success" if response.success else SUCCESS_FALSE, response.message
        result = self.probe.execute(self.actions[server], request, timeout=120.0).result
        names = {getattr(type(result), n): n for n in dir(type(result))
                 if n.isupper() and isinstance(getattr(type(result), n), int)}
        message = getattr(result, "error_msg", None) or getattr(result, "error_string", "")
        return result, names.get(result.error_code, str(result.error_code)), message

    def truth_ids(self) -> list[str]:
        self.truth.clear()
        assert self.probe.spin_until(lambda: len(self.truth) >= 2, 30.0), "no ground truth"
        return [o.id for o in self.truth[-1].objects]


@pytest.fixture(scope="module")
def graph(launch, graph_probe, tmp_path_factory) -> Graph:
    folder = tmp_path_factory.mktemp("bad_goals")
    write_bad_scenarios(folder)
    models = folder / "models" / "clean.yaml"
    models.parent.mkdir()
    shutil.copy(resources.files("tsrrt_planner").joinpath("data", "models", "clean.yaml"),
                models)
    processes = [
        launch.start("tsrrt_sim", "sim_node", "scenario:=clean", "real_time_factor:=5.0"),
        launch.start("tsrrt_perception", "perception_node", "scenario:=clean",
                     "lost_timeout:=1.0"),
        launch.start("tsrrt_executor", "executor_node", "settle_timeout:=4.0"),
        launch.start("tsrrt_planner", "planner_node", "scenario:=clean",
                     f"models_path:={models}", "observe_timeout_s:=5.0")]
    graph = Graph(graph_probe, processes, folder)
    for name, client in graph.actions.items():
        assert client.wait_for_server(timeout_sec=90.0), f"no {name}"
    for name, client in graph.services.items():
        assert client.wait_for_service(timeout_sec=90.0), f"no {name}"
    return graph


@pytest.mark.parametrize("what, server, request_, code, fragment", [
    pytest.param(what, server, request, code, fragment, id=what)
    for what, server, request, code, fragment in CASES])
def test_bad_request_gets_its_code_and_names_the_problem(graph, what, server, request_, code,
                                                         fragment):
    _, answered, message = graph.send(server, request_)
    assert answered == code, message
    assert fragment in message, message


def test_failed_loads_leave_the_loaded_scenario_in_place(graph):
    for _, server, request, _, _ in CASES:
        if server == "/sim/load_scenario":
            graph.send(server, request)
    assert sorted(graph.truth_ids()) == sorted(CLEAN_IDS)
    assert all(process.running for process in graph.processes)


def test_every_server_in_the_graph_has_bad_request_cases(graph):
    covered = {server for _, server, _, _, _ in CASES}
    parameter_services = ("/describe_parameters", "/get_parameter_types", "/get_parameters",
                          "/list_parameters", "/set_parameters", "/set_parameters_atomically",
                          "/get_type_description")
    services = {name for name, _ in graph.probe.get_service_names_and_types()
                if "/_action/" not in name and not name.endswith(parameter_services)}
    actions = {name for name, _ in get_action_names_and_types(graph.probe)}
    assert services | actions == covered


@pytest.fixture(scope="module")
def vanished(graph) -> Graph:
    """The world after loading tset3: clean's objects are gone from the table."""
    response, code, message = graph.send("/sim/load_scenario",
                                         LoadScenario.Request(scenario="tset3", seed=-1))
    assert code == "success", message
    assert "scale" not in graph.truth_ids()
    return graph


VANISHED_CASES = [
    ("pushing an object that has vanished", "/executor/execute_primitive", push("scale", 1),
     "OBJECT_LOST", "'scale' is lost or missing in the settled observation"),
    ("planning for objects that have vanished", "/planner/plan_task", PlanTask.Goal(),
     "NO_OBSERVATION", "perception does not see ['scale', 'remote', 'eraser']"),
]


@pytest.mark.parametrize("what, server, request_, code, fragment", [
    pytest.param(*case, id=case[0]) for case in VANISHED_CASES])
def test_goal_on_a_vanished_object_names_it(vanished, what, server, request_, code, fragment):
    _, answered, message = vanished.send(server, request_)
    assert answered == code, message
    assert fragment in message, message


def test_no_node_died_or_logged_a_traceback(graph):
    for process in graph.processes:
        assert process.running, process.log()
        assert "Traceback" not in process.log(), process.log()
