"""Scenario files: the table, the objects and obstacles on it, and the task's objective.

The format is documented in docs/scenarios.md. Every problem found while loading raises a
ScenarioError naming the file, the field (as a dotted path) and what is wrong with it.
Random placements are resolved here, deterministically for a seed, so that every node that loads
the same file with the same seed sees the same world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tsrrt_common.errors import ClassTableError, ScenarioError
from tsrrt_common.geometry import Pose2D, convex_polygons_separated, footprint_polygon
from tsrrt_common.object_classes import ObjectClass, load_class_table

FORMAT_VERSION = 1

# Objective term types and the extra parameters each accepts (besides type, weight, objects).
# The planner's objectives module defines what each term computes; this is the file schema.
OBJECTIVE_TERM_PARAMS: dict[str, frozenset[str]] = {
    "spread": frozenset(),                       # Eq. 1
    "distance_to_point": frozenset({"point"}),   # Eq. 2 (point: [x, y] or "table_center", Eq. 5)
    "orthogonality": frozenset(),                # Eq. 3
    "table_bounds": frozenset({"margin"}),       # Eq. 4 as a soft penalty; the hard bound holds
    "cluster_by_class": frozenset(),             # future work in the paper: group alike objects
    "keep_clear": frozenset({"region"}),         # stay out of a rectangle [xmin, ymin, xmax, ymax]
    "align": frozenset(),                        # objects share one heading modulo pi/2
}


@dataclass(frozen=True)
class Table:
    """Rectangular table whose edges are parallel to the robot base axes (as in the paper)."""

    center: tuple[float, float]
    size: tuple[float, float]
    height: float = 0.0
    friction: float = 0.5

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the table top (Eq. 4)."""
        (cx, cy), (sx, sy) = self.center, self.size
        return (cx - sx / 2.0, cy - sy / 2.0, cx + sx / 2.0, cy + sy / 2.0)


@dataclass(frozen=True)
class ObjectSpec:
    """A movable object (or, with static=True, a fixed obstacle) and its physical properties."""

    id: str
    object_class: str
    shape: str
    length: float
    width: float
    height: float
    symmetry: int
    mass: float
    friction: float
    color: tuple[float, float, float]
    pose: Pose2D
    static: bool = False

    def footprint(self, pose: Pose2D | None = None) -> np.ndarray:
        return footprint_polygon(self.shape, self.length, self.width, pose or self.pose)


@dataclass(frozen=True)
class ObjectiveTermSpec:
    """One weighted term of the objective (Eq. 6) and the objects it applies to."""

    type: str
    weight: float
    object_ids: tuple[str, ...]
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    table: Table
    objects: tuple[ObjectSpec, ...]
    obstacles: tuple[ObjectSpec, ...]
    objective: tuple[ObjectiveTermSpec, ...]
    orientation_weight: float      # Eq. 11: weight of orientation against position in the metric
    seed: int
    source: str

    def object(self, object_id: str) -> ObjectSpec:
        for spec in self.objects:
            if spec.id == object_id:
                return spec
        raise KeyError(f"unknown object {object_id!r}; known: {[o.id for o in self.objects]}")


# ----------------------------------------------------------------------------------- parsing
class _Reader:
    """Typed field access that raises ScenarioError with the field's dotted path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, problem: str) -> ScenarioError:
        return ScenarioError(self.source, where, problem)

    def mapping(self, value: Any, where: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"expected a mapping, got {type(value).__name__}")
        return value

    def check_keys(self, value: dict[str, Any], where: str, allowed: set[str]) -> None:
        unknown = set(value) - allowed
        if unknown:
            raise self.fail(where, f"unknown fields {sorted(unknown)}; allowed: {sorted(allowed)}")

    def require(self, value: dict[str, Any], key: str, where: str) -> Any:
        if key not in value:
            raise self.fail(f"{where}.{key}" if where else key, "missing")
        return value[key]

    def number(self, value: Any, where: str, *, positive: bool = False,
               non_negative: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(where, f"expected a number, got {value!r}")
        number = float(value)
        if not math.isfinite(number):
            raise self.fail(where, f"must be finite, got {value!r}")
        if positive and number <= 0:
            raise self.fail(where, f"must be > 0, got {value!r}")
        if non_negative and number < 0:
            raise self.fail(where, f"must be >= 0, got {value!r}")
        return number

    def vector(self, value: Any, where: str, length: int, **checks: bool) -> tuple[float, ...]:
        if not isinstance(value, list) or len(value) != length:
            raise self.fail(where, f"expected a list of {length} numbers, got {value!r}")
        return tuple(self.number(v, f"{where}[{i}]", **checks) for i, v in enumerate(value))

    def text(self, value: Any, where: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(where, f"expected a non-empty string, got {value!r}")
        return value


_OBJECT_KEYS = {"id", "class", "size", "mass", "friction", "color", "pose"}


def _parse_table(reader: _Reader, raw: Any) -> Table:
    table = reader.mapping(raw, "table")
    reader.check_keys(table, "table", {"center", "size", "height", "friction"})
    center = reader.vector(reader.require(table, "center", "table"), "table.center", 2)
    size = reader.vector(reader.require(table, "size", "table"), "table.size", 2, positive=True)
    height = reader.number(table.get("height", 0.0), "table.height")
    friction = reader.number(table.get("friction", 0.5), "table.friction", positive=True)
    return Table(center, size, height, friction)  # type: ignore[arg-type]


def _parse_object(reader: _Reader, raw: Any, where: str, classes: dict[str, ObjectClass],
                  static: bool) -> tuple[dict[str, Any], Any]:
    """Object fields except the pose, which is returned raw for placement."""
    entry = reader.mapping(raw, where)
    reader.check_keys(entry, where, _OBJECT_KEYS)
    object_id = reader.text(reader.require(entry, "id", where), f"{where}.id")
    class_name = reader.text(reader.require(entry, "class", where), f"{where}.class")
    if class_name not in classes:
        raise reader.fail(f"{where}.class",
                          f"unknown class {class_name!r}; known: {sorted(classes)}")
    cls = classes[class_name]
    length, width, height = cls.length, cls.width, cls.height
    if "size" in entry:
        if cls.shape == "box":
            length, width, height = reader.vector(entry["size"], f"{where}.size", 3, positive=True)
            if width > length:
                raise reader.fail(f"{where}.size", f"length {length} must be >= width {width}")
        else:
            length, height = reader.vector(entry["size"], f"{where}.size", 2, positive=True)
            width = length
    mass = reader.number(entry.get("mass", 0.2), f"{where}.mass", positive=True)
    friction = reader.number(entry.get("friction", 0.4), f"{where}.friction", positive=True)
    color = reader.vector(entry.get("color", [0.7, 0.7, 0.7]), f"{where}.color", 3,
                          non_negative=True)
    if max(color) > 1.0:
        raise reader.fail(f"{where}.color", f"RGB components must be within [0, 1], got {color}")
    fields = dict(id=object_id, object_class=class_name, shape=cls.shape, length=length,
                  width=width, height=height, symmetry=cls.symmetry, mass=mass,
                  friction=friction, color=color, static=static)
    return fields, reader.require(entry, "pose", where)


def _inside_table(footprint: np.ndarray, table: Table) -> bool:
    x_min, y_min, x_max, y_max = table.bounds
    return bool(np.all(footprint[:, 0] >= x_min) and np.all(footprint[:, 0] <= x_max)
                and np.all(footprint[:, 1] >= y_min) and np.all(footprint[:, 1] <= y_max))


def _heading(fields: dict[str, Any], theta: float) -> float:
    """A disc's heading is 0 whatever the file says: it has none a camera could see, so its
    push primitives (along its own axes) go along the table's axes. A random heading drawn
    for it looked like any other and sent its pushes askew: tset6's plates then needed
    staircases of two primitives to slide along an edge or through a gap."""
    return theta if fields["shape"] == "box" else 0.0


def _place(reader: _Reader, fields: dict[str, Any], raw_pose: Any, where: str, table: Table,
           placed: list[ObjectSpec], placement: dict[str, float], rng: np.random.Generator
           ) -> ObjectSpec:
    """Resolve a pose (explicit or 'random') and check it is on the table and overlaps nothing."""
    if raw_pose == "random":
        x_min, y_min, x_max, y_max = table.bounds
        for _ in range(500):
            pose = Pose2D(float(rng.uniform(x_min, x_max)), float(rng.uniform(y_min, y_max)),
                          _heading(fields, float(rng.uniform(-math.pi, math.pi))))
            radius = math.hypot(pose.x, pose.y)
            if not placement["min_radius"] <= radius <= placement["max_radius"]:
                continue
            spec = ObjectSpec(pose=pose, **fields)
            footprint = spec.footprint()
            if _inside_table(footprint, table) and all(
                    convex_polygons_separated(footprint, other.footprint(), placement["margin"])
                    for other in placed):
                return spec
        raise reader.fail(f"{where}.pose", "no free random placement found after 50 restarts; "
                          "the table is too crowded for these objects")
    x, y, theta = reader.vector(raw_pose, f"{where}.pose", 3)
    spec = ObjectSpec(pose=Pose2D(x, y, _heading(fields, theta)), **fields)
    footprint = spec.footprint()
    if not _inside_table(footprint, table):
        raise reader.fail(f"{where}.pose", f"{spec.id} at {raw_pose} is not entirely on the table "
                          f"(bounds {tuple(round(b, 3) for b in table.bounds)})")
    for other in placed:
        if not convex_polygons_separated(footprint, other.footprint()):
            raise reader.fail(f"{where}.pose", f"{spec.id} overlaps {other.id}")
    return spec


def _place_all(reader: _Reader, parsed: list[tuple[dict[str, Any], Any, str]], table: Table,
               placement: dict[str, float], rng: np.random.Generator) -> list[ObjectSpec]:
    """Place every object; a random placement that paints itself into a corner starts over."""
    attempts = 50
    for attempt in range(attempts):
        placed: list[ObjectSpec] = []
        try:
            for fields, raw_pose, where in parsed:
                placed.append(_place(reader, fields, raw_pose, where, table, placed, placement,
                                     rng))
            return placed
        except ScenarioError as error:
            if "random placement" not in error.problem or attempt == attempts - 1:
                raise
    raise AssertionError("unreachable")


def _parse_objective(reader: _Reader, raw: Any, objects: tuple[ObjectSpec, ...]
                     ) -> tuple[tuple[ObjectiveTermSpec, ...], float]:
    objective = reader.mapping(raw, "objective")
    reader.check_keys(objective, "objective", {"terms", "orientation_weight"})
    orientation_weight = reader.number(objective.get("orientation_weight", 40.0),
                                       "objective.orientation_weight", positive=True)
    raw_terms = reader.require(objective, "terms", "objective")
    if not isinstance(raw_terms, list) or not raw_terms:
        raise reader.fail("objective.terms", "expected a non-empty list of terms")
    ids = [o.id for o in objects]
    classes = sorted({o.object_class for o in objects})
    terms = []
    for index, raw_term in enumerate(raw_terms):
        where = f"objective.terms[{index}]"
        term = reader.mapping(raw_term, where)
        term_type = reader.text(reader.require(term, "type", where), f"{where}.type")
        if term_type not in OBJECTIVE_TERM_PARAMS:
            raise reader.fail(f"{where}.type", f"unknown term {term_type!r}; known: "
                              f"{sorted(OBJECTIVE_TERM_PARAMS)}")
        reader.check_keys(term, where, {"type", "weight", "objects"}
                          | OBJECTIVE_TERM_PARAMS[term_type])
        weight = reader.number(reader.require(term, "weight", where), f"{where}.weight",
                               non_negative=True)
        selected = _select_objects(reader, term.get("objects", "all"), f"{where}.objects",
                                   ids, classes, objects)
        params = {k: v for k, v in term.items() if k not in ("type", "weight", "objects")}
        terms.append(ObjectiveTermSpec(term_type, weight, selected, params))
    return tuple(terms), orientation_weight


def _select_objects(reader: _Reader, raw: Any, where: str, ids: list[str], classes: list[str],
                    objects: tuple[ObjectSpec, ...]) -> tuple[str, ...]:
    """Resolve 'all', {class: name | [names]} or {ids: [...]} to object ids."""
    if raw == "all":
        selected = tuple(ids)
    else:
        selector = reader.mapping(raw, where)
        reader.check_keys(selector, where, {"class", "ids"})
        if len(selector) != 1:
            raise reader.fail(where, "give exactly one of 'class' or 'ids' (or the word 'all')")
        if "class" in selector:
            wanted = selector["class"]
            wanted = [wanted] if isinstance(wanted, str) else wanted
            if not isinstance(wanted, list):
                raise reader.fail(f"{where}.class", "expected a class name or a list of them")
            for name in wanted:
                if name not in classes:
                    raise reader.fail(f"{where}.class", f"no object of class {name!r} in this "
                                      f"scenario; classes present: {classes}")
            selected = tuple(o.id for o in objects if o.object_class in wanted)
        else:
            wanted = selector["ids"]
            if not isinstance(wanted, list):
                raise reader.fail(f"{where}.ids", "expected a list of object ids")
            for object_id in wanted:
                if object_id not in ids:
                    raise reader.fail(f"{where}.ids",
                                      f"unknown object {object_id!r}; known: {ids}")
            selected = tuple(wanted)
    if not selected:
        raise reader.fail(where, "the term applies to no object")
    return selected


def parse_scenario(data: Any, source: str, seed: int | None = None,
                   classes: dict[str, ObjectClass] | None = None) -> Scenario:
    """Build a Scenario from already-parsed YAML data; `source` names it in errors."""
    reader = _Reader(source)
    if classes is None:
        try:
            classes = load_class_table()
        except ClassTableError as error:
            raise reader.fail("classes", str(error)) from None
    root = reader.mapping(data, "(top level)")
    reader.check_keys(root, "", {"format", "name", "description", "table", "objects",
                                 "obstacles", "placement", "objective"})
    version = reader.require(root, "format", "")
    if version != FORMAT_VERSION:
        raise reader.fail("format", f"unsupported format {version!r}; this tsrrt reads "
                          f"{FORMAT_VERSION}")
    name = reader.text(reader.require(root, "name", ""), "name")
    description = str(root.get("description", ""))
    table = _parse_table(reader, reader.require(root, "table", ""))

    placement_raw = reader.mapping(root.get("placement", {}), "placement")
    reader.check_keys(placement_raw, "placement", {"seed", "margin", "min_radius", "max_radius"})
    file_seed = placement_raw.get("seed", 0)
    if isinstance(file_seed, bool) or not isinstance(file_seed, int) or file_seed < 0:
        raise reader.fail("placement.seed", f"expected a non-negative integer, got {file_seed!r}")
    placement = {
        "margin": reader.number(placement_raw.get("margin", 0.02), "placement.margin",
                                non_negative=True),
        "min_radius": reader.number(placement_raw.get("min_radius", 0.3),
                                    "placement.min_radius", non_negative=True),
        "max_radius": reader.number(placement_raw.get("max_radius", 0.62),
                                    "placement.max_radius", positive=True),
    }
    if placement["min_radius"] >= placement["max_radius"]:
        raise reader.fail("placement", "min_radius must be smaller than max_radius")
    used_seed = file_seed if seed is None or seed < 0 else seed
    rng = np.random.default_rng(used_seed)

    raw_objects = reader.require(root, "objects", "")
    if not isinstance(raw_objects, list) or not raw_objects:
        raise reader.fail("objects", "expected a non-empty list of objects")
    raw_obstacles = root.get("obstacles", [])
    if not isinstance(raw_obstacles, list):
        raise reader.fail("obstacles", "expected a list")

    entries = [(raw, f"obstacles[{i}]", True) for i, raw in enumerate(raw_obstacles)]
    entries += [(raw, f"objects[{i}]", False) for i, raw in enumerate(raw_objects)]
    parsed = [(*_parse_object(reader, raw, where, classes, static), where)
              for raw, where, static in entries]
    seen_ids: set[str] = set()
    for fields, _, where in parsed:
        if fields["id"] in seen_ids:
            raise reader.fail(f"{where}.id", f"duplicate id {fields['id']!r}")
        seen_ids.add(fields["id"])
    # Explicit poses first, so random placements avoid them; then the largest footprints, which
    # are the hardest to fit.
    parsed.sort(key=lambda item: (item[1] == "random",
                                  -item[0]["length"] * item[0]["width"] if item[1] == "random"
                                  else 0.0))
    placed = _place_all(reader, parsed, table, placement, rng)

    # Placement order differs from file order; keep the file's order in the result.
    file_ids = [e["id"] for e, _, _ in entries if isinstance(e, dict)]
    by_id = {spec.id: spec for spec in placed}
    obstacles = tuple(by_id[i] for i in file_ids if by_id[i].static)
    objects = tuple(by_id[i] for i in file_ids if not by_id[i].static)
    objective, orientation_weight = _parse_objective(
        reader, reader.require(root, "objective", ""), objects)
    return Scenario(name, description, table, objects, obstacles, objective,
                    orientation_weight, used_seed, source)


def shipped_scenarios() -> list[str]:
    """Names of the scenarios that ship with tsrrt."""
    folder = resources.files("tsrrt_common").joinpath("scenarios")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_scenario(name_or_path: str | Path, seed: int | None = None) -> Scenario:
    """Load a shipped scenario by name, or any scenario file by path."""
    text_path = str(name_or_path)
    if text_path in shipped_scenarios():
        source = f"{text_path}.yaml"
        text = resources.files("tsrrt_common").joinpath("scenarios", source).read_text()
    else:
        path = Path(text_path)
        source = str(path)
        if not path.is_file():
            raise ScenarioError(source, "(file)", "no such file and not a shipped scenario; "
                                f"shipped: {shipped_scenarios()}")
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as error:
            raise ScenarioError(source, "(file)", f"cannot read ({error.strerror})") from None
        except UnicodeDecodeError as error:
            raise ScenarioError(source, "(file)", f"not UTF-8 text ({error.reason} at byte "
                                f"{error.start})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ScenarioError(source, "(file)", f"not valid YAML: {error}") from None
    return parse_scenario(data, source, seed)
