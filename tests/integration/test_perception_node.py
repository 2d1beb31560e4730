"""Perception node against the simulator: published poses match /sim/object_states.

Starts `tsrrt_sim.sim_node` and `tsrrt_perception.perception_node` as processes on their own
ROS domain (localhost only), listens with rclpy, and kills both processes at teardown.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

DOMAIN_ID = "61"
os.environ["ROS_DOMAIN_ID"] = DOMAIN_ID            # before rclpy.init, for this process too
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

rclpy = pytest.importorskip("rclpy")
interfaces = pytest.importorskip("tsrrt_interfaces.msg")
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from tsrrt_common.geometry import angle_difference_modulo_symmetry  # noqa: E402
from tsrrt_interfaces.msg import ObjectState, ObjectStateArray  # noqa: E402
from tsrrt_interfaces.srv import DisturbObject, GetSettledObjects  # noqa: E402

SCENARIO = "tset6"
PARAMS_FILE = (Path(__file__).resolve().parents[2]
               / "ros2_ws/src/tsrrt_perception/config/perception_node.yaml")
POSITION_TOLERANCE = 0.002     # m: the benchmark's max target
ANGLE_TOLERANCE_DEG = 1.5


def _start(module: str, *ros_args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, "--ros-args", *ros_args],
                            env=dict(os.environ), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGINT)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=10)


class Listener(Node):
    def __init__(self) -> None:
        super().__init__("perception_integration_listener")
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.perceived: list[tuple[float, ObjectStateArray]] = []
        self.truth: ObjectStateArray | None = None
        self.create_subscription(ObjectStateArray, "/perception/objects",
                                 lambda m: self.perceived.append((time.monotonic(), m)), reliable)
        self.create_subscription(ObjectStateArray, "/sim/object_states",
                                 lambda m: setattr(self, "truth", m), reliable)
        self.settled_client = self.create_client(GetSettledObjects,
                                                 "/perception/get_settled_objects")
        self.disturb_client = self.create_client(DisturbObject, "/sim/disturb_object")

    def spin_until(self, condition, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            rclpy.spin_once(self, timeout_sec=0.1)
            if condition():
                return True
        return False

    def call(self, client, request, timeout: float):
        assert client.wait_for_service(timeout_sec=20.0), f"{client.srv_name} not available"
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"{client.srv_name} did not answer"
        return future.result()


@pytest.fixture(scope="module")
def listener():
    sim = _start("tsrrt_sim.sim_node", "-p", f"scenario:={SCENARIO}", "-p",
                 "real_time_factor:=1.0")
    perception = _start("tsrrt_perception.perception_node", "--params-file", str(PARAMS_FILE),
                        "-p", f"scenario:={SCENARIO}")
    rclpy.init()
    node = Listener()
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        for process in (perception, sim):
            _stop(process)
            assert process.returncode is not None


def _tracked(message: ObjectStateArray) -> dict[str, ObjectState]:
    return {o.id: o for o in message.objects if o.status == ObjectState.STATUS_TRACKED}


def _assert_matches_truth(perceived: dict[str, ObjectState], truth: ObjectStateArray) -> None:
    truth_by_id = {o.id: o for o in truth.objects}
    for object_id, state in perceived.items():
        true = truth_by_id[object_id]
        assert state.object_class == true.object_class
        error = math.hypot(state.x - true.x, state.y - true.y)
        assert error < POSITION_TOLERANCE, f"{object_id}: {1000 * error:.2f} mm off"
        if true.symmetry:
            turn = angle_difference_modulo_symmetry(state.theta, true.theta, true.symmetry)
            assert abs(math.degrees(turn)) < ANGLE_TOLERANCE_DEG, f"{object_id}: {turn} rad off"


def _latest_with(listener: Listener, object_id: str) -> ObjectStateArray | None:
    """The newest published array in which object_id is TRACKED (frames come irregularly on a
    loaded machine, so the very latest may be STALE)."""
    return next((m for _, m in reversed(listener.perceived) if object_id in _tracked(m)), None)


def test_tracked_poses_match_ground_truth_and_others_are_not_tracked(listener):
    assert listener.spin_until(lambda: listener.truth is not None and any(
        _tracked(m) for _, m in listener.perceived), 60.0), "no tracked objects published"
    listener.spin_until(lambda: False, 2.0)        # let the objects settle on the table
    # The arm at its ready posture hides most of tset6's table: the partly hidden objects must
    # be flagged (never reported TRACKED at a guessed pose); plate_2 is in plain view.
    latest = _latest_with(listener, "plate_2")
    assert latest is not None, [(o.id, o.status) for o in listener.perceived[-1][1].objects]
    assert {o.id for o in latest.objects} == {o.id for o in listener.truth.objects}
    _assert_matches_truth(_tracked(latest), listener.truth)


def test_objects_are_published_at_ten_hertz(listener):
    start = len(listener.perceived)
    listener.spin_until(lambda: False, 3.0)
    stamps = [t for t, _ in listener.perceived[start:]]
    assert (len(stamps) - 1) / (stamps[-1] - stamps[0]) >= 9.0


def test_settled_observation_follows_a_disturbance_with_the_same_id(listener):
    before = _tracked(_latest_with(listener, "plate_2"))["plate_2"]
    moved = listener.call(listener.disturb_client, DisturbObject.Request(
        object_id="plate_2", dx=-0.02, dy=-0.01, dtheta=0.0), 20.0)
    assert moved.success, moved.message
    answer = listener.call(listener.settled_client,
                           GetSettledObjects.Request(timeout_s=20.0, max_speed=0.0), 30.0)
    assert answer.success, answer.message
    after = _tracked(answer.objects)["plate_2"]
    assert after.x - before.x == pytest.approx(-0.02, abs=POSITION_TOLERANCE)
    assert after.y - before.y == pytest.approx(-0.01, abs=POSITION_TOLERANCE)
    listener.spin_until(lambda: False, 1.0)
    _assert_matches_truth({"plate_2": after}, listener.truth)
