"""rviz/tsrrt.rviz stays in step with the nodes: each display's topic is one a node publishes,
with the message type the display draws. (RViz itself is not on this machine.)"""

from __future__ import annotations

import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "rviz/tsrrt.rviz"
DISPLAY_MESSAGE = {"rviz_default_plugins/Image": "Image",
                   "rviz_default_plugins/MarkerArray": "MarkerArray"}
PUBLISHER = re.compile(r"create_publisher\(\s*(\w+),\s*\"([^\"]+)\"")


def published_topics() -> dict[str, str]:
    """{topic: message class name} from every node module's create_publisher calls."""
    topics: dict[str, str] = {}
    for module in ROOT.glob("ros2_ws/src/*/*/*_node.py"):
        for message, topic in PUBLISHER.findall(module.read_text()):
            topics[topic] = message
    return topics


def test_config_is_rviz2_yaml_in_the_world_frame():
    config = yaml.safe_load(CONFIG.read_text())
    manager = config["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "world"
    assert all(panel["Class"].startswith("rviz_common/") for panel in config["Panels"])
    assert all(d["Class"].startswith("rviz_default_plugins/") for d in manager["Displays"])


def test_every_display_topic_is_published_with_the_drawn_type():
    publishers = published_topics()
    assert "/camera/image_raw" in publishers        # the scan found the node modules
    displays = yaml.safe_load(CONFIG.read_text())["Visualization Manager"]["Displays"]
    drawn = {d["Topic"]["Value"]: DISPLAY_MESSAGE[d["Class"]] for d in displays if "Topic" in d}
    assert set(drawn) == {"/camera/image_raw", "/perception/markers", "/planner/markers"}
    for topic, message in drawn.items():
        assert publishers.get(topic) == message, f"no node publishes {message} on {topic}"
