"""Exact planar collision tests between oriented boxes, discs and the pusher's ball path.

This is the planner's inner loop: a push is checked against every other footprint at several
poses along its way, thousands of times a second. Each batch is a few dozen small arrays, too
small for numpy to pay off (a vectorised version spent most of its time in per-call overhead),
so the tests are scalar loops compiled by numba (kernels.py), with early exits:

* box-box: separating-axis test on the four edge normals (exact for overlap); when separated,
  the distance is the smallest corner-to-box distance of either box (exact for disjoint convex
  polygons, whose closest points always include a vertex);
* box-disc: signed distance of the disc centre to the box, minus the radius;
* disc-disc: centre distance minus the radii;
* ball path (a capsule: segment swept by the ball) against boxes and discs.

Signed distances are positive when separated (the true Euclidean gap) and <= 0 when overlapping
(for box-box the largest separating-axis gap, a continuous penetration measure). The table bound
(Eq. 4) is that every footprint lies inside the table rectangle. Pairs whose bounding circles are
farther apart than the required gap skip the exact test.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tsrrt_common.scenario import ObjectSpec
from tsrrt_planner.kernels import (
    ball_paths_clear,
    constraint_jacobian,
    constraint_rows,
    pair_distances,
    swept_poses_clear,
)
from tsrrt_planner.objectives import ObjectSet, axis_aligned_half_extents


class Shapes:
    """Footprints of movable objects followed by static obstacles, as flat arrays.

    Rows 0..n-1 are the movable objects (state order), rows n.. the obstacles.
    """

    def __init__(self, objects: ObjectSet, obstacles: Sequence[ObjectSpec]) -> None:
        self.half = np.concatenate([
            np.column_stack([objects.half_length, objects.half_width]),
            np.array([[o.length / 2.0, o.width / 2.0] for o in obstacles]).reshape(-1, 2)])
        self.is_disc = np.concatenate([objects.is_disc,
                                       np.array([o.shape != "box" for o in obstacles], bool)])
        self.obstacle_poses = np.array([o.pose.as_array() for o in obstacles]).reshape(-1, 3)
        # radius of the smallest centred circle around each footprint, for cheap rejections
        self.bounding_radius = np.where(self.is_disc, self.half[:, 0],
                                        np.hypot(self.half[:, 0], self.half[:, 1]))

    def pair_signed_distance(self, rows_a: np.ndarray, poses_a: np.ndarray, rows_b: np.ndarray,
                             poses_b: np.ndarray) -> np.ndarray:
        """Signed distance (P,) between shapes rows_a (P,) at poses_a (P, 3) and rows_b/poses_b."""
        return pair_distances(np.asarray(rows_a, np.int64), _floats(poses_a),
                               np.asarray(rows_b, np.int64), _floats(poses_b), self.half,
                               self.is_disc)


def _floats(array: np.ndarray) -> np.ndarray:
    """A C-contiguous float64 array, as the kernels' compiled signatures expect."""
    return np.ascontiguousarray(array, dtype=np.float64)


class CollisionChecker:
    """Validity of object states: on the table, no overlaps (with a clearance margin), pusher
    ball path free of other objects.

    Args:
        objects: the movable objects (state order).
        obstacles: static obstacles (their poses are fixed).
        table_bounds: (x_min, y_min, x_max, y_max).
        margin: required gap between any two footprints, metres.
        ball_margin: required gap between the ball surface and objects it must not touch.
    """

    def __init__(self, objects: ObjectSet, obstacles: Sequence[ObjectSpec],
                 table_bounds: Sequence[float], margin: float = 0.005,
                 ball_margin: float = 0.003) -> None:
        self.objects = objects
        self.shapes = Shapes(objects, obstacles)
        self.table_bounds = tuple(float(b) for b in table_bounds)
        self._bounds = np.array(self.table_bounds)
        self.margin = margin
        self.ball_margin = ball_margin
        n, m = len(objects), len(obstacles)
        first, second = np.triu_indices(n, k=1)
        self.pair_first, self.pair_second = first, second
        self.obstacle_object = np.repeat(np.arange(n), m)
        self.obstacle_row = np.tile(np.arange(n, n + m), n)
        self.n, self.m = n, m
        # How far each constraint may be violated (see `tolerate`); zero for a valid start.
        self.pair_allowance = np.zeros((n, n))
        self.obstacle_allowance = np.zeros((n, m))
        self.table_allowance = np.zeros((n, 4))
        # Compile the kernels (or load them from numba's cache) now, not in the first plan.
        no_rows = np.zeros(0, np.int64)
        self.moved_objects_valid(np.zeros((n, 3)), no_rows, np.zeros((0, 3)))
        self.shapes.pair_signed_distance(no_rows, np.zeros((0, 3)), no_rows, np.zeros((0, 3)))
        self.constraint_jacobian(np.zeros((n, 3)))

    def tolerate(self, state: np.ndarray) -> tuple[float, float]:
        """Accept the violations of `state` (n, 3) but no deeper ones.

        An observed start can break the margin (a push left two objects 3 mm apart, perception
        put an edge 1 mm past the table). Planning must still start from it: every constraint
        that `state` violates is relaxed to exactly its value there, so pushes may keep or
        reduce that violation but never deepen it, and every other constraint is unchanged.

        Returns:
            The deepest violation between footprints (margin included) and the largest
            overhang past a table edge, metres.
        """
        values = self.constraint_values(np.asarray(state, dtype=float))
        deficit = np.maximum(-values, 0.0)
        n_pairs, n_obstacle = len(self.pair_first), len(self.obstacle_object)
        self.pair_allowance[:] = 0.0
        self.pair_allowance[self.pair_first, self.pair_second] = deficit[:n_pairs]
        self.pair_allowance = np.maximum(self.pair_allowance, self.pair_allowance.T)
        self.obstacle_allowance[:] = deficit[n_pairs:n_pairs + n_obstacle].reshape(
            self.n, self.m)
        self.table_allowance[:] = deficit[n_pairs + n_obstacle:].reshape(self.n, 4)
        return (float(deficit[:n_pairs + n_obstacle].max(initial=0.0)),
                float(self.table_allowance.max(initial=0.0)))

    # ------------------------------------------------------------------ constraint vector
    def constraint_tables(self) -> tuple:
        """What constraint_rows needs besides the states; built per call, as `tolerate`
        replaces the allowances."""
        return (self.pair_first, self.pair_second,
                self.pair_allowance[self.pair_first, self.pair_second], self.obstacle_object,
                self.obstacle_row, self.obstacle_allowance.ravel(), self.shapes.half,
                self.shapes.is_disc, self.shapes.obstacle_poses, self.margin, self._bounds,
                self.table_allowance)

    def constraint_values(self, state: np.ndarray) -> np.ndarray:
        """All constraints g(state) >= 0 of one state (n, 3): pairs, obstacles, table edges.
        Compiled, as is the Jacobian: DIRECTGD's SLSQP asks for both at every iteration."""
        state = _floats(state)
        return constraint_rows(state, state, self.constraint_tables())

    def constraint_jacobian(self, state: np.ndarray, step: float = 1e-6) -> np.ndarray:
        """d g / d state (C, 3n) by forward differences (constraint_jacobian)."""
        return constraint_jacobian(_floats(state), step, self.constraint_tables())

    # ------------------------------------------------------------------ validity
    def state_valid(self, state: np.ndarray) -> bool:
        """True when every object is on the table and all footprints keep the margin."""
        return bool(np.all(self.constraint_values(np.asarray(state, dtype=float)) >= 0.0))

    def moved_objects_valid(self, parent: np.ndarray, moved: np.ndarray,
                            poses: np.ndarray) -> np.ndarray:
        """Validity (k,) of k candidate states that each differ from `parent` in one object.

        Args:
            parent: (n, 3) state whose other objects stay put.
            moved: (k,) index of the moved object of each candidate.
            poses: (k, 3) new pose of that object.
        """
        return self.swept_valid(parent, moved, poses, np.zeros((len(poses), 3)),
                                np.ones(len(poses), np.int64))

    def swept_valid(self, parent: np.ndarray, moved: np.ndarray, start: np.ndarray,
                    change: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """(k,) validity of k objects moving in straight lines (in x, y, theta) from poses
        `start` (k, 3) by `change` (k, 3), checked at `steps` (k,) evenly spaced poses after the
        start, the end included (a push's path among the other objects)."""
        return swept_poses_clear(
            _floats(parent), np.asarray(moved, np.int64), _floats(start), _floats(change),
            np.asarray(steps, np.int64), *self.pose_tables())

    def pose_tables(self) -> tuple:
        """The arrays kernels.swept_poses_clear takes after the pushes (shapes, obstacles,
        allowances, margin, bounds), also the push checks' (PlanningProblem.check_tables);
        built per call, as `tolerate` replaces the allowances."""
        return (self.shapes.half, self.shapes.is_disc, self.shapes.bounding_radius,
                self.shapes.obstacle_poses, self.pair_allowance, self.obstacle_allowance,
                self.margin, self._bounds, self.table_allowance)

    def table_clearances_rows(self, rows: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """Table clearances (k, 4) of objects `rows` (k,) at poses (k, 3)."""
        x_min, y_min, x_max, y_max = self.table_bounds
        hx, hy, _, _ = axis_aligned_half_extents(poses[:, 2], self.objects.half_length[rows],
                                                 self.objects.half_width[rows],
                                                 self.objects.is_disc[rows])
        x, y = poses[:, 0], poses[:, 1]
        return np.stack([x - hx - x_min, x_max - x - hx, y - hy - y_min, y_max - y - hy], -1)

    def on_table_rows(self, rows: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """(k,) True where object rows[i] at poses[i] (k, 3) stays on the table, as the push
        checks count it (its tolerated overhang included): a cheap test that needs no
        other object."""
        clearances = self.table_clearances_rows(rows, poses) + self.table_allowance[rows]
        return (clearances >= 0.0).all(axis=-1)

    def ball_paths_clear(self, parent: np.ndarray, pushed: np.ndarray, start: np.ndarray,
                         end: np.ndarray, radius: float) -> np.ndarray:
        """(k,) True when the ball (radius) moving start->end (k, 2) keeps ball_margin from every
        object except the pushed one (k,) and from the obstacles, in state `parent` (n, 3)."""
        return ball_paths_clear(_floats(parent), np.asarray(pushed, np.int64), _floats(start),
                                 _floats(end), self.shapes.half, self.shapes.is_disc,
                                 self.shapes.bounding_radius, self.shapes.obstacle_poses,
                                 radius + self.ball_margin)
