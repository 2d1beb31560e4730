"""`scripts/graph.py` against a live node: every subcommand run as a user would, as a process.

`graph_tool_node.py` runs on the module's own ROS domain (`ros_env` in conftest.py: random,
localhost discovery only) and is killed at teardown.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from tsrrt_common.processes import stop_process_group

pytestmark = pytest.mark.integration

pytest.importorskip("rclpy")
pytest.importorskip("tsrrt_interfaces.action")

ROOT = Path(__file__).resolve().parents[2]
GRAPH = ROOT / "scripts/graph.py"
TEST_NODE = Path(__file__).with_name("graph_tool_node.py")
CHATTER_RATE_HZ = 20.0
LISTINGS = ("nodes", "topics", "services", "actions")


def graph(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    """Run graph.py. Listings discover for 4 s (one small node); lookups of a name that exists
    may take up to 20 s to succeed on a loaded machine."""
    wait = () if "--wait" in args else ("--wait", "4" if args[0] in LISTINGS else "20")
    return subprocess.run([sys.executable, str(GRAPH), *args, *wait], env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def test_node(ros_env, tmp_path_factory) -> Iterator[subprocess.Popen]:
    log = tmp_path_factory.mktemp("graph_tool") / "graph_tool_node.log"
    with log.open("w") as output:
        process = subprocess.Popen(
            [sys.executable, str(TEST_NODE), "--ros-args", "-p", f"rate_hz:={CHATTER_RATE_HZ}"],
            env=ros_env, start_new_session=True, stdout=output, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60.0
        while "/graph_test/chatter" not in graph(ros_env, "topics", "--wait", "5").stdout:
            assert process.poll() is None, log.read_text()
            assert time.monotonic() < deadline, "the test node never appeared in the graph"
        yield process
    finally:
        stop_process_group(process, grace_s=10.0)


@pytest.fixture
def env(ros_env, test_node) -> dict[str, str]:
    return ros_env


def ok(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 0, result.stderr
    return result.stdout


def failed(result: subprocess.CompletedProcess) -> str:
    """stderr of a run that must have failed cleanly: exit 1, one message, no traceback."""
    assert result.returncode == 1, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr
    return result.stderr


def echoed(stdout: str) -> list:
    """The YAML documents `echo` printed (separated by '---')."""
    return [yaml.safe_load(doc) for doc in stdout.split("---\n") if doc.strip()]


# ---------------------------------------------------------------------------------- listings
def test_nodes_lists_the_endpoints_of_each_node(env):
    out = ok(graph(env, "nodes"))
    assert "/graph_tool_test" in out, out
    section = out[out.index("/graph_tool_test"):]
    assert re.search(r"Publishers:\n(    .*\n)*    /graph_test/chatter +std_msgs/msg/String",
                     section)
    assert re.search(r"Service Servers:\n(    .*\n)*    /graph_test/set_flag +"
                     r"std_srvs/srv/SetBool", section)
    assert re.search(r"Action Servers:\n    /graph_test/move +"
                     r"tsrrt_interfaces/action/FollowJointTrajectory", section)
    assert "/_action/" not in out                   # hidden topics are shown as the action
    assert "_graph_tool_" not in out                # the tool does not list itself
    assert ok(graph(env, "nodes", "--brief")).split() == ["/graph_tool_test"]


def test_nodes_names_a_missing_node(env):
    assert "no node /nobody; nodes: /graph_tool_test" in failed(graph(env, "nodes", "/nobody"))


def test_topics_with_types_and_verbose_qos(env):
    rows = dict(line.split() for line in ok(graph(env, "topics")).splitlines())
    assert rows["/graph_test/chatter"] == "std_msgs/msg/String"
    assert rows["/graph_test/blob"] == "std_msgs/msg/UInt8MultiArray"
    verbose = ok(graph(env, "topics", "-v"))
    blob = verbose[verbose.index("/graph_test/blob"):]
    assert blob.splitlines()[1:4] == ["  publishers: 1",
                                      "    /graph_tool_test  (best_effort, volatile)",
                                      "  subscribers: 0"]


def test_services_hide_action_internals_unless_asked(env):
    rows = dict(line.split() for line in ok(graph(env, "services")).splitlines())
    assert rows["/graph_test/set_flag"] == "std_srvs/srv/SetBool"
    assert rows["/graph_tool_test/get_parameters"] == "rcl_interfaces/srv/GetParameters"
    assert not any("/_action/" in name for name in rows)
    hidden = ok(graph(env, "services", "--include-hidden"))
    assert "/graph_test/move/_action/send_goal" in hidden


def test_actions_are_derived_from_their_hidden_endpoints(env):
    assert ok(graph(env, "actions")).split() == ["/graph_test/move",
                                                 "tsrrt_interfaces/action/FollowJointTrajectory"]
    verbose = ok(graph(env, "actions", "-v")).splitlines()
    assert verbose[1:4] == ["  servers: 1", "    /graph_tool_test", "  clients: 0"]


# ---------------------------------------------------------------------------------- echo, hz
def test_echo_once_prints_one_message_as_yaml(env):
    (message,) = echoed(ok(graph(env, "echo", "/graph_test/chatter", "--once")))
    assert re.fullmatch(r"hello \d+", message["data"])


def test_echo_count_and_field(env):
    values = echoed(ok(graph(env, "echo", "graph_test/chatter", "--count", "3",
                             "--field", "data")))
    numbers = [int(v.split()[1]) for v in values]
    assert len(numbers) == 3 and numbers == sorted(numbers) and len(set(numbers)) == 3


def test_echo_truncates_big_arrays(env):
    (message,) = echoed(ok(graph(env, "echo", "/graph_test/blob", "--once", "--truncate", "4")))
    assert message["data"] == [0, 1, 2, 3, "... 996 more"]
    (full,) = echoed(ok(graph(env, "echo", "/graph_test/blob", "--once", "--truncate", "0",
                              "--field", "data")))
    assert full == [i % 256 for i in range(1000)]


@pytest.mark.parametrize("args, message", [
    (["/graph_test/nothing", "--wait", "1"], "topic '/graph_test/nothing' not found after 1 s"),
    (["/graph_test/chatter", "--type", "std_msgs/msg/Strin"],
     "std_msgs/msg has no type 'Strin'"),
    (["/graph_test/chatter", "--type", "no_such_pkg/msg/X"], "cannot import 'no_such_pkg.msg'"),
    (["/graph_test/chatter", "--field", "dat"], "String has no field 'dat'; fields: data"),
    (["/graph_test/silent", "--type", "std_msgs/msg/String", "--timeout", "1"],
     "0 of 1 message(s) on '/graph_test/silent' within 1 s"),
])
def test_echo_failures_are_clean(env, args, message):
    assert message in failed(graph(env, "echo", *args))


def test_hz_measures_the_publishing_rate(env):
    out = ok(graph(env, "hz", "/graph_test/chatter", "--duration", "3", "--window", "40"))
    rates = [float(r) for r in re.findall(r"average rate: ([\d.]+) Hz", out)]
    assert rates, out
    assert rates[-1] == pytest.approx(CHATTER_RATE_HZ, rel=0.3)
    last = re.findall(r"min: ([\d.]+)s max: ([\d.]+)s std dev: ([\d.]+)s window: (\d+)", out)[-1]
    shortest, longest = float(last[0]), float(last[1])
    assert shortest <= 1.0 / rates[-1] <= longest
    assert 2 <= int(last[3]) <= 40


def test_hz_fails_without_messages(env):
    error = failed(graph(env, "hz", "/graph_test/silent", "--type", "std_msgs/msg/String",
                         "--duration", "1"))
    assert "0 message(s) on '/graph_test/silent' in 1 s" in error


# ---------------------------------------------------------------------------------- call, param
def test_call_sends_the_yaml_request_and_prints_the_response(env):
    out = ok(graph(env, "call", "/graph_test/set_flag", "std_srvs/srv/SetBool", "{data: true}"))
    assert yaml.safe_load(out) == {"request": {"data": True},
                                   "response": {"success": True, "message": "flag is now True"}}


@pytest.mark.parametrize("args, message", [
    (["std_srvs/srv/SetBool", "{flag: true}"], "no field 'flag'; fields: data"),
    (["std_srvs/srv/SetBool", "{data: 3}"], "data: cannot set 3"),
    (["std_srvs/srv/SetBool", "{data: "], "request is not valid YAML"),
    (["std_srvs/srv/Trigger"], "has type std_srvs/srv/SetBool, not std_srvs/srv/Trigger"),
    (["std_msgs/msg/String"], "is not a service type"),
])
def test_call_failures_are_clean(env, args, message):
    assert message in failed(graph(env, "call", "/graph_test/set_flag", *args))


def test_call_of_a_missing_service_times_out(env):
    error = failed(graph(env, "call", "/graph_test/nothing", "std_srvs/srv/Trigger",
                         "--timeout", "1"))
    assert "service '/graph_test/nothing' not found after 1 s" in error


def test_param_list_get_and_dump(env):
    names = ok(graph(env, "param", "list", "graph_tool_test")).split()
    assert {"greeting", "rate_hz", "use_sim_time"} <= set(names)
    assert ok(graph(env, "param", "get", "/graph_tool_test", "rate_hz")).strip() == "20.0"
    dump = yaml.safe_load(ok(graph(env, "param", "dump", "/graph_tool_test")))
    assert dump["graph_tool_test"]["ros__parameters"]["greeting"] == "hello"
    error = failed(graph(env, "param", "get", "/graph_tool_test", "nope"))
    assert "has no parameter nope; it has: greeting, rate_hz" in error


@pytest.mark.parametrize("command", [["echo", "/graph_test/chatter"],
                                     ["hz", "/graph_test/chatter"]])
def test_ctrl_c_ends_a_streaming_command_cleanly(env, command):
    # As from a terminal: a test run started in the background (`cmd &` in a script) passes on
    # SIGINT ignored, and Python then never turns Ctrl-C into KeyboardInterrupt.
    process = subprocess.Popen([sys.executable, str(GRAPH), *command, "--wait", "20"], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        first_line = process.stdout.readline()          # blocks until the command prints
        assert first_line, process.stderr.read()
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, stderr
    assert "Traceback" not in stderr
