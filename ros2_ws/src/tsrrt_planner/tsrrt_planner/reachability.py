"""Can the arm reach a push? A swappable model the planner uses as a constraint.

The planner only needs a vectorised predicate over the ball-centre points of a push (the approach
point and the end point, on the table plane in the robot base frame). PlanningProblem's default
is the executor's Pinocchio-IK grid (tsrrt_executor.reachability.default_map()), the reach the
robot really has. AnnulusReachability is a simple stand-in for tests and what-if studies: too
close and the elbow folds into the base, too far and the arm is stretched flat; its radii are a
guess, not a computed workspace (the real near limit is not a circle: x >= 0.33 m straight
ahead, x >= 0.25 m at |y| = 0.2 m).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tsrrt_planner.errors import PlannerError


class Reachability(Protocol):
    """Anything that says which ball-centre points (k, 2) the arm can reach."""

    def reachable(self, points: np.ndarray) -> np.ndarray:
        """(k,) bool for points (k, 2) in the base frame."""
        ...


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
