#!/usr/bin/env python3
"""Inspect a running ROS 2 graph with rclpy alone: the `ros2` CLI is not on PyPI.

After `source scripts/env.sh`:

    python scripts/graph.py nodes [NODE ...] [--brief]
    python scripts/graph.py topics [-v]
    python scripts/graph.py services
    python scripts/graph.py actions [-v]
    python scripts/graph.py echo TOPIC [--once | --count N] [--field a.b] [--timeout S]
    python scripts/graph.py hz TOPIC [--window N] [--duration S]
    python scripts/graph.py call SERVICE TYPE ['YAML']
    python scripts/graph.py param list|dump NODE  /  param get NODE NAME

The graph is that of ROS_DOMAIN_ID (and ROS_AUTOMATIC_DISCOVERY_RANGE), as for any node.
There is no daemon: every run discovers the graph afresh. Listings discover for `--wait` seconds
(default 3), then until the graph is stable; lookups (echo, hz, param) give up on a name not seen
within `--wait`. Failures (unknown topic, bad type, timeout) print one line on stderr and exit 1;
usage errors exit 2. `record_bag.py` shares the type and QoS helpers below.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import statistics
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import rclpy
import yaml
from rclpy.action import (
    get_action_client_names_and_types_by_node,
    get_action_names_and_types,
    get_action_server_names_and_types_by_node,
)
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosidl_parser.definition import (
    FLOATING_POINT_TYPES,
    AbstractNestedType,
    BasicType,
    NamespacedType,
)
from rosidl_pycommon import convert_camel_case_to_lower_case_underscore

from tsrrt_common.errors import TsrrtError

DEFAULT_TRUNCATE = 16               # array elements shown by `echo` before "... N more"
STABLE_S = 1.0                      # a listing ends once the graph is unchanged this long...
SETTLE_MAX_S = 5.0                  # ...or this long after --wait at the latest
UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"   # rmw's name for an endpoint of an unnamed node


class GraphToolError(TsrrtError):
    """A command could not do what was asked; the message says what was missing."""


# ------------------------------------------------------------------------------ interface types
def import_interface(type_name: str) -> Any:
    """The Python class of 'pkg/msg/Name', 'pkg/srv/Name' or 'pkg/action/Name' ('pkg/Name' = msg).

    Raises:
        GraphToolError: the name is malformed or the type is not installed.
    """
    parts = type_name.strip("/").split("/")
    if len(parts) == 2:
        parts.insert(1, "msg")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action") or not all(parts):
        raise GraphToolError(f"type '{type_name}' is not of the form package/msg|srv|action/Name")
    package, kind, name = parts
    try:
        module = importlib.import_module(f"{package}.{kind}")
    except ImportError as error:
        raise GraphToolError(f"cannot import '{package}.{kind}' for type '{type_name}': {error} "
                             "(is the workspace sourced? source scripts/env.sh)") from None
    if hasattr(module, name):
        return getattr(module, name)
    # The parts of a service or action ('X_Request', 'X_FeedbackMessage', ...) live only in the
    # generated module of X, e.g. an action's feedback topic type.
    base = name.split("_")[0]
    try:
        parts_module = importlib.import_module(
            f"{package}.{kind}._{convert_camel_case_to_lower_case_underscore(base)}")
        return getattr(parts_module, name)
    except (ImportError, AttributeError):
        available = sorted(n for n in dir(module) if n[:1].isupper())
        raise GraphToolError(f"{package}/{kind} has no type '{name}'; it has: "
                             + ", ".join(available)) from None


def _import_namespaced(namespaced: NamespacedType) -> Any:
    return import_interface("/".join((*namespaced.namespaces, namespaced.name)))


# ------------------------------------------------------------------------------ messages <-> YAML
def message_to_plain(value: Any, truncate: int = 0) -> Any:
    """Message -> nested dicts/lists/scalars for YAML; arrays longer than `truncate` (>0) are cut.

    A cut array keeps its first `truncate` elements and ends with the string '... N more'.
    """
    if hasattr(value, "get_fields_and_field_types"):
        return {name: message_to_plain(getattr(value, name), truncate)
                for name in value.get_fields_and_field_types()}
    if isinstance(value, bytes) and len(value) == 1:      # an 'octet'/'byte' scalar
        return value[0]
    if hasattr(value, "tolist"):                          # numpy arrays/scalars, array.array
        value = value.tolist()
    if isinstance(value, bytes | bytearray):
        value = list(value)
    if not isinstance(value, list | tuple):
        return value
    if 0 < truncate < len(value):
        cut = [message_to_plain(item, truncate) for item in value[:truncate]]
        return [*cut, f"... {len(value) - truncate} more"]
    return [message_to_plain(item, truncate) for item in value]


class _YamlDumper(yaml.SafeDumper):
    """Block mappings, but lists of scalars on one line: `position: [0.1, 0.2]`."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flat = not any(isinstance(item, dict | list) for item in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flat)


_YamlDumper.add_representer(list, _represent_list)


def to_yaml(plain: Any) -> str:
    """YAML text of a plain value; scalars print bare (no '...' document end)."""
    text = yaml.dump(plain, Dumper=_YamlDumper, sort_keys=False, default_flow_style=False,
                     width=99, allow_unicode=True)
    return text.removesuffix("...\n").rstrip("\n")


def select_field(message: Any, path: str) -> Any:
    """`a.b.0.c` below a message: names are fields, integers index arrays."""
    value = message
    for part in path.split("."):
        if hasattr(value, "get_fields_and_field_types"):
            fields = value.get_fields_and_field_types()
            if part not in fields:
                raise GraphToolError(f"'{path}': {type(value).__name__} has no field '{part}'; "
                                     f"fields: {', '.join(fields)}")
            value = getattr(value, part)
        elif part.lstrip("-").isdigit() and hasattr(value, "__getitem__"):
            try:
                value = value[int(part)]
            except IndexError:
                raise GraphToolError(f"'{path}': index {part} is out of range "
                                     f"(length {len(value)})") from None
        else:
            raise GraphToolError(f"'{path}': cannot select '{part}' in a {type(value).__name__}")
    return value


def check_field_path(message_type: Any, path: str) -> None:
    """Fail now, before any message arrives, if `path` cannot exist in `message_type`."""
    slot: Any = NamespacedType(*_split_type(message_type))
    for part in path.split("."):
        if isinstance(slot, AbstractNestedType) and part.lstrip("-").isdigit():
            slot = slot.value_type
            continue
        if not isinstance(slot, NamespacedType):
            raise GraphToolError(f"'{path}': cannot select '{part}' below a non-message field")
        cls = _import_namespaced(slot)
        fields = list(cls.get_fields_and_field_types())
        if part not in fields:
            raise GraphToolError(f"'{path}': {cls.__name__} has no field '{part}'; "
                                 f"fields: {', '.join(fields)}")
        slot = cls.SLOT_TYPES[fields.index(part)]


def _split_type(message_type: Any) -> tuple[list[str], str]:
    """(['pkg', 'msg'], 'Name') of a generated message class (the module is pkg.msg._name)."""
    return message_type.__module__.split(".")[:2], message_type.__name__


def fill_message(message: Any, values: Any, where: str = "") -> Any:
    """Set the fields named in `values` (a dict from YAML) on `message`; returns it.

    Create `message` with `check_fields=True`: without it (Jazzy's default) rclpy does not check
    types and ranges, and a wrong value aborts the process when the message is serialised.
    """
    label = where or type(message).__name__
    if values is None:
        return message
    if not isinstance(values, dict):
        raise GraphToolError(f"{label}: expected a mapping of field names, got {values!r}")
    fields = list(message.get_fields_and_field_types())
    slot_types = dict(zip(fields, type(message).SLOT_TYPES, strict=True))
    for name, value in values.items():
        if name not in slot_types:
            raise GraphToolError(f"{label}: no field '{name}'; fields: {', '.join(fields)}")
        path = f"{where}.{name}" if where else name
        converted = _convert(slot_types[name], value, path)
        try:
            setattr(message, name, converted)
        except (AssertionError, TypeError, ValueError) as error:
            detail = str(error) or "wrong type or out of range"
            raise GraphToolError(f"{path}: cannot set {value!r}: {detail}") from None
    return message


def _convert(slot_type: Any, value: Any, path: str) -> Any:
    """YAML value -> what rclpy's setter for a field of `slot_type` accepts."""
    if isinstance(slot_type, NamespacedType):
        return fill_message(_import_namespaced(slot_type)(check_fields=True), value, path)
    if isinstance(slot_type, AbstractNestedType):
        if not isinstance(value, list):
            raise GraphToolError(f"{path}: expected a list, got {value!r}")
        return [_convert(slot_type.value_type, item, f"{path}.{i}")
                for i, item in enumerate(value)]
    is_float = isinstance(slot_type, BasicType) and slot_type.typename in FLOATING_POINT_TYPES
    if is_float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


# ------------------------------------------------------------------------------ graph helpers
def publisher_matched_qos(node: Node, topic: str, depth: int = 10) -> QoSProfile:
    """A subscription QoS that every current publisher of `topic` can serve (as ros2 bag does).

    Reliable only if all publishers are; transient local only if all are (so a latched message
    is received). With no publisher yet, best effort: it matches either kind.
    """
    publishers = node.get_publishers_info_by_topic(topic)
    reliable = bool(publishers) and all(
        p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in publishers)
    latched = bool(publishers) and all(
        p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
    return QoSProfile(
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def absolute(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def full_node_name(name: str, namespace: str) -> str:
    return namespace.rstrip("/") + "/" + name


def is_hidden_name(name: str) -> bool:
    """ROS convention: a name with a token starting with '_' (like '/x/_action/status')."""
    return any(part.startswith("_") for part in name.split("/"))


class GraphTool:
    """The command's own node (hidden, no rosout, no parameter services) and its waits."""

    def __init__(self, wait: float) -> None:
        self.wait = wait
        self.node = Node(f"_graph_tool_{os.getpid()}", enable_rosout=False,
                         start_parameter_services=False)

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0.0:
            rclpy.spin_once(self.node, timeout_sec=min(0.05, left))

    def spin_until(self, done: Callable[[], bool], timeout: float | None) -> bool:
        """Spin until `done()`; False when `timeout` (None: forever) ran out first."""
        deadline = math.inf if timeout is None else time.monotonic() + timeout
        while not done():
            if time.monotonic() >= deadline:
                return False
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return True

    def settle(self) -> None:
        """Discover for `wait` s, then until the graph is stable (for at most SETTLE_MAX_S more).

        Stable: nothing changed for STABLE_S and every endpoint's node is named (node names
        arrive after their topics). Each process answers discovery on its own schedule, up to
        seconds apart on a loaded machine, so a longer `--wait` gives a more complete listing.
        """
        started = time.monotonic()
        earliest, deadline = started + self.wait, started + self.wait + SETTLE_MAX_S
        last, changed_at = None, started
        while (now := time.monotonic()) < deadline:
            snapshot = (self.nodes(include_hidden=True),
                        self.node.get_topic_names_and_types(),
                        self.node.get_service_names_and_types())
            if snapshot != last:
                last, changed_at = snapshot, now
            elif (now >= earliest and now - changed_at > STABLE_S
                  and not self._endpoints_of_unknown_nodes(snapshot[1])):
                return
            self.spin_for(0.1)

    def _endpoints_of_unknown_nodes(self, topics: list[tuple[str, list[str]]]) -> bool:
        """True while some endpoint's node name has not arrived yet."""
        for topic, _ in topics:
            endpoints = (self.node.get_publishers_info_by_topic(topic)
                         + self.node.get_subscriptions_info_by_topic(topic))
            if any(e.node_name == UNKNOWN_NODE_NAME for e in endpoints):
                return True
        return False

    def nodes(self, include_hidden: bool = False) -> list[tuple[str, str]]:
        """(name, namespace) of every node but this one; a name used twice is listed twice."""
        found = sorted(self.node.get_node_names_and_namespaces())
        return [(n, ns) for n, ns in found
                if n != self.node.get_name() and (include_hidden or not n.startswith("_"))]

    def topic_types(self, topic: str) -> list[str]:
        """Types of `topic`, waiting up to `wait` s for it to be discovered; [] if never seen."""
        def types() -> list[str]:
            return dict(self.node.get_topic_names_and_types()).get(topic, [])
        self.spin_until(lambda: bool(types()), self.wait)
        return types()

    def message_type_of(self, topic: str, explicit_type: str | None) -> Any:
        if explicit_type:
            return import_interface(explicit_type)
        types = self.topic_types(topic)
        if not types:
            known = ", ".join(t for t, _ in self.node.get_topic_names_and_types()
                              if not is_hidden_name(t))
            raise GraphToolError(
                f"topic '{topic}' not found after {self.wait:g} s "
                f"(ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}); "
                f"known topics: {known or 'none'}; give --type to wait for it anyway")
        if len(types) > 1:
            raise GraphToolError(f"topic '{topic}' has several types {types}; choose with --type")
        return import_interface(types[0])


# ------------------------------------------------------------------------------ listing commands
def _rows(pairs: list[tuple[str, list[str]]], include_hidden: bool) -> list[tuple[str, str]]:
    return [(name, ", ".join(types)) for name, types in sorted(pairs)
            if include_hidden or not is_hidden_name(name)]


def _print_table(rows: list[tuple[str, str]], indent: str = "") -> None:
    width = max((len(name) for name, _ in rows), default=0)
    for name, kind in rows:
        print(f"{indent}{name:<{width}}  {kind}")


def cmd_nodes(tool: GraphTool, args: argparse.Namespace) -> None:
    tool.settle()
    nodes = tool.nodes(args.include_hidden)
    if args.node:
        wanted = {absolute(n) for n in args.node}
        missing = wanted - {full_node_name(n, ns) for n, ns in nodes}
        if missing:
            raise GraphToolError(f"no node {', '.join(sorted(missing))}; nodes: "
                                 + ", ".join(full_node_name(n, ns) for n, ns in nodes))
        nodes = [(n, ns) for n, ns in nodes if full_node_name(n, ns) in wanted]
    names = [full_node_name(n, ns) for n, ns in nodes]
    for duplicate in sorted({n for n in names if names.count(n) > 1}):
        print(f"warning: {names.count(duplicate)} nodes are named {duplicate} (two graphs on one "
              "ROS_DOMAIN_ID?); their endpoints are shown merged", file=sys.stderr)
    if args.brief:
        print("\n".join(names))
        return
    g = tool.node
    for name, namespace in dict.fromkeys(nodes):        # each name once, in order
        print(full_node_name(name, namespace))
        sections = {
            "Subscribers": g.get_subscriber_names_and_types_by_node(name, namespace),
            "Publishers": g.get_publisher_names_and_types_by_node(name, namespace),
            "Service Servers": g.get_service_names_and_types_by_node(name, namespace),
            "Service Clients": g.get_client_names_and_types_by_node(name, namespace),
            "Action Servers": get_action_server_names_and_types_by_node(g, name, namespace),
            "Action Clients": get_action_client_names_and_types_by_node(g, name, namespace),
        }
        for title, pairs in sections.items():
            rows = _rows(pairs, args.include_hidden)
            print(f"  {title}:" + ("" if rows else " none"))
            _print_table(rows, indent="    ")


def _qos_text(qos: QoSProfile) -> str:
    return f"{qos.reliability.name.lower()}, {qos.durability.name.lower()}"


def cmd_topics(tool: GraphTool, args: argparse.Namespace) -> None:
    tool.settle()
    rows = _rows(tool.node.get_topic_names_and_types(), args.include_hidden)
    if not args.verbose:
        _print_table(rows)
        return
    for topic, kind in rows:
        print(f"{topic}  {kind}")
        for title, endpoints in (("publishers", tool.node.get_publishers_info_by_topic(topic)),
                                 ("subscribers",
                                  tool.node.get_subscriptions_info_by_topic(topic))):
            endpoints = [e for e in endpoints if e.node_name != tool.node.get_name()]
            print(f"  {title}: {len(endpoints)}")
            for e in endpoints:
                print(f"    {full_node_name(e.node_name, e.node_namespace)}  "
                      f"({_qos_text(e.qos_profile)})")


def cmd_services(tool: GraphTool, args: argparse.Namespace) -> None:
    tool.settle()
    _print_table(_rows(tool.node.get_service_names_and_types(), args.include_hidden))


def cmd_actions(tool: GraphTool, args: argparse.Namespace) -> None:
    """Actions as rcl_action sees them: names derived from their '/_action/' topics."""
    tool.settle()
    actions = sorted(get_action_names_and_types(tool.node))
    if not args.verbose:
        _print_table([(name, ", ".join(types)) for name, types in actions])
        return
    nodes = tool.nodes(include_hidden=True)
    for name, types in actions:
        print(f"{name}  {', '.join(types)}")
        for title, by_node in (("servers", get_action_server_names_and_types_by_node),
                               ("clients", get_action_client_names_and_types_by_node)):
            owners = [full_node_name(n, ns) for n, ns in nodes
                      if name in dict(by_node(tool.node, n, ns))]
            print(f"  {title}: {len(owners)}")
            for owner in owners:
                print(f"    {owner}")


# ------------------------------------------------------------------------------ echo and hz
def cmd_echo(tool: GraphTool, args: argparse.Namespace) -> None:
    topic = absolute(args.topic)
    message_type = tool.message_type_of(topic, args.type)
    if args.field:
        check_field_path(message_type, args.field)
    count = 1 if args.once else args.count            # 0: until Ctrl-C or --timeout
    received = 0

    def on_message(message: Any) -> None:
        nonlocal received
        if count and received >= count:
            return
        received += 1
        value = select_field(message, args.field) if args.field else message
        print(to_yaml(message_to_plain(value, args.truncate)))
        print("---", flush=True)

    tool.node.create_subscription(message_type, topic, on_message,
                                  publisher_matched_qos(tool.node, topic))
    tool.spin_until(lambda: bool(count) and received >= count, args.timeout)
    if args.timeout is not None and received < max(count, 1):
        raise GraphToolError(f"{received} of {max(count, 1)} message(s) on '{topic}' "
                             f"within {args.timeout:g} s")


class RateMeter:
    """Arrival statistics over the last `window` periods (wall clock, as `ros2 topic hz`)."""

    def __init__(self, window: int) -> None:
        self.arrivals: deque[float] = deque(maxlen=window + 1)
        self.total = 0

    def add(self, stamp: float) -> None:
        self.arrivals.append(stamp)
        self.total += 1

    def report(self) -> str | None:
        if len(self.arrivals) < 2:
            return None
        times = list(self.arrivals)
        periods = [b - a for a, b in zip(times, times[1:], strict=False)]
        mean = statistics.fmean(periods)
        std = statistics.pstdev(periods)
        return (f"average rate: {1.0 / mean:.3f} Hz\n"
                f"  min: {min(periods):.4f}s max: {max(periods):.4f}s "
                f"std dev: {std:.5f}s window: {len(periods)}")


def cmd_hz(tool: GraphTool, args: argparse.Namespace) -> None:
    topic = absolute(args.topic)
    message_type = tool.message_type_of(topic, args.type)
    meter = RateMeter(args.window)
    # raw: the rate does not need the message decoded (a camera image costs ms to convert).
    tool.node.create_subscription(message_type, topic, lambda _: meter.add(time.monotonic()),
                                  publisher_matched_qos(tool.node, topic, depth=100), raw=True)
    end = math.inf if args.duration is None else time.monotonic() + args.duration
    last_total = 0
    while time.monotonic() < end:
        tool.spin_for(min(1.0, end - time.monotonic()))
        if meter.total == last_total:
            print(f"no new messages on {topic}", flush=True)
        elif (text := meter.report()) is not None:
            print(text, flush=True)
        last_total = meter.total
    if meter.report() is None:
        raise GraphToolError(f"{meter.total} message(s) on '{topic}' in {args.duration:g} s: "
                             "too few to measure a rate")


# ------------------------------------------------------------------------------ services, params
def call_service(tool: GraphTool, service: str, service_type: Any, request: Any,
                 timeout: float) -> Any:
    client = tool.node.create_client(service_type, service)
    if not client.wait_for_service(timeout_sec=timeout):
        raise GraphToolError(f"service '{service}' not available after {timeout:g} s")
    future = client.call_async(request)
    if not tool.spin_until(future.done, timeout):
        raise GraphToolError(f"service '{service}' did not answer within {timeout:g} s")
    return future.result()


def cmd_call(tool: GraphTool, args: argparse.Namespace) -> None:
    service = absolute(args.service)
    service_type = import_interface(args.type)
    if not hasattr(service_type, "Request"):
        raise GraphToolError(f"'{args.type}' is not a service type (package/srv/Name)")
    try:
        values = yaml.safe_load(args.values)
    except yaml.YAMLError as error:
        detail = " ".join(str(error).split())
        raise GraphToolError(f"request is not valid YAML: {detail}") from None
    request = fill_message(service_type.Request(check_fields=True), values)

    def advertised() -> list[str]:
        return dict(tool.node.get_service_names_and_types()).get(service, [])
    if not tool.spin_until(lambda: bool(advertised()), args.timeout):
        raise GraphToolError(f"service '{service}' not found after {args.timeout:g} s")
    if args.type.strip("/") not in advertised():
        raise GraphToolError(f"service '{service}' has type {', '.join(advertised())}, "
                             f"not {args.type}")
    print("request:\n" + _indent(to_yaml(message_to_plain(request, DEFAULT_TRUNCATE))))
    response = call_service(tool, service, service_type, request, args.timeout)
    print("response:\n" + _indent(to_yaml(message_to_plain(response, args.truncate))))


def _indent(text: str) -> str:
    return "\n".join("  " + line for line in text.splitlines())


def node_parameters(tool: GraphTool, node_name: str, names: list[str] | None,
                    timeout: float) -> dict[str, Any]:
    """{name: value} of a node's parameters (all of them when `names` is None)."""
    from rcl_interfaces.srv import GetParameters, ListParameters

    node_name = absolute(node_name)
    if names is None:
        listed = call_service(tool, f"{node_name}/list_parameters", ListParameters,
                              ListParameters.Request(), timeout)
        names = sorted(listed.result.names)
    answer = call_service(tool, f"{node_name}/get_parameters", GetParameters,
                          GetParameters.Request(names=names), timeout)
    values = dict(zip(names, map(parameter_value_to_python, answer.values), strict=False))
    missing = [name for name in names if values.get(name) is None]
    if missing:                             # undeclared: no value, or NOT_SET (None)
        listed = call_service(tool, f"{node_name}/list_parameters", ListParameters,
                              ListParameters.Request(), timeout)
        raise GraphToolError(f"node {node_name} has no parameter {', '.join(missing)}; it has: "
                             + ", ".join(sorted(listed.result.names)))
    return values


def cmd_param(tool: GraphTool, args: argparse.Namespace) -> None:
    node_name = absolute(args.node)
    if not tool.spin_until(lambda: node_name in {full_node_name(n, ns)
                                                 for n, ns in tool.nodes(True)}, tool.wait):
        raise GraphToolError(f"node '{node_name}' not found after {tool.wait:g} s")
    if args.param_command == "get":
        values = node_parameters(tool, node_name, [args.name], args.timeout)
        print(to_yaml(values[args.name]))
    elif args.param_command == "list":
        for name in node_parameters(tool, node_name, None, args.timeout):
            print(name)
    else:
        values = node_parameters(tool, node_name, None, args.timeout)
        print(to_yaml({node_name.lstrip("/"): {"ros__parameters": values}}))


# ------------------------------------------------------------------------------ command line
def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _seconds(text: str) -> float:
    value = float(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--wait", type=_seconds, default=3.0, metavar="S",
                        help="discovery time: listings discover for S s (then until stable), "
                             "lookups give up on a name after S s (default 3)")
    common.add_argument("-a", "--include-hidden", action="store_true",
                        help="also show hidden names ('/_action/...', '_'-prefixed)")
    parser = argparse.ArgumentParser(
        prog="graph.py", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    nodes = sub.add_parser("nodes", parents=[common], help="nodes and their endpoints")
    nodes.add_argument("node", nargs="*", help="only these nodes (e.g. /sim_node)")
    nodes.add_argument("--brief", action="store_true", help="names only")
    nodes.set_defaults(run=cmd_nodes)

    topics = sub.add_parser("topics", parents=[common], help="topics and their types")
    topics.add_argument("-v", "--verbose", action="store_true",
                        help="publishers and subscribers with their QoS")
    topics.set_defaults(run=cmd_topics)

    services = sub.add_parser("services", parents=[common], help="services and their types")
    services.set_defaults(run=cmd_services)

    actions = sub.add_parser("actions", parents=[common], help="actions and their types")
    actions.add_argument("-v", "--verbose", action="store_true", help="server and client nodes")
    actions.set_defaults(run=cmd_actions)

    echo = sub.add_parser("echo", parents=[common], help="print a topic's messages as YAML")
    echo.add_argument("topic")
    echo.add_argument("--type", help="message type, if the topic is not published yet")
    echo.add_argument("--once", action="store_true", help="print one message and exit")
    echo.add_argument("--count", type=_positive_int, default=0, metavar="N",
                      help="print N messages and exit")
    echo.add_argument("--field", metavar="a.b", help="print only this field (indices allowed)")
    echo.add_argument("--timeout", type=_seconds, metavar="S",
                      help="fail if the messages asked for have not arrived within S s")
    echo.add_argument("--truncate", type=int, default=DEFAULT_TRUNCATE, metavar="N",
                      help=f"array elements shown (default {DEFAULT_TRUNCATE}; 0: all)")
    echo.set_defaults(run=cmd_echo)

    hz = sub.add_parser("hz", parents=[common], help="a topic's publishing rate")
    hz.add_argument("topic")
    hz.add_argument("--type", help="message type, if the topic is not published yet")
    hz.add_argument("--window", type=_positive_int, default=100, metavar="N",
                    help="periods averaged (default 100)")
    hz.add_argument("--duration", type=_seconds, metavar="S",
                    help="stop after S s (fails if fewer than 2 messages arrived)")
    hz.set_defaults(run=cmd_hz)

    call = sub.add_parser("call", parents=[common], help="call a service, print the response")
    call.add_argument("service")
    call.add_argument("type", help="service type, e.g. tsrrt_interfaces/srv/LoadScenario")
    call.add_argument("values", nargs="?", default="{}",
                      help="request fields as YAML, e.g. '{scenario: tset3, seed: -1}'")
    call.add_argument("--timeout", type=_seconds, default=10.0, metavar="S",
                      help="for the service to appear and to answer (default 10 s)")
    call.add_argument("--truncate", type=int, default=DEFAULT_TRUNCATE, metavar="N",
                      help=f"array elements shown (default {DEFAULT_TRUNCATE}; 0: all)")
    call.set_defaults(run=cmd_call)

    param = sub.add_parser("param", help="a node's parameters (list, get, dump)")
    param_sub = param.add_subparsers(dest="param_command", required=True, metavar="ACTION")
    param_common = argparse.ArgumentParser(add_help=False, parents=[common])
    param_common.add_argument("node", help="e.g. /sim_node")
    param_common.add_argument("--timeout", type=_seconds, default=10.0, metavar="S",
                              help="for the parameter services to answer (default 10 s)")
    param_sub.add_parser("list", parents=[param_common], help="parameter names")
    get = param_sub.add_parser("get", parents=[param_common], help="one parameter's value")
    get.add_argument("name")
    param_sub.add_parser("dump", parents=[param_common],
                         help="all parameters as a ROS parameter file")
    param.set_defaults(run=cmd_param)
    return parser


@contextmanager
def graph_tool(wait: float) -> Iterator[GraphTool]:
    # Python's own SIGINT handling (KeyboardInterrupt, caught in main): rclpy's handler would
    # shut the context down under a spinning command, which then fails with an RCLError.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    tool = GraphTool(wait)
    try:
        yield tool
    finally:
        tool.node.destroy_node()
        rclpy.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with graph_tool(args.wait) as tool:
            args.run(tool, args)
    except GraphToolError as error:
        print(f"graph.py {args.command}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        pass                                    # Ctrl-C is how echo and hz are meant to end
    return 0


if __name__ == "__main__":
    sys.exit(main())
