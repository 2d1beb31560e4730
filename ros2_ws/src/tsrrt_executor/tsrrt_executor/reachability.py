"""Where on the table the Panda can push: a shipped grid of reachable ball positions.

A table point (x, y) is reachable when Pinocchio IK (inverse_kinematics.PusherIK, cold-started
from the ready posture) puts the ball centre above it with the tool pointing down at every height
in REACH_HEIGHTS (the lowest pushing height up to a safe transit height), with every joint at
least JOINT_LIMIT_MARGIN inside its limits. A point between grid nodes counts only if all four
surrounding nodes do. Two sets are kept:

- *reachable* (`is_reachable`, what the planner plans with) erodes the IK set: a node counts
  only if every node within REACH_MARGIN of it is reachable too, so a planned push keeps room
  for the few millimetres (up to centimetres after a slip) by which the object will really be
  elsewhere when the push is executed;
- *executable* (`is_executable`, what the executor checks before moving) is the IK set itself:
  that room is for the executor to use. Refusing a planned push because the observed pose is
  a few millimetres off the predicted one, well inside the margin, throws the plan away for
  nothing (a replan, and near the reach limit maybe no push left for that object).

The grid is computed by `python -m tsrrt_executor.reachability --write` (about 25 s) and
shipped as `reachability_grid.yaml` beside this module; it records a digest of the kinematics
(joints, origins, axes, limits) of the URDF it was computed from, and loading it against another
robot description raises ReachabilityMapError.

The workspace this yields (grid x in [0.10, 0.85], y in [-0.55, 0.55]; outside it nothing is
reachable): 93 % of the table top (x in [0.28, 0.62], y in [-0.26, 0.26]). Straight ahead the
ball reaches x from 0.33 to 0.77 m; the near limit comes from the elbow (joint 4) reaching its
lower limit when folding the tool down close to the base, so it recedes sideways (x >= 0.31 at
|y| = 0.1, x >= 0.25 at |y| = 0.2). Pushes on the near table edge from the robot's side are
therefore unreachable and the planner must use another primitive. The issue author measured all
six approach points reachable for object centres within about 0.56 m of the base; this map is
checked per push (`push_is_executable`) instead of by a radius.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
import yaml

from tsrrt_common.robot_model import pusher_urdf_path
from tsrrt_executor.errors import ExecutorError, IKError, UnreachableError
from tsrrt_executor.push_primitives import PushGeometry, ball_path_points

GRID_FILE = Path(__file__).with_name("reachability_grid.yaml")
GRID_X = (0.10, 0.85)              # metres, base frame
GRID_Y = (-0.55, 0.55)
GRID_STEP = 0.01
# Ball-centre heights above the table (world z with the table at 0) checked at each grid point:
# the lowest pushing height (ball radius + table clearance), the highest, and transit heights.
REACH_HEIGHTS = (0.014, 0.03, 0.06, 0.10, 0.15, 0.20)
REACH_MARGIN = 0.02                # metres of erosion ("reachable with margin")
JOINT_LIMIT_MARGIN = 0.05          # rad a solution must keep from every joint limit
GRID_IK_ITERATIONS = 100


class ReachabilityMapError(ExecutorError):
    """The shipped reachability grid is missing, malformed, or computed for another robot."""


@dataclass(frozen=True)
class ReachabilityMap:
    """Boolean grids over the table plane; grid[i, j] is (x0 + j * step, y0 + i * step)."""

    x0: float
    y0: float
    step: float
    heights: tuple[float, ...]
    grid: np.ndarray        # (ny, nx) bool, reachable with margin (eroded)
    ik_grid: np.ndarray     # (ny, nx) bool, IK solutions found (executable)

    def is_reachable(self, points_xy: np.ndarray) -> np.ndarray:
        """Reachable-with-margin flags (N,) for points (N, 2); False outside the grid."""
        return self._lookup(self._cells[0], points_xy)

    def is_executable(self, points_xy: np.ndarray) -> np.ndarray:
        """Flags (N,) for points (N, 2) the IK reaches, margin or not; False outside the grid."""
        return self._lookup(self._cells[1], points_xy)

    @cached_property
    def _cells(self) -> tuple[np.ndarray, np.ndarray]:
        """Per grid cell (ny - 1, nx - 1), of `grid` and of `ik_grid`: a point in the cell counts
        only if all four grid nodes around it do. Precomputed: the planner looks up thousands of
        points a second."""
        return tuple(grid[:-1, :-1] & grid[:-1, 1:] & grid[1:, :-1] & grid[1:, 1:]
                     for grid in (self.grid, self.ik_grid))

    def _lookup(self, cells: np.ndarray, points_xy: np.ndarray) -> np.ndarray:
        points = np.asarray(points_xy, dtype=float).reshape(-1, 2)
        col = np.floor((points[:, 0] - self.x0) / self.step + 1e-9)
        row = np.floor((points[:, 1] - self.y0) / self.step + 1e-9)
        inside = (col >= 0) & (col < cells.shape[1]) & (row >= 0) & (row < cells.shape[0])
        result = np.zeros(len(points), bool)
        result[inside] = cells[row[inside].astype(int), col[inside].astype(int)]
        return result

    def reachable(self, points_xy: np.ndarray) -> np.ndarray:
        """Same as is_reachable; the name tsrrt_planner's Reachability protocol expects."""
        return self.is_reachable(points_xy)

    def reach_cells(self) -> tuple[float, float, float, np.ndarray]:
        """(x0, y0, step, cells) of is_reachable, for lookups compiled elsewhere (the planner's
        GridReachability): a point is reachable iff it lies in the grid and
        cells[floor((y - y0) / step + 1e-9), floor((x - x0) / step + 1e-9)]."""
        return self.x0, self.y0, self.step, self._cells[0]

    def covers_height(self, z: float, table_height: float = 0.0) -> bool:
        return min(self.heights) - 1e-9 <= z - table_height <= max(self.heights) + 1e-9


def kinematics_digest() -> str:
    """Digest of the pusher URDF's joints (origins, axes, limits), independent of mesh paths."""
    root = ET.parse(pusher_urdf_path()).getroot()
    parts = []
    for joint in root.iter("joint"):
        parts.append(repr((joint.get("name"), joint.get("type"),
                           *(sorted(child.attrib.items()) for child in joint))))
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def compute_reachable_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw reachability (ny, nx) at the grid nodes (before erosion), with the node coordinates."""
    from tsrrt_executor.inverse_kinematics import IKSettings, PusherIK

    ik = PusherIK(settings=IKSettings(max_iterations=GRID_IK_ITERATIONS))
    xs = np.round(np.arange(GRID_X[0], GRID_X[1] + GRID_STEP / 2, GRID_STEP), 6)
    ys = np.round(np.arange(GRID_Y[0], GRID_Y[1] + GRID_STEP / 2, GRID_STEP), 6)
    reachable = np.zeros((ys.size, xs.size), dtype=bool)
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            reachable[i, j] = _reachable_at(ik, x, y)
    return reachable, xs, ys


def _reachable_at(ik, x: float, y: float) -> bool:
    for z in REACH_HEIGHTS:
        try:
            q, _ = ik.solve(np.array([x, y, z]))
        except IKError:
            return False
        inside = np.minimum(q - ik.model.lowerPositionLimit, ik.model.upperPositionLimit - q)
        if inside.min() < JOINT_LIMIT_MARGIN:
            return False
    return True


def erode(reachable: np.ndarray, step: float, margin: float) -> np.ndarray:
    """Keep a node only if every node within `margin` (a disc) is reachable; (ny, nx) bool."""
    radius = int(math.ceil(margin / step - 1e-9))
    padded = np.pad(reachable, radius, constant_values=False)
    result = reachable.copy()
    ny, nx = reachable.shape
    for di in range(-radius, radius + 1):
        for dj in range(-radius, radius + 1):
            if (di * di + dj * dj) * step * step <= margin * margin + 1e-12:
                result &= padded[radius + di:radius + di + ny, radius + dj:radius + dj + nx]
    return result


def write_grid(path: Path = GRID_FILE) -> ReachabilityMap:
    """Compute the grid with IK and write the YAML file shipped with the package."""
    raw, xs, ys = compute_reachable_grid()
    rows = ["".join("#" if v else "." for v in row) for row in raw[::-1]]
    document = {
        "description": "Ball positions the IK reaches with the tool pointing down (before the"
                       " margin's erosion, which is done on loading). Generated by `python -m"
                       " tsrrt_executor.reachability --write`; do not edit. Rows from y max"
                       " (first) to y min (last); '#' reachable.",
        "kinematics_sha256": kinematics_digest(),
        "x0": float(xs[0]), "y0": float(ys[0]), "step": GRID_STEP,
        "nx": int(xs.size), "ny": int(ys.size),
        "heights": list(REACH_HEIGHTS), "margin": REACH_MARGIN,
        "joint_limit_margin": JOINT_LIMIT_MARGIN,
        "rows": rows,
    }
    path.write_text(yaml.safe_dump(document, sort_keys=False, width=1000))
    return ReachabilityMap(float(xs[0]), float(ys[0]), GRID_STEP, REACH_HEIGHTS,
                           erode(raw, GRID_STEP, REACH_MARGIN), raw)


def load_grid(path: Path = GRID_FILE, check_urdf: bool = True) -> ReachabilityMap:
    """Read a grid file; raises ReachabilityMapError if malformed or for another URDF."""
    if not path.is_file():
        raise ReachabilityMapError(f"{path}: reachability grid missing; generate it with "
                                   "`python -m tsrrt_executor.reachability --write`")
    try:
        document = yaml.safe_load(path.read_text())
        rows = document["rows"]
        reachable = np.array([[c == "#" for c in row] for row in rows[::-1]], dtype=bool)
        step, margin = float(document["step"]), float(document["margin"])
        grid = ReachabilityMap(float(document["x0"]), float(document["y0"]), step,
                               tuple(document["heights"]), erode(reachable, step, margin),
                               reachable)
        shape_ok = reachable.shape == (int(document["ny"]), int(document["nx"]))
    except (KeyError, TypeError, ValueError, yaml.YAMLError) as error:
        raise ReachabilityMapError(f"{path}: malformed reachability grid ({error})") from None
    if not shape_ok:
        raise ReachabilityMapError(f"{path}: rows do not match nx x ny")
    if check_urdf and document.get("kinematics_sha256") != kinematics_digest():
        raise ReachabilityMapError(
            f"{path}: computed for another robot description (kinematics_sha256 "
            f"{document.get('kinematics_sha256')} != {kinematics_digest()}); regenerate it with "
            "`python -m tsrrt_executor.reachability --write`")
    return grid


@lru_cache(maxsize=1)
def default_map() -> ReachabilityMap:
    """The shipped grid, loaded once."""
    return load_grid()


def is_reachable(points_xy: np.ndarray) -> np.ndarray:
    """Reachable-with-margin flags (N,) for ball-centre table points (N, 2), base frame."""
    return default_map().is_reachable(points_xy)


def push_is_executable(geometry: PushGeometry, table_height: float = 0.0) -> bool:
    """True when the IK reaches every ball position of the push with the tool pointing down.

    The executor's check: the planner's margin (`is_reachable`) is room for the executor.

    Checks the xy of the approach point (descent column), the push to its end and the back-off
    (all on one segment, sampled every 5 mm), at the push and safe heights. The transit at the
    safe height is a joint move; primitive_plan checks that it stays high.

    Raises:
        UnreachableError: the push or safe height is outside the heights the grid verified.
    """
    grid = default_map()
    for name, z in (("push height", geometry.push_z), ("safe height", geometry.safe_z)):
        if not grid.covers_height(z, table_height):
            raise UnreachableError(
                f"{name} {z - table_height:.3f} m above the table is outside the heights the "
                f"reachability grid verified: [{min(grid.heights)}, {max(grid.heights)}] m")
    return bool(grid.is_executable(ball_path_points(geometry)).all())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true",
                        help=f"recompute the grid with IK and write {GRID_FILE.name}")
    args = parser.parse_args(argv)
    if args.write:
        start = time.perf_counter()
        grid = write_grid()
        print(f"wrote {GRID_FILE} in {time.perf_counter() - start:.1f} s")
    else:
        grid = load_grid()
    print(f"{int(grid.grid.sum())} of {grid.grid.size} grid points reachable")
    for radius in (0.3, 0.5, 0.56, 0.6, 0.7, 0.8):
        angles = np.linspace(-math.pi / 2, math.pi / 2, 181)
        ring = radius * np.column_stack([np.cos(angles), np.sin(angles)])
        print(f"  radius {radius:.2f} m: {grid.is_reachable(ring).mean() * 100:5.1f} % of the "
              "front half-circle reachable")
    return 0


if __name__ == "__main__":
    sys.exit(main())
