"""Exact planar collision tests between oriented boxes, discs and the pusher's ball path.

This is the planner's inner loop, so everything works on arrays of pairs at once:

* box-box: separating-axis test on the four edge normals (exact for overlap); when separated,
  the distance is the smallest corner-to-box distance of either box (exact for disjoint convex
  polygons, whose closest points always include a vertex);
* box-disc: signed distance of the disc centre to the box, minus the radius;
* disc-disc: centre distance minus the radii;
* ball path (a capsule: segment swept by the ball) against boxes and discs.

Signed distances are positive when separated (the true Euclidean gap) and <= 0 when overlapping
(for box-box the largest separating-axis gap, a continuous penetration measure). The table bound
(Eq. 4) is that every footprint lies inside the table rectangle.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tsrrt_common.scenario import ObjectSpec
from tsrrt_planner.objectives import ObjectSet, axis_aligned_half_extents

_BIG = 1e9


def _rotation(theta: np.ndarray) -> np.ndarray:
    """(..., 2, 2) rotation matrices, columns = the frame's x and y axes in the world."""
    c, s = np.cos(theta), np.sin(theta)
    rotation = np.empty((*np.shape(theta), 2, 2))
    rotation[..., 0, 0], rotation[..., 0, 1] = c, -s
    rotation[..., 1, 0], rotation[..., 1, 1] = s, c
    return rotation


def _to_frame(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """World points (P, m, 2) into the frames of poses (P, 3)."""
    rotation = _rotation(pose[:, 2])
    return np.einsum("pmi,pij->pmj", points - pose[:, None, :2], rotation)


def point_box_signed_distance(points: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Signed distance of points (P, m, 2), given in a box's frame, to boxes with half sizes
    (P, 2)."""
    q = np.abs(points) - half[:, None, :]
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return outside + inside


def _corners(pose: np.ndarray, half: np.ndarray) -> np.ndarray:
    """World corners (P, 4, 2) of boxes with poses (P, 3) and half sizes (P, 2)."""
    signs = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    local = signs[None] * half[:, None, :]
    return np.einsum("pij,pmj->pmi", _rotation(pose[:, 2]), local) + pose[:, None, :2]


def box_box_signed_distance(pose_a: np.ndarray, half_a: np.ndarray, pose_b: np.ndarray,
                            half_b: np.ndarray) -> np.ndarray:
    """Signed distance (P,) between boxes with poses (P, 3) and half sizes (P, 2)."""
    axes_a = _rotation(pose_a[:, 2])  # columns are the box axes
    axes_b = _rotation(pose_b[:, 2])
    axes = np.concatenate([np.swapaxes(axes_a, 1, 2), np.swapaxes(axes_b, 1, 2)], axis=1)
    centre = pose_b[:, :2] - pose_a[:, :2]
    radius_a = (np.abs(np.einsum("pkd,pdj->pkj", axes, axes_a)) * half_a[:, None, :]).sum(-1)
    radius_b = (np.abs(np.einsum("pkd,pdj->pkj", axes, axes_b)) * half_b[:, None, :]).sum(-1)
    gap = np.abs(np.einsum("pkd,pd->pk", axes, centre)) - radius_a - radius_b
    separating = gap.max(axis=1)
    corner_a_to_b = point_box_signed_distance(_to_frame(_corners(pose_a, half_a), pose_b), half_b)
    corner_b_to_a = point_box_signed_distance(_to_frame(_corners(pose_b, half_b), pose_a), half_a)
    corner = np.minimum(corner_a_to_b.min(axis=1), corner_b_to_a.min(axis=1))
    return np.where(separating > 0.0, corner, separating)


def box_disc_signed_distance(pose_box: np.ndarray, half_box: np.ndarray, centre: np.ndarray,
                             radius: np.ndarray) -> np.ndarray:
    """Signed distance (P,) between boxes (P, 3)/(P, 2) and discs with centres (P, 2)."""
    local = _to_frame(centre[:, None, :], pose_box)
    return point_box_signed_distance(local, half_box)[:, 0] - radius


def segment_box_distance(start: np.ndarray, end: np.ndarray, pose_box: np.ndarray,
                         half_box: np.ndarray) -> np.ndarray:
    """Distance (P,) from segments start-end (P, 2) to boxes; 0 when they intersect."""
    ends = _to_frame(np.stack([start, end], axis=1), pose_box)  # (P, 2, 2)
    p0, direction = ends[:, 0], ends[:, 1] - ends[:, 0]
    endpoint = np.maximum(point_box_signed_distance(ends, half_box).min(axis=1), 0.0)
    corners = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])[None] * half_box[
        :, None, :]
    length_sq = np.maximum((direction**2).sum(-1), 1e-18)
    t = np.clip(np.einsum("pmd,pd->pm", corners - p0[:, None], direction) / length_sq[:, None],
                0.0, 1.0)
    nearest = p0[:, None] + t[..., None] * direction[:, None]
    corner = np.linalg.norm(corners - nearest, axis=-1).min(axis=1)
    # Slab test: does the segment pass through the box?
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.where(np.abs(direction) > 1e-15, 1.0 / direction, _BIG)
        t1 = (-half_box - p0) * inverse
        t2 = (half_box - p0) * inverse
    inside_slab = np.abs(p0) <= half_box
    t_low = np.where(np.abs(direction) > 1e-15, np.minimum(t1, t2),
                     np.where(inside_slab, -_BIG, _BIG))
    t_high = np.where(np.abs(direction) > 1e-15, np.maximum(t1, t2),
                      np.where(inside_slab, _BIG, -_BIG))
    enter, leave = t_low.max(axis=1), t_high.min(axis=1)
    crosses = (enter <= leave) & (leave >= 0.0) & (enter <= 1.0)
    return np.where(crosses, 0.0, np.minimum(endpoint, corner))


def segment_point_distance(start: np.ndarray, end: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Distance (P,) from segments (P, 2)-(P, 2) to points (P, 2)."""
    direction = end - start
    length_sq = np.maximum((direction**2).sum(-1), 1e-18)
    t = np.clip(((point - start) * direction).sum(-1) / length_sq, 0.0, 1.0)
    return np.linalg.norm(start + t[:, None] * direction - point, axis=-1)


class Shapes:
    """Footprints of movable objects followed by static obstacles, as flat arrays.

    Rows 0..n-1 are the movable objects (state order), rows n.. the obstacles.
    """

    def __init__(self, objects: ObjectSet, obstacles: Sequence[ObjectSpec]) -> None:
        self.n_movable = len(objects)
        self.half = np.concatenate([
            np.column_stack([objects.half_length, objects.half_width]),
            np.array([[o.length / 2.0, o.width / 2.0] for o in obstacles]).reshape(-1, 2)])
        self.is_disc = np.concatenate([objects.is_disc,
                                       np.array([o.shape != "box" for o in obstacles], bool)])
        self.obstacle_poses = np.array([o.pose.as_array() for o in obstacles]).reshape(-1, 3)
        # radius of the smallest centred circle around each footprint, for cheap rejections
        self.bounding_radius = np.where(self.is_disc, self.half[:, 0],
                                        np.hypot(self.half[:, 0], self.half[:, 1]))

    def pairs_apart(self, rows_a: np.ndarray, centres_a: np.ndarray, rows_b: np.ndarray,
                    centres_b: np.ndarray, gap: float) -> np.ndarray:
        """(P,) True where the bounding circles alone prove the footprints at least `gap`
        apart, so the exact test can be skipped."""
        reach = self.bounding_radius[rows_a] + self.bounding_radius[rows_b] + gap
        return ((centres_a - centres_b) ** 2).sum(-1) > reach**2

    def pair_signed_distance(self, rows_a: np.ndarray, poses_a: np.ndarray, rows_b: np.ndarray,
                             poses_b: np.ndarray) -> np.ndarray:
        """Signed distance (P,) between shapes rows_a (P,) at poses_a (P, 3) and rows_b/poses_b."""
        result = np.empty(len(rows_a))
        disc_a, disc_b = self.is_disc[rows_a], self.is_disc[rows_b]
        half_a, half_b = self.half[rows_a], self.half[rows_b]
        both_box = ~disc_a & ~disc_b
        if both_box.any():
            result[both_box] = box_box_signed_distance(poses_a[both_box], half_a[both_box],
                                                       poses_b[both_box], half_b[both_box])
        both_disc = disc_a & disc_b
        if both_disc.any():
            result[both_disc] = (np.linalg.norm(poses_a[both_disc, :2] - poses_b[both_disc, :2],
                                                axis=-1)
                                 - half_a[both_disc, 0] - half_b[both_disc, 0])
        box_first = ~disc_a & disc_b
        if box_first.any():
            result[box_first] = box_disc_signed_distance(
                poses_a[box_first], half_a[box_first], poses_b[box_first, :2],
                half_b[box_first, 0])
        disc_first = disc_a & ~disc_b
        if disc_first.any():
            result[disc_first] = box_disc_signed_distance(
                poses_b[disc_first], half_b[disc_first], poses_a[disc_first, :2],
                half_a[disc_first, 0])
        return result

    def segment_distance(self, start: np.ndarray, end: np.ndarray, rows: np.ndarray,
                         poses: np.ndarray) -> np.ndarray:
        """Distance (P,) from segments (P, 2)-(P, 2) to shapes rows (P,) at poses (P, 3)."""
        result = np.empty(len(rows))
        disc = self.is_disc[rows]
        if disc.any():
            result[disc] = np.maximum(segment_point_distance(
                start[disc], end[disc], poses[disc, :2]) - self.half[rows[disc], 0], 0.0)
        box = ~disc
        if box.any():
            result[box] = segment_box_distance(start[box], end[box], poses[box],
                                               self.half[rows[box]])
        return result


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
    def table_clearances(self, states: np.ndarray) -> np.ndarray:
        """Clearances (..., n, 4) of every footprint to x_min, x_max, y_min, y_max (>= 0 valid)."""
        x_min, y_min, x_max, y_max = self.table_bounds
        hx, hy, _, _ = axis_aligned_half_extents(states[..., 2], self.objects.half_length,
                                                 self.objects.half_width, self.objects.is_disc)
        x, y = states[..., 0], states[..., 1]
        return np.stack([x - hx - x_min, x_max - x - hx, y - hy - y_min, y_max - y - hy], -1)

    def constraint_values(self, state: np.ndarray) -> np.ndarray:
        """All constraints g(state) >= 0 of one state (n, 3): pairs, obstacles, table edges."""
        return self._constraints(state[None], state[None])[0]

    def _constraints(self, first: np.ndarray, second: np.ndarray) -> np.ndarray:
        """Constraints (B, C) where pair constraints take their first member from states
        first (B, n, 3) and their second from second (B, n, 3); obstacle and table constraints
        use `first`. Batched so that one call serves a whole Jacobian."""
        batch = len(first)
        parts = []
        if len(self.pair_first):
            rows_a = np.tile(self.pair_first, batch)
            rows_b = np.tile(self.pair_second, batch)
            poses_a = first[:, self.pair_first].reshape(-1, 3)
            poses_b = second[:, self.pair_second].reshape(-1, 3)
            parts.append(self.shapes.pair_signed_distance(rows_a, poses_a, rows_b, poses_b)
                         .reshape(batch, -1) - self.margin
                         + self.pair_allowance[self.pair_first, self.pair_second])
        if self.m:
            rows_o = np.tile(self.obstacle_row, batch)
            parts.append(self.shapes.pair_signed_distance(
                np.tile(self.obstacle_object, batch),
                first[:, self.obstacle_object].reshape(-1, 3), rows_o,
                self.shapes.obstacle_poses[rows_o - self.n]).reshape(batch, -1) - self.margin
                + self.obstacle_allowance.ravel())
        parts.append((self.table_clearances(first) + self.table_allowance).reshape(batch, -1))
        return np.concatenate(parts, axis=1)

    def constraint_jacobian(self, state: np.ndarray, step: float = 1e-6) -> np.ndarray:
        """d g / d state (C, 3n) by forward differences. Each constraint depends on one or two
        objects, so moving every object at once along one coordinate - first members of pairs
        only, then second members only - gives all columns from seven batched evaluations."""
        n = self.n
        n_pairs, n_obst = len(self.pair_first), len(self.obstacle_object)
        shifted = np.repeat(state[None], 3, axis=0)
        shifted[np.arange(3), :, np.arange(3)] += step
        base = np.repeat(state[None], 3, axis=0)
        values = self._constraints(np.concatenate([state[None], shifted, base]),
                                   np.concatenate([state[None], base, shifted]))
        reference = values[0]
        moved_first = (values[1:4] - reference) / step   # (3, C)
        moved_second = (values[4:7] - reference) / step
        jacobian = np.zeros((len(reference), 3 * n))
        rows = np.arange(n_pairs)
        for d in range(3):
            jacobian[rows, 3 * self.pair_first + d] = moved_first[d, rows]
            jacobian[rows, 3 * self.pair_second + d] = moved_second[d, rows]
            other = np.arange(n_pairs, n_pairs + n_obst)
            jacobian[other, 3 * self.obstacle_object + d] = moved_first[d, other]
            table = np.arange(n_pairs + n_obst, n_pairs + n_obst + 4 * n)
            jacobian[table, 3 * np.repeat(np.arange(n), 4) + d] = moved_first[d, table]
        return jacobian

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
        k, n = len(moved), self.n
        table = (self.table_clearances_rows(moved, poses) + self.table_allowance[moved]).min(
            axis=1) >= 0.0
        others = np.broadcast_to(np.arange(n), (k, n))
        keep = others != moved[:, None]
        cand = np.broadcast_to(np.arange(k)[:, None], (k, n))[keep]
        rows_b = others[keep]
        ok = table.copy()
        if n > 1:
            ok &= self._moved_pairs_clear(k, cand, moved[cand], poses[cand], rows_b,
                                          parent[rows_b], self.pair_allowance[moved[cand], rows_b])
        if self.m:
            cand_o = np.repeat(np.arange(k), self.m)
            rows_o = np.tile(np.arange(n, n + self.m), k)
            ok &= self._moved_pairs_clear(k, cand_o, moved[cand_o], poses[cand_o], rows_o,
                                          self.shapes.obstacle_poses[rows_o - n],
                                          self.obstacle_allowance[moved[cand_o], rows_o - n])
        return ok

    def _moved_pairs_clear(self, k: int, cand: np.ndarray, rows_a: np.ndarray,
                           poses_a: np.ndarray, rows_b: np.ndarray, poses_b: np.ndarray,
                           allowance: np.ndarray) -> np.ndarray:
        """(k,) True for candidates whose pairs (cand (P,) -> candidate) all keep the margin
        less `allowance` (P,); exact tests only for pairs the bounding circles cannot clear."""
        near = np.nonzero(~self.shapes.pairs_apart(rows_a, poses_a[:, :2], rows_b,
                                                   poses_b[:, :2], self.margin))[0]
        if len(near) == 0:
            return np.ones(k, bool)
        gap = self.shapes.pair_signed_distance(rows_a[near], poses_a[near], rows_b[near],
                                               poses_b[near])
        blocked = gap < self.margin - allowance[near]
        return np.bincount(cand[near], weights=blocked, minlength=k) == 0

    def table_clearances_rows(self, rows: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """Table clearances (k, 4) of objects `rows` (k,) at poses (k, 3)."""
        x_min, y_min, x_max, y_max = self.table_bounds
        hx, hy, _, _ = axis_aligned_half_extents(poses[:, 2], self.objects.half_length[rows],
                                                 self.objects.half_width[rows],
                                                 self.objects.is_disc[rows])
        x, y = poses[:, 0], poses[:, 1]
        return np.stack([x - hx - x_min, x_max - x - hx, y - hy - y_min, y_max - y - hy], -1)

    def ball_paths_clear(self, parent: np.ndarray, pushed: np.ndarray, start: np.ndarray,
                         end: np.ndarray, radius: float) -> np.ndarray:
        """(k,) True when the ball (radius) moving start->end (k, 2) keeps ball_margin from every
        object except the pushed one (k,) and from the obstacles, in state `parent` (n, 3)."""
        k, n = len(pushed), self.n
        rows_all = np.arange(n + self.m)
        poses_all = np.concatenate([parent, self.shapes.obstacle_poses])
        keep = rows_all[None, :] != pushed[:, None]
        cand = np.broadcast_to(np.arange(k)[:, None], keep.shape)[keep]
        rows = np.broadcast_to(rows_all, keep.shape)[keep]
        if len(rows) == 0:
            return np.ones(k, bool)
        clearance = radius + self.ball_margin
        # a segment farther from a centre than the bounding circle plus clearance is clear
        centre_gap = segment_point_distance(start[cand], end[cand], poses_all[rows, :2])
        near = np.nonzero(centre_gap <= self.shapes.bounding_radius[rows] + clearance)[0]
        if len(near) == 0:
            return np.ones(k, bool)
        cand, rows = cand[near], rows[near]
        gap = self.shapes.segment_distance(start[cand], end[cand], rows, poses_all[rows])
        return np.bincount(cand, weights=gap < clearance, minlength=k) == 0
