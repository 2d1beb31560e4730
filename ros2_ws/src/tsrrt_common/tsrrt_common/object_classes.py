"""The object class table: nominal footprint, height and symmetry of each class of object.

Perception classifies by footprint size and aspect ratio against this table (never by colour);
scenarios instantiate objects from it. The table is a YAML file, `classes.yaml` beside this module
unless another path is given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from tsrrt_common.errors import ClassTableError

SHAPES = ("box", "cylinder")


@dataclass(frozen=True)
class ObjectClass:
    """Nominal geometry of one class. For a cylinder, length == width == diameter."""

    name: str
    shape: str
    length: float
    width: float
    height: float
    symmetry: int
    tolerance: float

    @property
    def aspect_ratio(self) -> float:
        return self.length / self.width


def _parse_class(name: str, entry: Any, source: str) -> ObjectClass:
    where = f"{source}: classes.{name}"
    if not isinstance(entry, dict):
        raise ClassTableError(f"{where}: expected a mapping, got {type(entry).__name__}")
    missing = {"shape", "size", "symmetry", "tolerance"} - entry.keys()
    if missing:
        raise ClassTableError(f"{where}: missing fields {sorted(missing)}")
    shape = entry["shape"]
    if shape not in SHAPES:
        raise ClassTableError(f"{where}.shape: {shape!r} is not one of {list(SHAPES)}")
    size = entry["size"]
    expected = 3 if shape == "box" else 2
    if not isinstance(size, list) or len(size) != expected:
        raise ClassTableError(f"{where}.size: a {shape} needs {expected} numbers")
    try:
        size = [float(v) for v in size]
        tolerance = float(entry["tolerance"])
        symmetry = int(entry["symmetry"])
    except (TypeError, ValueError) as error:
        raise ClassTableError(
            f"{where}: non-numeric size, tolerance or symmetry ({error})") from None
    if not all(math.isfinite(v) and v > 0 for v in [*size, tolerance]):
        raise ClassTableError(f"{where}: sizes and tolerance must be finite and positive")
    if shape == "box":
        length, width, height = size
        if width > length:
            raise ClassTableError(f"{where}.size: length {length} must be >= width {width}")
    else:
        length = width = size[0]
        height = size[1]
        symmetry = 0
    if symmetry not in (0, 1, 2, 4):
        raise ClassTableError(f"{where}.symmetry: {symmetry} is not one of 0, 1, 2, 4")
    return ObjectClass(name, shape, length, width, height, symmetry, tolerance)


def load_class_table(path: str | Path | None = None) -> dict[str, ObjectClass]:
    """Read the class table; without a path, the one shipped with tsrrt_common."""
    if path is None:
        source = "classes.yaml"
        text = resources.files("tsrrt_common").joinpath("classes.yaml").read_text()
    else:
        source = str(path)
        try:
            text = Path(path).read_text()
        except OSError as error:
            raise ClassTableError(f"{source}: cannot read ({error.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ClassTableError(f"{source}: not valid YAML ({error})") from None
    if not isinstance(data, dict) or not isinstance(data.get("classes"), dict):
        raise ClassTableError(f"{source}: expected a top-level 'classes' mapping")
    if not data["classes"]:
        raise ClassTableError(f"{source}: the class table is empty")
    return {name: _parse_class(name, entry, source) for name, entry in data["classes"].items()}


def lookup_class(table: dict[str, ObjectClass], name: str) -> ObjectClass:
    """The class called `name`, or an error listing the classes that exist."""
    try:
        return table[name]
    except KeyError:
        raise ClassTableError(f"unknown object class {name!r}; known: {sorted(table)}") from None
