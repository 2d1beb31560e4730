"""Every package.xml declares what its Python code imports, as rosdep keys, and nothing it does
not use: `rosdep install --from-paths ros2_ws/src` must be all an apt install of Jazzy needs.

A static scan (ast) of each ament_python package's modules (exec dependencies) and test/ files
(test dependencies, or exec ones) against the <exec_depend>/<depend>/<test_depend> tags.
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "ros2_ws/src"
PYTHON_PACKAGES = sorted(p.parent.name for p in SRC.glob("*/setup.py"))
WORKSPACE_PACKAGES = {p.parent.name for p in SRC.glob("*/package.xml")}
# Modules that are not ROS packages: their rosdep keys (ros/rosdistro rosdep/python.yaml, or
# the ROS package that ships them). A module missing here fails the test until it is added.
ROSDEP_KEYS = {
    "numpy": "python3-numpy",
    "numba": "python3-numba",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "cv2": "python3-opencv",
    "matplotlib": "python3-matplotlib",
    "pybullet": "python3-pybullet-pip",      # no apt package in rosdep: pip
    "pinocchio": "pinocchio",                # ros-jazzy-pinocchio, with its Python bindings
    "pytest": "python3-pytest",
}
# OMPL's Python bindings have no rosdep key (ROS's ompl package is C++ only); only the planner
# benchmark's optional baselines import them, lazily.
NO_ROSDEP_KEY = {"ompl"}
# Dependencies used as files, not imports.
DATA_DEPENDENCIES = {"tsrrt_common": {"example-robot-data"}}   # the Panda URDF and meshes


def ros_packages() -> set[str]:
    from ament_index_python.packages import get_packages_with_prefixes
    return set(get_packages_with_prefixes()) | WORKSPACE_PACKAGES


def imported_modules(files: list[Path]) -> set[str]:
    """Top-level names of every absolute import in `files`, function-level ones included."""
    modules = set()
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                modules.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                modules.add(node.module.split(".")[0])
    return modules


def rosdep_keys(package: str, modules: set[str], known_ros: set[str]) -> set[str]:
    keys = set()
    for module in modules - set(sys.stdlib_module_names) - NO_ROSDEP_KEY - {package}:
        if module in ROSDEP_KEYS:
            keys.add(ROSDEP_KEYS[module])
        elif module in known_ros:
            keys.add(module)
        else:
            pytest.fail(f"{package} imports '{module}', which is neither a ROS package nor in "
                        "ROSDEP_KEYS: add its rosdep key there and to package.xml")
    return keys


def declared(package: str) -> tuple[set[str], set[str]]:
    """(exec dependencies, test dependencies) of the package's package.xml."""
    root = ET.parse(SRC / package / "package.xml").getroot()
    tags = {tag: {e.text.strip() for e in root.iter(tag)}
            for tag in ("depend", "exec_depend", "test_depend")}
    return tags["depend"] | tags["exec_depend"], tags["test_depend"]


@pytest.fixture(scope="module")
def known_ros() -> set[str]:
    pytest.importorskip("ament_index_python")
    return ros_packages()


def test_the_scan_finds_the_packages_and_their_imports(known_ros):
    assert set(PYTHON_PACKAGES) == WORKSPACE_PACKAGES - {"tsrrt_interfaces"}
    assert {"rclpy", "sensor_msgs", "tsrrt_interfaces"} <= known_ros
    sim_modules = imported_modules(sorted((SRC / "tsrrt_sim/tsrrt_sim").glob("*.py")))
    assert {"pybullet", "rclpy", "numpy", "tsrrt_common"} <= sim_modules


@pytest.mark.parametrize("package", PYTHON_PACKAGES)
def test_package_xml_declares_every_import_and_only_those(package, known_ros):
    code = rosdep_keys(package, imported_modules(sorted((SRC / package / package).rglob("*.py"))),
                       known_ros)
    tests = rosdep_keys(package, imported_modules(sorted((SRC / package / "test").rglob("*.py"))),
                        known_ros)
    exec_depends, test_depends = declared(package)
    data = DATA_DEPENDENCIES.get(package, set())
    assert code - exec_depends == set(), f"{package}/package.xml lacks <exec_depend>s"
    assert tests - exec_depends - test_depends == set(), \
        f"{package}/package.xml lacks <test_depend>s"
    assert exec_depends - code - data == set(), \
        f"{package}/package.xml declares <exec_depend>s its code does not import"
    assert test_depends - tests == set(), \
        f"{package}/package.xml declares <test_depend>s its tests do not import"
