"""Can the arm reach a push? A swappable model the planner uses as a constraint.

The planner only needs a vectorised predicate over the ball-centre points of a push (the approach
point and the end point, on the table plane in the robot base frame). PlanningProblem's default
is the executor's Pinocchio-IK grid (tsrrt_executor.reachability.default_map()), the reach the
robot really has. AnnulusReachability is a simple stand-in for tests and what-if studies: too
close and the elbow folds into the base, too far and the arm is stretched flat; its radii are a
guess, not a computed workspace (the real near limit is not a circle: x >= 0.33 m straight
ahead, x >= 0.25 m at |y| = 0.2 m).

The planner looks reach up on a grid of cells in compiled loops (`faces_reached`,
`segments_reached`): it asks about a few dozen points at a time, thousands of times a second, and
numpy's per-call overhead was most of the cost. A reach model that is such a grid
(`GridReachability`, as the executor's is) gives its cells; any other is sampled onto one
(`rasterised`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from tsrrt_planner.collision import kernel
from tsrrt_planner.errors import PlannerError

RASTER_STEP = 0.002  # metres: cells of a reach model the planner rasterises (`rasterised`)
RASTER_PAD = 0.25    # metres beyond the table's edges it covers: ball paths start off the table


class Reachability(Protocol):
    """Anything that says which ball-centre points (k, 2) the arm can reach."""

    def reachable(self, points: np.ndarray) -> np.ndarray:
        """(k,) bool for points (k, 2) in the base frame."""
        ...


@runtime_checkable
class GridReachability(Reachability, Protocol):
    """A reach model that is a grid of cells, so compiled checks can look points up."""

    def reach_cells(self) -> tuple[float, float, float, np.ndarray]:
        """(x0, y0, step, cells (rows, cols) bool): (x, y) is reachable iff it lies in the
        grid and cells[floor((y - y0) / step + 1e-9), floor((x - x0) / step + 1e-9)]."""
        ...


@kernel
def _cell_reachable(x: float, y: float, x0: float, y0: float, step: float,
                    cells: np.ndarray) -> bool:
    col = math.floor((x - x0) / step + 1e-9)
    row = math.floor((y - y0) / step + 1e-9)
    if col < 0 or row < 0 or col >= cells.shape[1] or row >= cells.shape[0]:
        return False
    return cells[row, col]


@kernel
def approach_reached(obj: int, face: int, x: float, y: float, c: float, s: float,
                     offsets: np.ndarray, x0: float, y0: float, step: float,
                     cells: np.ndarray) -> bool:
    """Whether the approach point of `face`, offsets[obj, face] (object frame), of object
    `obj` at (x, y) with heading cosine c and sine s is in reach."""
    ox, oy = offsets[obj, face, 0], offsets[obj, face, 1]
    return _cell_reachable(x + (c * ox - s * oy), y + (s * ox + c * oy), x0, y0, step, cells)


@kernel
def faces_reached_at(obj: int, pose: np.ndarray, offsets: np.ndarray, available: np.ndarray,
                     x0: float, y0: float, step: float, cells: np.ndarray) -> int:
    """How many faces f of object `obj` at `pose` (3,) are available[obj, f] and have their
    approach point in reach."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    count = 0
    for f in range(offsets.shape[1]):
        if available[obj, f] and approach_reached(obj, f, pose[0], pose[1], c, s, offsets,
                                                  x0, y0, step, cells):
            count += 1
    return count


@kernel
def faces_reached(objects: np.ndarray, poses: np.ndarray, offsets: np.ndarray,
                  available: np.ndarray, x0: float, y0: float, step: float,
                  cells: np.ndarray) -> np.ndarray:
    """(k,) faces_reached_at of objects (k,) at poses (k, 3)."""
    count = np.zeros(len(objects), np.int64)
    for i in range(len(objects)):
        count[i] = faces_reached_at(objects[i], poses[i], offsets, available, x0, y0, step,
                                    cells)
    return count


@kernel
def segment_reached(start: np.ndarray, end: np.ndarray, spacing: float, x0: float, y0: float,
                    step: float, cells: np.ndarray) -> bool:
    """Whether every point of the segment start-end (2,), sampled evenly at most `spacing`
    apart (ends included), is in reach."""
    dx, dy = end[0] - start[0], end[1] - start[1]
    count = max(2, math.ceil(math.sqrt(dx * dx + dy * dy) / spacing) + 1)
    for j in range(count):
        fraction = j / (count - 1)
        if not _cell_reachable(start[0] + fraction * dx, start[1] + fraction * dy, x0, y0,
                               step, cells):
            return False
    return True


@kernel
def segments_reached(start: np.ndarray, end: np.ndarray, spacing: float, x0: float, y0: float,
                     step: float, cells: np.ndarray) -> np.ndarray:
    """(k,) segment_reached of each segment start-end (k, 2)."""
    ok = np.ones(len(start), np.bool_)
    for i in range(len(start)):
        ok[i] = segment_reached(start[i], end[i], spacing, x0, y0, step, cells)
    return ok


@kernel
def points_reached(points: np.ndarray, x0: float, y0: float, step: float, cells: np.ndarray
                   ) -> np.ndarray:
    """(k,) whether each of points (k, 2) is in reach."""
    reached = np.empty(len(points), np.bool_)
    for i in range(len(points)):
        reached[i] = _cell_reachable(points[i, 0], points[i, 1], x0, y0, step, cells)
    return reached


def rasterised(reachability: Reachability, table_bounds: tuple[float, float, float, float],
               step: float = RASTER_STEP, pad: float = RASTER_PAD
               ) -> tuple[float, float, float, np.ndarray]:
    """A reach model that is no grid as reach_cells over the table, `pad` beyond its edges:
    a cell counts only if the model reaches its four corners (as the executor's map counts its
    own), so the planner never uses a point the model does not reach but within a hair of a
    circular boundary."""
    x_min, y_min, x_max, y_max = table_bounds
    xs = np.arange(x_min - pad, x_max + pad + step, step)
    ys = np.arange(y_min - pad, y_max + pad + step, step)
    grid_x, grid_y = np.meshgrid(xs, ys)
    nodes = np.asarray(reachability.reachable(np.column_stack([grid_x.ravel(), grid_y.ravel()])),
                       bool).reshape(len(ys), len(xs))
    cells = nodes[:-1, :-1] & nodes[:-1, 1:] & nodes[1:, :-1] & nodes[1:, 1:]
    return float(xs[0]), float(ys[0]), step, cells


@dataclass(frozen=True)
class AnnulusReachability:
    """Reachable iff min_radius <= |point| <= max_radius (metres from the base axis)."""

    min_radius: float = 0.25
    max_radius: float = 0.75

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_radius < self.max_radius:
            raise PlannerError(f"reachability annulus needs 0 <= min_radius < max_radius, got "
                               f"{self.min_radius}, {self.max_radius}")

    def reachable(self, points: np.ndarray) -> np.ndarray:
        radius = np.linalg.norm(np.asarray(points, dtype=float), axis=-1)
        return (radius >= self.min_radius) & (radius <= self.max_radius)
