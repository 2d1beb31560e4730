"""The Panda with the paper's ball end-effector: one URDF the simulator and Pinocchio load.

The description comes from example-robot-data (pip's cmeel prefix or an apt install's share dir).
The fingers are replaced by a short rod with a ball at its tip, as on the paper's arm, and the mesh
URIs are made absolute so that PyBullet (which does not resolve package://) reads the same file.
"""

from __future__ import annotations

import hashlib
import os
import site
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from tsrrt_common.errors import RobotModelError

ARM_JOINT_NAMES: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, 8))
# A comfortable posture with the tool pointing down above the middle of the table.
READY_POSTURE: tuple[float, ...] = (0.0, -0.35, 0.0, -2.35, 0.0, 2.0, 0.785398)
# Where the arm waits while the overhead camera looks: folded back over its base (ball at about
# (0.19, 0, 0.35), hand and links behind and above it), so that no part of it is inside the
# camera's field of view (OverheadCamera defaults; checked by rendering: not one pixel, with
# joint 2 up to 0.4 rad further forward). At READY_POSTURE the arm hides most of the table.
# The simulator starts here and the executor returns here after every push, so that perception
# sees every object before and after it.
OBSERVE_POSTURE: tuple[float, ...] = (0.0, -1.4, 0.0, -2.9, 0.0, 1.6, 0.785398)
BASE_LINK = "panda_link0"
TOOL_FRAME = "tsrrt_ball"          # frame at the centre of the pushing ball
BALL_RADIUS = 0.012                # metres
ROD_RADIUS = 0.006
ROD_START_IN_HAND = 0.05           # rod spans hand z in [0.05, BALL_CENTRE_IN_HAND]
BALL_CENTRE_IN_HAND = 0.13
_FINGER_LINKS = ("panda_leftfinger", "panda_rightfinger")
_PACKAGE_PREFIX = "package://example-robot-data/"


def example_robot_data_dir() -> Path:
    """Directory holding `robots/panda_description`, wherever example-robot-data is installed."""
    candidates: list[Path] = []
    if env_dir := os.environ.get("TSRRT_EXAMPLE_ROBOT_DATA_DIR"):
        candidates.append(Path(env_dir))
    for site_dir in [*site.getsitepackages(), site.getusersitepackages(), *sys.path]:
        candidates.append(Path(site_dir) / "cmeel.prefix" / "share" / "example-robot-data")
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "example-robot-data")
    candidates.append(Path("/opt/ros/jazzy/share/example-robot-data"))
    for candidate in candidates:
        if (candidate / "robots" / "panda_description" / "urdf" / "panda.urdf").is_file():
            return candidate
    raise RobotModelError(
        "example-robot-data's Panda not found; install the 'example-robot-data' wheel or set "
        "TSRRT_EXAMPLE_ROBOT_DATA_DIR (looked in: "
        + ", ".join(str(c) for c in candidates[:6]) + ", ...)"
    )


def _fixed_joint(name: str, parent: str, child: str, z: float) -> ET.Element:
    joint = ET.Element("joint", name=name, type="fixed")
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=f"0 0 {z}", rpy="0 0 0")
    return joint


def _link(name: str, geometry: ET.Element, mass: float, inertia: float, z: float) -> ET.Element:
    link = ET.Element("link", name=name)
    for tag in ("visual", "collision"):
        element = ET.SubElement(link, tag)
        ET.SubElement(element, "origin", xyz=f"0 0 {z}", rpy="0 0 0")
        ET.SubElement(element, "geometry").append(geometry)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz=f"0 0 {z}", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=str(mass))
    ET.SubElement(inertial, "inertia", ixx=str(inertia), iyy=str(inertia), izz=str(inertia),
                  ixy="0", ixz="0", iyz="0")
    return link


def pusher_urdf_text(data_dir: Path) -> str:
    """The Panda URDF with fingers replaced by the ball pusher and absolute mesh paths."""
    source = data_dir / "robots" / "panda_description" / "urdf" / "panda.urdf"
    root = ET.fromstring(source.read_text())
    for element in list(root):
        is_finger_link = element.tag == "link" and element.get("name") in _FINGER_LINKS
        child = element.find("child")
        is_finger_joint = element.tag == "joint" and child is not None and child.get(
            "link") in _FINGER_LINKS
        if is_finger_link or is_finger_joint:
            root.remove(element)
    for mesh in root.iter("mesh"):
        filename = mesh.get("filename", "")
        if filename.startswith(_PACKAGE_PREFIX):
            mesh.set("filename", str(data_dir / filename[len(_PACKAGE_PREFIX):]))
    rod_length = BALL_CENTRE_IN_HAND - ROD_START_IN_HAND
    rod = ET.Element("cylinder", radius=str(ROD_RADIUS), length=str(rod_length))
    ball = ET.Element("sphere", radius=str(BALL_RADIUS))
    root.append(_link("tsrrt_rod", rod, 0.05, 3e-5, rod_length / 2.0))
    root.append(_fixed_joint("tsrrt_rod_joint", "panda_hand", "tsrrt_rod", ROD_START_IN_HAND))
    root.append(_link(TOOL_FRAME, ball, 0.03, 2e-6, 0.0))
    root.append(_fixed_joint("tsrrt_ball_joint", "tsrrt_rod", TOOL_FRAME, rod_length))
    root.set("name", "panda_pusher")
    return ET.tostring(root, encoding="unicode")


def pusher_urdf_path(cache_dir: Path | None = None) -> Path:
    """Path of the generated pusher URDF, written atomically once per source and geometry."""
    data_dir = example_robot_data_dir()
    text = pusher_urdf_text(data_dir)
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    if cache_dir is None:
        cache_root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        cache_dir = Path(cache_root) / "tsrrt"
    cache_dir.mkdir(parents=True, exist_ok=True)
    path = cache_dir / f"panda_pusher_{digest}.urdf"
    if not path.is_file():
        with tempfile.NamedTemporaryFile("w", dir=cache_dir, delete=False, suffix=".tmp") as tmp:
            tmp.write(text)
        os.replace(tmp.name, path)
    return path
