"""`scripts/record_bag.py` records the simulator's topics into a bag that rosbags reads back.

The simulator runs on the module's own ROS domain (conftest.py: random, localhost discovery
only); the recorder is stopped the two ways a user or `demo.sh` stops it (SIGINT, SIGTERM) and
must close the bag both times, and is started and stopped once more the way `demo.sh --record`
does it. Every process started here is killed at teardown.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.integration

pytest.importorskip("rclpy")
pytest.importorskip("tsrrt_interfaces.msg")
from ament_index_python.packages import get_package_share_directory  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag2 import Reader  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from tsrrt_common.camera import OverheadCamera  # noqa: E402
from tsrrt_common.robot_model import ARM_JOINT_NAMES  # noqa: E402
from tsrrt_common.scenario import load_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
RECORDER = ROOT / "scripts/record_bag.py"
INTERFACES = ROOT / "ros2_ws/src/tsrrt_interfaces"
SCENARIO = "tset3"
SIM_TOPICS = ("/camera/image_raw", "/camera/camera_info", "/joint_states", "/sim/object_states",
              "/clock")
RECORD_SECONDS = 3.0
# What the demo's bag holds when only the simulator runs (record_bag.py's other default topics
# have no publisher here).
SIM_TYPES = {
    "/camera/image_raw": "sensor_msgs/msg/Image",
    "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/sim/object_states": "tsrrt_interfaces/msg/ObjectStateArray",
    "/clock": "rosgraph_msgs/msg/Clock",
}


def _stop(process: subprocess.Popen, sig: int = signal.SIGINT) -> int:
    """Signal the process group, wait, escalate to SIGKILL; returns the exit code."""
    if process.poll() is None:
        os.killpg(process.pid, sig)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=10)
    return process.returncode


@pytest.fixture(scope="module")
def sim(launch):
    return launch.start("tsrrt_sim", "sim_node", f"scenario:={SCENARIO}")


def wait_until_recording(process: subprocess.Popen, log: Path) -> None:
    """Until the recorder has subscribed to every sim topic, then RECORD_SECONDS more."""
    deadline = time.monotonic() + 90.0
    while not all(f"recording {topic} " in log.read_text() for topic in SIM_TOPICS):
        assert process.poll() is None, log.read_text()
        assert time.monotonic() < deadline, f"recorder never subscribed:\n{log.read_text()}"
        time.sleep(0.2)
    time.sleep(RECORD_SECONDS)


def record(env: dict[str, str], bag: Path, log: Path, stop_signal: int) -> tuple[int, str]:
    """Record the default topics: once subscribed to every sim topic, RECORD_SECONDS more."""
    with log.open("w") as stderr:
        process = subprocess.Popen([sys.executable, str(RECORDER), "-o", str(bag)], env=env,
                                   start_new_session=True, stdout=subprocess.DEVNULL,
                                   stderr=stderr)
    try:
        wait_until_recording(process, log)
        returncode = _stop(process, stop_signal)
    finally:
        _stop(process, signal.SIGKILL)
    return returncode, log.read_text()


@pytest.fixture(scope="module", params=[signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def bag(request, sim, ros_env, tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("bag")
    path = directory / "run"
    returncode, log = record(ros_env, path, directory / "recorder.log", request.param)
    assert returncode == 0, log
    assert "Traceback" not in log, log
    return path


def typestore_from_sources():
    """Jazzy's standard types plus tsrrt_interfaces parsed from this repository's .msg files."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted((INTERFACES / "msg").glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"tsrrt_interfaces/msg/{path.stem}"))
    typestore.register(types)
    return typestore


def first_messages(bag: Path, typestore) -> dict[str, object]:
    """The first deserialised message of every topic."""
    first: dict[str, object] = {}
    with Reader(bag) as reader:
        for connection, _, data in reader.messages():
            if connection.topic not in first:
                first[connection.topic] = typestore.deserialize_cdr(data, connection.msgtype)
    return first


def test_bag_is_closed_rosbag2_mcap_with_every_sim_topic(bag):
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["version"] == 9
    assert metadata["storage_identifier"] == "mcap"
    assert (bag / metadata["relative_file_paths"][0]).suffix == ".mcap"
    counts = {t["topic_metadata"]["name"]: t["message_count"]
              for t in metadata["topics_with_message_count"]}
    assert set(SIM_TOPICS) <= set(counts)
    assert all(counts[topic] > 0 for topic in SIM_TOPICS), counts
    assert metadata["message_count"] == sum(counts.values())


def test_messages_deserialise_with_the_expected_fields(bag):
    messages = first_messages(bag, typestore_from_sources())
    camera = OverheadCamera()
    image = messages["/camera/image_raw"]
    assert (image.height, image.width, image.encoding) == (camera.height, camera.width, "rgb8")
    pixels = np.asarray(image.data).reshape(camera.height, camera.width, 3)
    assert pixels.std() > 1.0                                # a rendered scene, not a blank
    joints = messages["/joint_states"]
    assert list(joints.name) == list(ARM_JOINT_NAMES) and len(joints.position) == 7
    states = messages["/sim/object_states"]
    assert states.header.frame_id == "world"
    scenario = load_scenario(SCENARIO)
    assert sorted(o.id for o in states.objects) == sorted(o.id for o in scenario.objects)
    xmin, ymin, xmax, ymax = scenario.table.bounds
    assert all(xmin < o.x < xmax and ymin < o.y < ymax for o in states.objects)
    info = messages["/camera/camera_info"]
    np.testing.assert_allclose(np.asarray(info.k).reshape(3, 3), camera.intrinsics)


def test_bag_carries_definitions_and_hashes_ros_tools_accept(bag):
    """A reader with no type knowledge decodes the custom types from the bag alone, and the
    recorded type hashes are the ones ROS generated (what `ros2 bag play` checks)."""
    description = (Path(get_package_share_directory("tsrrt_interfaces"))
                   / "msg/ObjectStateArray.json")
    generated = json.loads(description.read_text())["type_hashes"][0]
    assert generated["type_name"] == "tsrrt_interfaces/msg/ObjectStateArray"
    with AnyReader([bag]) as reader:
        (connection,) = [c for c in reader.connections if c.topic == "/sim/object_states"]
        assert connection.digest == generated["hash_string"]
        _, _, data = next(reader.messages(connections=[connection]))
        states = reader.deserialize(data, connection.msgtype)
    assert len(states.objects) == len(load_scenario(SCENARIO).objects)


def test_recorder_refuses_to_overwrite_a_bag(tmp_path, ros_env):
    result = subprocess.run([sys.executable, str(RECORDER), "-o", str(tmp_path)], env=ros_env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert f"{tmp_path} exists" in result.stderr


def load_demo_script():
    """scripts/demo.py as a module (it is a script, not part of a package)."""
    spec = importlib.util.spec_from_file_location("tsrrt_demo_script", ROOT / "scripts/demo.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_demo_record_writes_a_compressed_bag_rosbags_reads_back(sim, tmp_path):
    """`demo.sh --record` starts the recorder beside the graph and stops it with the graph's
    SIGTERM; every message in the bag decodes as its topic's type, the per-topic counts in the
    metadata are the messages read back, and zstd makes the bag smaller than its messages."""
    demo = load_demo_script()
    out = tmp_path / "out"
    recorder = demo.start_recorder(out / "bag", out / "logs")
    log = out / "logs" / "record_bag.log"
    try:
        wait_until_recording(recorder, log)
    finally:
        demo.stop_graph(recorder)
    assert recorder.returncode == 0, log.read_text()
    assert "Traceback" not in log.read_text(), log.read_text()

    read: dict[str, int] = {}
    payload_bytes = 0
    with AnyReader([out / "bag"]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == SIM_TYPES
        listed = {c.topic: c.msgcount for c in reader.connections}
        truth_stamps = []
        for connection, _, data in reader.messages():
            message = reader.deserialize(data, connection.msgtype)     # raises on bad CDR
            read[connection.topic] = read.get(connection.topic, 0) + 1
            payload_bytes += len(data)
            if connection.topic == "/sim/object_states":
                truth_stamps.append(message.header.stamp.sec + message.header.stamp.nanosec * 1e-9)
    assert read == listed
    assert all(read[topic] > 0 for topic in SIM_TYPES), read
    assert truth_stamps == sorted(truth_stamps) and truth_stamps[-1] > truth_stamps[0]
    bag_bytes = sum(f.stat().st_size for f in (out / "bag").iterdir())
    assert bag_bytes < payload_bytes / 2, (bag_bytes, payload_bytes)
    summary = demo.bag_summary(out / "bag")
    assert f"/camera/image_raw {read['/camera/image_raw']}" in summary
