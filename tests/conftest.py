"""Shared machinery of the graph tests (integration/, reliability/): nodes as processes on a
private ROS domain, and a probe node that records topics and calls services and actions.

Each test module, and each isolated node a test asks for, gets a random ROS domain never used
before in the session and not held by another test session on the machine (a lock file per
domain; localhost discovery only), so concurrent runs and stray nodes do not interfere. Every
process started through `launch` is stopped at the module's teardown (SIGINT to its process
group, SIGKILL if it does not exit), and its output goes to a log file that a failing test can
show.
"""

from __future__ import annotations

import fcntl
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tsrrt_common.processes import stop_process_group

try:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from tsrrt_interfaces.action import (
        ExecutePrimitive,
        FollowJointTrajectory,
        LearnModels,
        PlanTask,
        RunTask,
    )
except ImportError:     # without ROS the tests that need none still run; graph tests skip
    rclpy = None
    Node = object

HANDSHAKE = "handshake"     # names no planner and no object: a goal with it fails at once

PACKAGES_DIR = Path(__file__).resolve().parents[1] / "ros2_ws" / "src"


DOMAIN_IDS = range(1, 102)      # valid UDP ports on Linux
_handed_out_domains = {os.environ.get("ROS_DOMAIN_ID", "")}
_domain_locks: list = []        # open lock files: the domains this session holds until it exits


def free_domain_id() -> str:
    """A random ROS domain id never handed out before in this test session (nor the caller's)
    and held by no other test session on the machine. Unique per session, not per module: a CI
    run once drew the same id for two modules in a row and the graph tool's test listed the
    executor test's nodes. Locked across sessions: two runs side by side drew the same id, and
    one's RunTask went to the other's busy planner ("RunTask rejected")."""
    free = [str(domain) for domain in DOMAIN_IDS if str(domain) not in _handed_out_domains]
    random.shuffle(free)
    for domain in free:
        _handed_out_domains.add(domain)
        lock = open(Path(tempfile.gettempdir()) / f"tsrrt_ros_domain_{domain}.lock", "w")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:     # another session's
            lock.close()
            continue
        _domain_locks.append(lock)
        return domain
    raise RuntimeError(f"all {len(DOMAIN_IDS)} ROS domain ids are used in this session or "
                       "held by other test sessions")


class NodeProcess:
    """A node run as `python -m <package>.<node> --ros-args ...`, output in a log file."""

    def __init__(self, name: str, popen: subprocess.Popen, log_path: Path) -> None:
        self.name = name
        self.popen = popen
        self.log_path = log_path

    @property
    def running(self) -> bool:
        return self.popen.poll() is None

    def stop(self, sig: int = signal.SIGINT) -> int:
        """Signal the process group, wait, escalate to SIGKILL; returns the exit code."""
        return stop_process_group(self.popen, sig)

    def stop_cleanly(self, sig: int = signal.SIGINT) -> None:
        """stop() and assert exit code 0, showing the log's end otherwise: a node that hangs
        on the signal prints every thread's stack there (run_node), which says where."""
        code = self.stop(sig)
        assert code == 0, f"{self.name} exited with {code}; its log ends:\n{self.log()[-6000:]}"

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_for_log(self, text: str, timeout: float = 30.0, after: int = 0) -> bool:
        """Wait until `text` appears in the log past character `after` (e.g. len(log()))."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.log()[after:]:
                return True
            time.sleep(0.1)
        return False

    def wait_exit(self, timeout: float = 60.0) -> int | None:
        """The exit code once the process ends by itself, or None if it still runs."""
        try:
            return self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None


class Launcher:
    """Starts nodes with their package's parameter file; stops them all at the end."""

    def __init__(self, env: dict[str, str], log_dir: Path) -> None:
        self.env = env
        self.log_dir = log_dir
        self.processes: list[NodeProcess] = []

    def start(self, package: str, node: str, *parameters: str, params_file: bool = True,
              env: dict[str, str] | None = None) -> NodeProcess:
        """Start `package.node` with config/<node>.yaml (if params_file) and `-p` parameters."""
        args = [sys.executable, "-m", f"{package}.{node}", "--ros-args"]
        if params_file:
            args += ["--params-file", str(PACKAGES_DIR / package / "config" / f"{node}.yaml")]
        for parameter in parameters:
            args += ["-p", parameter]
        log_path = self.log_dir / f"{node}_{len(self.processes)}.log"
        with log_path.open("w") as log:
            popen = subprocess.Popen(args, env=env or self.env, start_new_session=True,
                                     stdout=log, stderr=subprocess.STDOUT, text=True)
        process = NodeProcess(node, popen, log_path)
        self.processes.append(process)
        return process

    def other_domain_env(self) -> dict[str, str]:
        """The environment with a domain id of its own (three isolated planners once drew the
        same id and answered each other's goals)."""
        return dict(self.env, ROS_DOMAIN_ID=free_domain_id())

    def stop_all(self) -> None:
        for process in reversed(self.processes):
            process.stop()


def failing_goal(goal_type: type) -> Any:
    """A goal of the type that its server fails or refuses at once, for a handshake."""
    failing = {RunTask.Goal: lambda: RunTask.Goal(planner=HANDSHAKE),
               PlanTask.Goal: lambda: PlanTask.Goal(planner=HANDSHAKE),
               LearnModels.Goal: lambda: LearnModels.Goal(object_ids=[HANDSHAKE]),
               ExecutePrimitive.Goal: ExecutePrimitive.Goal,   # no object: answered at once
               FollowJointTrajectory.Goal: FollowJointTrajectory.Goal}   # no joints: refused
    return failing[goal_type]()


class Probe(Node):
    """The tests' window on the graph: records topics, calls services, sends action goals."""

    def __init__(self, context, name: str = "integration_probe") -> None:
        super().__init__(name, context=context)
        self.spinner = SingleThreadedExecutor(context=context)
        self.spinner.add_node(self)
        # Action clients whose server has answered a goal in full; a restarted server needs
        # a `handshake` of its own.
        self.answered: set = set()

    def record(self, message_type, topic: str, qos: Any = 10,
               transform: Callable[[Any], Any] | None = None) -> list:
        """Subscribe to `topic`; returns the list every message (or transform(message)) is
        appended to."""
        received: list = []
        self.create_subscription(
            message_type, topic,
            received.append if transform is None else lambda m: received.append(transform(m)),
            qos)
        return received

    def next_message(self, message_type, topic: str, qos: Any = 10, timeout: float = 30.0):
        """The next message on `topic` (subscribed only while waiting, for fast topics)."""
        received: list = []
        subscription = self.create_subscription(message_type, topic, received.append, qos)
        try:
            assert self.spin_until(lambda: bool(received), timeout), f"nothing on {topic}"
        finally:
            self.destroy_subscription(subscription)
        return received[0]

    def spin_until(self, condition: Callable[[], bool], timeout: float = 30.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.spinner.spin_once(timeout_sec=0.05)
            if condition():
                return True
        return False

    def wait_for(self, future, timeout: float = 30.0):
        assert self.spin_until(future.done, timeout), f"no answer within {timeout} s"
        return future.result()

    def call(self, client, request, timeout: float = 30.0, resend_after: float | None = None):
        """The service's response to `request`. A query that is safe to repeat may pass
        `resend_after`: the request is then sent again each time no answer came in that long,
        because rmw_fastrtps drops a response sent before the server has matched a new client's
        reader, and the client then waits forever (a fresh-clone CI run: GetParameters on a
        client made just before, no answer in 60 s)."""
        assert client.wait_for_service(timeout_sec=30.0), f"{client.srv_name} not available"
        if resend_after is None:
            return self.wait_for(client.call_async(request), timeout)
        deadline = time.monotonic() + timeout
        futures = []
        while time.monotonic() < deadline:
            futures.append(client.call_async(request))
            wait = min(resend_after, deadline - time.monotonic())
            if self.spin_until(lambda: any(f.done() for f in futures), wait):
                return next(f for f in futures if f.done()).result()
        raise AssertionError(f"no answer within {timeout} s from {client.srv_name} "
                             f"to {len(futures)} requests")

    def send_goal(self, action_client, goal, feedback: list | None = None):
        """Send an action goal; feedback messages (if a list is given) are appended to it. The
        first goal to a server goes after a `handshake`: a fresh-clone CI run lost the answer
        to a lone executor's first goal."""
        if action_client not in self.answered:
            self.handshake(action_client, type(goal))
        assert action_client.wait_for_server(timeout_sec=30.0), "action server not available"
        callback = feedback.append if feedback is not None else None
        return self.wait_for(action_client.send_goal_async(goal, feedback_callback=callback))

    def handshake(self, action_client, goal_type: type, timeout: float = 60.0,
                  resend_after: float = 2.0) -> None:
        """Send a goal of the type that the server refuses or fails at once (`failing_goal`)
        until it is answered in full.
        wait_for_server only sees the server in the graph: rmw_fastrtps drops the goal
        response of a server that has not yet matched this client's reader (a fresh-clone CI
        run: RunTask to a restarted planner, no answer in 30 s), and a real goal cannot simply
        be sent again, since the lost one may be running."""
        assert action_client.wait_for_server(timeout_sec=timeout), "action server not available"
        deadline = time.monotonic() + timeout
        sent = []
        while time.monotonic() < deadline:
            sent.append(action_client.send_goal_async(failing_goal(goal_type)))
            if not self.spin_until(lambda: any(f.done() for f in sent), resend_after):
                continue
            handle = next(f for f in sent if f.done()).result()
            if not handle.accepted or self.spin_until(handle.get_result_async().done,
                                                      resend_after):
                self.answered.add(action_client)
                return
        raise AssertionError(f"{action_client._action_name}: {len(sent)} goals, no answer "
                             f"within {timeout} s")

    def execute(self, action_client, goal, feedback: list | None = None,
                timeout: float = 60.0):
        """Send a goal that must be accepted and wait for its result (the wrapper with status)."""
        handle = self.send_goal(action_client, goal, feedback)
        assert handle.accepted, "goal rejected"
        return self.wait_for(handle.get_result_async(), timeout)

    def close(self) -> None:
        self.spinner.shutdown()
        self.destroy_node()


@pytest.fixture(scope="module")
def ros_env() -> Iterator[dict[str, str]]:
    """The environment of this module's nodes and probe: its own domain, localhost only."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("ROS_DOMAIN_ID", free_domain_id())
        patch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        yield dict(os.environ)


@pytest.fixture(scope="module")
def launch(ros_env, tmp_path_factory) -> Iterator[Launcher]:
    launcher = Launcher(ros_env, tmp_path_factory.mktemp("node_logs"))
    yield launcher
    launcher.stop_all()


@pytest.fixture(scope="module")
def probe_on_domain() -> Iterator[Callable[[int], Probe]]:
    """Makes probes on a given ROS domain (each in an rclpy context of its own); all are shut
    down at the module's teardown."""
    if rclpy is None:
        pytest.skip("rclpy is not available")
    made: list[tuple[Any, Probe]] = []

    def make(domain_id: int) -> Probe:
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain_id)
        node = Probe(context)
        made.append((context, node))
        return node

    yield make
    for context, node in reversed(made):
        node.close()
        rclpy.shutdown(context=context)


@pytest.fixture(scope="module")
def graph_probe(ros_env, probe_on_domain) -> Probe:
    """A probe on this module's domain."""
    return probe_on_domain(int(ros_env["ROS_DOMAIN_ID"]))
