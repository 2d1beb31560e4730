#!/usr/bin/env python3
"""Write README.md's tables of every node's topics, services, actions and parameters, read from
the nodes themselves, so that the tables cannot drift from the code.

    python scripts/interface_tables.py            # rewrite the block in README.md
    python scripts/interface_tables.py --check    # exit 1 if README.md is out of date

The nodes are the `console_scripts` entry points of the installed tsrrt packages (what `ros2 run`
starts); each entry point's module holds one rclpy Node subclass. Each node is constructed in
this process twice, never spun: once as `ros2 run` starts it bare (its declared defaults), once
with its package's config/<node>.yaml as bringup.sh starts it, and its publishers,
subscriptions, services and actions are read from the ROS graph (as `ros2 node info` does) with
their QoS from the node's own endpoint objects. Discovery is off, so the graph holds this
process's nodes and nothing else running on the machine. The block sits between the markers
below in README.md; `scripts/test.sh` fails when it is out of date.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import importlib
import inspect
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

# Before rclpy loads the middleware: no discovery, only this process's own nodes in the graph.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"

import rclpy  # noqa: E402
from graph import is_hidden_name  # noqa: E402
from rcl_interfaces.msg import ParameterDescriptor, ParameterType  # noqa: E402
from rclpy.action import (  # noqa: E402
    get_action_client_names_and_types_by_node,
    get_action_server_names_and_types_by_node,
)
from rclpy.node import Node  # noqa: E402
from rclpy.qos import (  # noqa: E402
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
BEGIN = "<!-- interfaces:begin -->"
END = "<!-- interfaces:end -->"
# Every rclpy node has these; the tables list what tsrrt adds.
INFRASTRUCTURE_TOPICS = {"/rosout", "/parameter_events"}
INFRASTRUCTURE_SERVICES = {"describe_parameters", "get_parameter_types", "get_parameters",
                           "get_type_description", "list_parameters", "set_parameters",
                           "set_parameters_atomically"}
INFRASTRUCTURE_PARAMETERS = {"start_type_description_service"}
TYPE_NAMES = {ParameterType.PARAMETER_BOOL: "bool", ParameterType.PARAMETER_INTEGER: "integer",
              ParameterType.PARAMETER_DOUBLE: "double", ParameterType.PARAMETER_STRING: "string",
              ParameterType.PARAMETER_BYTE_ARRAY: "byte[]",
              ParameterType.PARAMETER_BOOL_ARRAY: "bool[]",
              ParameterType.PARAMETER_INTEGER_ARRAY: "integer[]",
              ParameterType.PARAMETER_DOUBLE_ARRAY: "double[]",
              ParameterType.PARAMETER_STRING_ARRAY: "string[]"}


@dataclass(frozen=True)
class NodeEntry:
    """One `ros2 run PACKAGE EXECUTABLE` and the Node class its module defines."""
    package: str
    executable: str
    node_class: type[Node]

    @property
    def config(self) -> Path:
        return ROOT / "ros2_ws/src" / self.package / "config" / f"{self.executable}.yaml"


@dataclass(frozen=True)
class Parameter:
    name: str
    descriptor: ParameterDescriptor
    default: Any
    configured: Any          # the value with config/<node>.yaml loaded


def node_entries() -> list[NodeEntry]:
    """The installed tsrrt console scripts, each with the one Node subclass of its module."""
    entries = []
    for point in entry_points(group="console_scripts"):
        module_name = point.value.split(":")[0]
        if not module_name.startswith("tsrrt_"):
            continue
        module = importlib.import_module(module_name)
        classes = [c for _, c in inspect.getmembers(module, inspect.isclass)
                   if issubclass(c, Node) and c.__module__ == module_name]
        if len(classes) != 1:
            raise SystemExit(f"interface_tables.py: {module_name} defines {len(classes)} Node "
                             "classes; expected exactly one")
        entries.append(NodeEntry(module_name.split(".")[0], point.name, classes[0]))
    if not entries:
        raise SystemExit("interface_tables.py: no tsrrt console scripts installed; build ros2_ws "
                         "(scripts/setup.sh) and source scripts/env.sh")
    return sorted(entries, key=lambda e: e.executable)


@contextlib.contextmanager
def constructed(entry: NodeEntry, ros_args: list[str]) -> Iterator[Node]:
    """The node, constructed in a fresh rclpy context with `ros_args`; destroyed afterwards."""
    rclpy.init(args=["interface_tables", "--ros-args", "--log-level", "warn", *ros_args])
    node = None
    try:
        node = entry.node_class()
        yield node
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def qos_note(qos: QoSProfile) -> str:
    if qos == qos_profile_sensor_data:
        return f"sensor data (best effort, volatile, depth {qos.depth})"
    reliability = "best effort" if qos.reliability == ReliabilityPolicy.BEST_EFFORT else "reliable"
    durability = ("transient local" if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
                  else "volatile")
    history = "keep all" if qos.history == HistoryPolicy.KEEP_ALL else f"depth {qos.depth}"
    return f"{reliability}, {durability}, {history}"


def interface_rows(node: Node) -> list[tuple[str, str, str, str]]:
    """(role, name, type, QoS) of every endpoint the node opened itself, as the graph shows it."""
    name, namespace = node.get_name(), node.get_namespace()
    own_services = f"{node.get_fully_qualified_name()}/"
    qos_of = {("publishes", p.topic_name): p.qos_profile for p in node.publishers}
    qos_of.update({("subscribes", s.topic_name): s.qos_profile for s in node.subscriptions})
    rows = []
    for role, listing in (
            ("publishes", node.get_publisher_names_and_types_by_node(name, namespace)),
            ("subscribes", node.get_subscriber_names_and_types_by_node(name, namespace))):
        for topic, types in listing:
            if topic not in INFRASTRUCTURE_TOPICS and not is_hidden_name(topic):
                rows += [(role, topic, t, qos_note(qos_of[role, topic])) for t in types]
    for role, listing in (
            ("service server", node.get_service_names_and_types_by_node(name, namespace)),
            ("service client", node.get_client_names_and_types_by_node(name, namespace))):
        for service, types in listing:
            infrastructure = (service.startswith(own_services) and
                              service[len(own_services):] in INFRASTRUCTURE_SERVICES)
            if not infrastructure and not is_hidden_name(service):
                rows += [(role, service, t, "") for t in types]
    for role, listing in (
            ("action server", get_action_server_names_and_types_by_node(node, name, namespace)),
            ("action client", get_action_client_names_and_types_by_node(node, name, namespace))):
        rows += [(role, action, t, "") for action, types in listing for t in types]
    return rows


def parameters(node: Node) -> dict[str, tuple[ParameterDescriptor, Any]]:
    names = [n for n in node.list_parameters([], 0).names if n not in INFRASTRUCTURE_PARAMETERS]
    return {n: (d, node.get_parameter(n).value)
            for n, d in zip(names, node.describe_parameters(names), strict=True)}


def inspect_node(entry: NodeEntry) -> tuple[list[tuple[str, str, str, str]], list[Parameter]]:
    with constructed(entry, []) as node:
        defaults = parameters(node)
    with constructed(entry, ["--params-file", str(entry.config)]) as node:
        rows = interface_rows(node)
        configured = parameters(node)
    return rows, [Parameter(n, d, value, configured[n][1]) for n, (d, value) in defaults.items()]


def value_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, str):
        return f"`{value}`" if value else '`""`'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(value_text(v).strip("`") for v in value) + "]"
    return str(value)


def range_text(descriptor: ParameterDescriptor) -> str:
    ranges = [*descriptor.floating_point_range, *descriptor.integer_range]
    text = ", ".join(f"{value_text(r.from_value)} .. {value_text(r.to_value)}" for r in ranges)
    if descriptor.read_only:
        text = f"{text}; read-only" if text else "read-only"
    return text


def cell(text: str) -> str:
    """Markdown table cell text: `|` would end the cell, `<name>` would vanish as an HTML tag."""
    return text.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def render(entries: list[NodeEntry]) -> str:
    lines = [BEGIN,
             "<!-- Generated by scripts/interface_tables.py from the nodes themselves: "
             "edit the nodes, then run it. -->"]
    for entry in entries:
        rows, params = inspect_node(entry)
        lines += ["", f"#### `{entry.executable}` (`ros2 run {entry.package} {entry.executable}`)",
                  "", "| role | name | type | QoS |", "|---|---|---|---|"]
        lines += [f"| {role} | `{name}` | `{kind}` | {qos} |" for role, name, kind, qos in rows]
        lines += ["", f"| parameter | type | default | `config/{entry.executable}.yaml` | range "
                  "| description |", "|---|---|---|---|---|---|"]
        for p in params:
            configured = value_text(p.configured) if p.configured != p.default else ""
            lines.append(f"| `{p.name}` | {TYPE_NAMES.get(p.descriptor.type, '?')} | "
                         f"{cell(value_text(p.default))} | {cell(configured)} | "
                         f"{cell(range_text(p.descriptor))} | {cell(p.descriptor.description)} |")
    lines.append(END)
    return "\n".join(lines)


def replace_block(text: str, block: str, path: Path) -> str:
    begin, end = text.find(BEGIN), text.find(END)
    if begin < 0 or end < begin:
        raise SystemExit(f"interface_tables.py: {path} lacks the {BEGIN} ... {END} markers")
    return text[:begin] + block + text[end + len(END):]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="interface_tables.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 with a diff if the tables are out of date")
    parser.add_argument("--readme", type=Path, default=README, help="default: README.md")
    args = parser.parse_args(argv)
    current = args.readme.read_text()
    updated = replace_block(current, render(node_entries()), args.readme)
    if updated == current:
        return 0
    if args.check:
        sys.stdout.writelines(difflib.unified_diff(
            current.splitlines(keepends=True), updated.splitlines(keepends=True),
            str(args.readme), "generated"))
        print(f"interface_tables.py: {args.readme} is out of date; run "
              "python scripts/interface_tables.py", file=sys.stderr)
        return 1
    args.readme.write_text(updated)
    print(f"interface_tables.py: updated {args.readme}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
