"""Can the arm reach a push? A swappable model the planner uses as a constraint.

The planner only needs a vectorised predicate over the ball-centre points of a push (the approach
point and the end point, on the table plane in the robot base frame). PlanningProblem's default
is the executor's Pinocchio-IK grid (tsrrt_executor.reachability.default_map()), the reach the
robot really has. AnnulusReachability is a simple stand-in for tests and what-if studies: too
close and the elbow folds into the base, too far and the arm is stretched flat; its radii are a
guess, not a computed workspace (the real near limit is not a circle: x >= 0.33 m straight
ahead, x >= 0.25 m at |y| = 0.2 m).

The planner looks reach up on a grid of cells in compiled loops (kernels.py: `faces_reached`,
`segments_reached`): it asks about a few dozen points at a time, thousands of times a second, and
numpy's per-call overhead was most of the cost. A reach model that is such a grid
(`GridReachability`, as the executor's is) gives its cells; any other is sampled onto one
(`rasterised`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

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
