"""Exact planar collision tests between oriented boxes, discs and the pusher's ball path.

This is the planner's inner loop: a push is checked against every other footprint at several
poses along its way, thousands of times a second. Each batch is a few dozen small arrays, too
small for numpy to pay off (a vectorised version spent most of its time in per-call overhead),
so the tests are scalar loops compiled by numba, with early exits:

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

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from tsrrt_common.scenario import ObjectSpec
from tsrrt_planner.objectives import ObjectSet, axis_aligned_half_extents

_BIG = 1e9
_CORNER_SIGNS = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))
# Compiled kernels are cached on disk (numba's __pycache__), so only a first run compiles.
kernel = njit(cache=True, nogil=True)


@kernel
def _point_box(px: float, py: float, hx: float, hy: float) -> float:
    """Signed distance of a point, given in a box's frame, to the box (half sizes hx, hy)."""
    qx, qy = abs(px) - hx, abs(py) - hy
    ox, oy = max(qx, 0.0), max(qy, 0.0)
    return math.sqrt(ox * ox + oy * oy) + min(max(qx, qy), 0.0)


@kernel
def _corners_to_box(x: float, y: float, c: float, s: float, hx: float, hy: float,
                    bx: float, by: float, bc: float, bs: float, bhx: float, bhy: float) -> float:
    """Smallest signed distance of box (x, y, cos, sin; half sizes)'s corners to box b."""
    best = _BIG
    for sx, sy in _CORNER_SIGNS:
        lx, ly = sx * hx, sy * hy
        dx, dy = x + c * lx - s * ly - bx, y + s * lx + c * ly - by
        best = min(best, _point_box(dx * bc + dy * bs, -dx * bs + dy * bc, bhx, bhy))
    return best


@kernel
def _box_box(ax: float, ay: float, at: float, ahx: float, ahy: float,
             bx: float, by: float, bt: float, bhx: float, bhy: float) -> float:
    return _box_box_turned(ax, ay, math.cos(at), math.sin(at), ahx, ahy,
                           bx, by, math.cos(bt), math.sin(bt), bhx, bhy)


@kernel
def _box_box_turned(ax: float, ay: float, ac: float, as_: float, ahx: float, ahy: float,
                    bx: float, by: float, bc: float, bs: float, bhx: float, bhy: float
                    ) -> float:
    """_box_box with the headings given by their cosines and sines."""
    dx, dy = bx - ax, by - ay
    # Relative rotation: the projections of one box's axes on the other's.
    cc, cs = abs(ac * bc + as_ * bs), abs(ac * bs - as_ * bc)
    separating = max(abs(dx * ac + dy * as_) - ahx - (cc * bhx + cs * bhy),
                     abs(-dx * as_ + dy * ac) - ahy - (cs * bhx + cc * bhy),
                     abs(dx * bc + dy * bs) - bhx - (cc * ahx + cs * ahy),
                     abs(-dx * bs + dy * bc) - bhy - (cs * ahx + cc * ahy))
    if separating <= 0.0:
        return separating
    return min(_corners_to_box(ax, ay, ac, as_, ahx, ahy, bx, by, bc, bs, bhx, bhy),
               _corners_to_box(bx, by, bc, bs, bhx, bhy, ax, ay, ac, as_, ahx, ahy))


@kernel
def _box_disc(x: float, y: float, t: float, hx: float, hy: float, cx: float, cy: float,
              radius: float) -> float:
    return _box_disc_turned(x, y, math.cos(t), math.sin(t), hx, hy, cx, cy, radius)


@kernel
def _box_disc_turned(x: float, y: float, c: float, s: float, hx: float, hy: float, cx: float,
                     cy: float, radius: float) -> float:
    """_box_disc with the box's heading given by its cosine and sine."""
    dx, dy = cx - x, cy - y
    return _point_box(dx * c + dy * s, -dx * s + dy * c, hx, hy) - radius


@kernel
def _footprint_distance(ax: float, ay: float, ac: float, as_: float, ahx: float, ahy: float,
                        disc_a: bool, bx: float, by: float, bc: float, bs: float, bhx: float,
                        bhy: float, disc_b: bool) -> float:
    """footprint_signed_distance on scalars, headings as cosines and sines: the pose checks
    pass no array views and turn each heading once."""
    if disc_a and disc_b:
        return math.hypot(ax - bx, ay - by) - ahx - bhx
    if disc_b:
        return _box_disc_turned(ax, ay, ac, as_, ahx, ahy, bx, by, bhx)
    if disc_a:
        return _box_disc_turned(bx, by, bc, bs, bhx, bhy, ax, ay, ahx)
    return _box_box_turned(ax, ay, ac, as_, ahx, ahy, bx, by, bc, bs, bhx, bhy)


@kernel
def footprint_signed_distance(pose_a: np.ndarray, half_a: np.ndarray, disc_a: bool,
                              pose_b: np.ndarray, half_b: np.ndarray, disc_b: bool) -> float:
    """Signed distance between footprints at poses (3,) with half sizes (2,) (a disc's radius
    is half[0])."""
    return _footprint_distance(pose_a[0], pose_a[1], math.cos(pose_a[2]), math.sin(pose_a[2]),
                               half_a[0], half_a[1], disc_a, pose_b[0], pose_b[1],
                               math.cos(pose_b[2]), math.sin(pose_b[2]), half_b[0], half_b[1],
                               disc_b)


@kernel
def _segment_point(sx: float, sy: float, ex: float, ey: float, px: float, py: float) -> float:
    dx, dy = ex - sx, ey - sy
    t = min(max(((px - sx) * dx + (py - sy) * dy) / max(dx * dx + dy * dy, 1e-18), 0.0), 1.0)
    return math.hypot(sx + t * dx - px, sy + t * dy - py)


@kernel
def _slab(p: float, d: float, h: float) -> tuple[float, float]:
    """Parameter interval in which the line p + t d lies within [-h, h]."""
    if abs(d) > 1e-15:
        t1, t2 = (-h - p) / d, (h - p) / d
        return min(t1, t2), max(t1, t2)
    return (-_BIG, _BIG) if abs(p) <= h else (_BIG, -_BIG)


@kernel
def _segment_box(sx: float, sy: float, ex: float, ey: float, x: float, y: float, c: float,
                 s: float, hx: float, hy: float) -> float:
    """Distance from segment s-e to a box (heading as cosine c and sine s); 0 when they
    intersect."""
    p0x, p0y = (sx - x) * c + (sy - y) * s, -(sx - x) * s + (sy - y) * c
    p1x, p1y = (ex - x) * c + (ey - y) * s, -(ex - x) * s + (ey - y) * c
    dx, dy = p1x - p0x, p1y - p0y
    low_x, high_x = _slab(p0x, dx, hx)
    low_y, high_y = _slab(p0y, dy, hy)
    enter, leave = max(low_x, low_y), min(high_x, high_y)
    if enter <= leave and leave >= 0.0 and enter <= 1.0:
        return 0.0
    best = max(min(_point_box(p0x, p0y, hx, hy), _point_box(p1x, p1y, hx, hy)), 0.0)
    for sx_, sy_ in _CORNER_SIGNS:
        best = min(best, _segment_point(p0x, p0y, p1x, p1y, sx_ * hx, sy_ * hy))
    return best


@kernel
def segment_footprint_distance(start: np.ndarray, end: np.ndarray, pose: np.ndarray,
                               half: np.ndarray, disc: bool) -> float:
    """Distance from segment start-end (2,) to a footprint; 0 when they intersect."""
    return _segment_footprint(start[0], start[1], end[0], end[1], pose[0], pose[1],
                              math.cos(pose[2]), math.sin(pose[2]), half[0], half[1], disc)


@kernel
def _segment_footprint(sx: float, sy: float, ex: float, ey: float, x: float, y: float,
                       c: float, s: float, hx: float, hy: float, disc: bool) -> float:
    """segment_footprint_distance on scalars, the heading as cosine c and sine s."""
    if disc:
        return max(_segment_point(sx, sy, ex, ey, x, y) - hx, 0.0)
    return _segment_box(sx, sy, ex, ey, x, y, c, s, hx, hy)


@kernel
def _pair_distances(rows_a: np.ndarray, poses_a: np.ndarray, rows_b: np.ndarray,
                    poses_b: np.ndarray, half: np.ndarray, is_disc: np.ndarray) -> np.ndarray:
    result = np.empty(len(rows_a))
    for i in range(len(rows_a)):
        a, b = rows_a[i], rows_b[i]
        result[i] = footprint_signed_distance(poses_a[i], half[a], is_disc[a], poses_b[i],
                                              half[b], is_disc[b])
    return result


@kernel
def headings(parent: np.ndarray, obstacle_poses: np.ndarray) -> np.ndarray:
    """(n + m, 2) cosine and sine of the heading of every object of `parent` (n, 3), then of
    every obstacle: the pose checks turn each neighbour once per batch, not once per test."""
    turned = np.empty((len(parent) + len(obstacle_poses), 2))
    for row in range(len(turned)):
        theta = parent[row, 2] if row < len(parent) else obstacle_poses[row - len(parent), 2]
        turned[row, 0], turned[row, 1] = math.cos(theta), math.sin(theta)
    return turned


@kernel
def _pose_clear(obj: int, x: float, y: float, theta: float, parent: np.ndarray,
                turned: np.ndarray, half: np.ndarray, is_disc: np.ndarray, bounding: np.ndarray,
                obstacle_poses: np.ndarray, pair_allowance: np.ndarray,
                obstacle_allowance: np.ndarray, margin: float, bounds: np.ndarray,
                table_allowance: np.ndarray) -> bool:
    """Object `obj` at (x, y, theta), the others as in `parent` (their `headings` in
    `turned`): on the table and clear of all."""
    c, s = math.cos(theta), math.sin(theta)
    if is_disc[obj]:
        hx = hy = half[obj, 0]
    else:
        hx = abs(c) * half[obj, 0] + abs(s) * half[obj, 1]
        hy = abs(s) * half[obj, 0] + abs(c) * half[obj, 1]
    if (x - hx - bounds[0] + table_allowance[obj, 0] < 0.0
            or bounds[2] - x - hx + table_allowance[obj, 1] < 0.0
            or y - hy - bounds[1] + table_allowance[obj, 2] < 0.0
            or bounds[3] - y - hy + table_allowance[obj, 3] < 0.0):
        return False
    n = len(parent)
    for row in range(n + len(obstacle_poses)):
        if row == obj:
            continue
        if row < n:
            ox, oy = parent[row, 0], parent[row, 1]
        else:
            ox, oy = obstacle_poses[row - n, 0], obstacle_poses[row - n, 1]
        reach = bounding[obj] + bounding[row] + margin
        if (x - ox) ** 2 + (y - oy) ** 2 > reach * reach:
            continue
        allowed = pair_allowance[obj, row] if row < n else obstacle_allowance[obj, row - n]
        if _footprint_distance(x, y, c, s, half[obj, 0], half[obj, 1], is_disc[obj], ox, oy,
                               turned[row, 0], turned[row, 1], half[row, 0], half[row, 1],
                               is_disc[row]) < margin - allowed:
            return False
    return True


@kernel
def swept_pose_clear(obj: int, before: np.ndarray, change: np.ndarray, steps: int,
                     parent: np.ndarray, turned: np.ndarray, half: np.ndarray,
                     is_disc: np.ndarray, bounding: np.ndarray, obstacle_poses: np.ndarray,
                     pair_allowance: np.ndarray, obstacle_allowance: np.ndarray, margin: float,
                     bounds: np.ndarray, table_allowance: np.ndarray) -> bool:
    """Object `obj` is clear at before + (j / steps) change (3,) for every j = 1..steps (the
    last is the end pose), the others as in `parent` (their `headings` in `turned`)."""
    count = max(steps, 1)
    for j in range(count, 0, -1):          # the end pose first: it fails most often
        fraction = j / count
        if not _pose_clear(obj, before[0] + fraction * change[0],
                           before[1] + fraction * change[1], before[2] + fraction * change[2],
                           parent, turned, half, is_disc, bounding, obstacle_poses,
                           pair_allowance, obstacle_allowance, margin, bounds, table_allowance):
            return False
    return True


@kernel
def _swept_poses_clear(parent: np.ndarray, moved: np.ndarray, before: np.ndarray,
                       change: np.ndarray, steps: np.ndarray, half: np.ndarray,
                       is_disc: np.ndarray, bounding: np.ndarray, obstacle_poses: np.ndarray,
                       pair_allowance: np.ndarray, obstacle_allowance: np.ndarray,
                       margin: float, bounds: np.ndarray, table_allowance: np.ndarray
                       ) -> np.ndarray:
    """(k,) swept_pose_clear of each moved[i] from before[i] by change[i] in steps[i]."""
    turned = headings(parent, obstacle_poses)
    ok = np.ones(len(moved), np.bool_)
    for i in range(len(moved)):
        ok[i] = swept_pose_clear(moved[i], before[i], change[i], steps[i], parent, turned, half,
                                 is_disc, bounding, obstacle_poses, pair_allowance,
                                 obstacle_allowance, margin, bounds, table_allowance)
    return ok


@kernel
def ball_path_clear(pushed: int, start: np.ndarray, end: np.ndarray, parent: np.ndarray,
                    turned: np.ndarray, half: np.ndarray, is_disc: np.ndarray,
                    bounding: np.ndarray, obstacle_poses: np.ndarray, clearance: float) -> bool:
    """The ball's path start-end (2,) keeps `clearance` from every object but `pushed` and
    from the obstacles (their `headings` in `turned`)."""
    n = len(parent)
    for row in range(n + len(obstacle_poses)):
        if row == pushed:
            continue
        if row < n:
            ox, oy = parent[row, 0], parent[row, 1]
        else:
            ox, oy = obstacle_poses[row - n, 0], obstacle_poses[row - n, 1]
        # a segment farther from a centre than the bounding circle plus clearance is clear
        if (_segment_point(start[0], start[1], end[0], end[1], ox, oy)
                > bounding[row] + clearance):
            continue
        if _segment_footprint(start[0], start[1], end[0], end[1], ox, oy, turned[row, 0],
                              turned[row, 1], half[row, 0], half[row, 1],
                              is_disc[row]) < clearance:
            return False
    return True


@kernel
def _ball_paths_clear(parent: np.ndarray, pushed: np.ndarray, start: np.ndarray,
                      end: np.ndarray, half: np.ndarray, is_disc: np.ndarray,
                      bounding: np.ndarray, obstacle_poses: np.ndarray, clearance: float
                      ) -> np.ndarray:
    turned = headings(parent, obstacle_poses)
    ok = np.ones(len(pushed), np.bool_)
    for i in range(len(pushed)):
        ok[i] = ball_path_clear(pushed[i], start[i], end[i], parent, turned, half, is_disc,
                                bounding, obstacle_poses, clearance)
    return ok


@kernel
def _constraint_rows(first: np.ndarray, second: np.ndarray, tables: tuple) -> np.ndarray:
    """CollisionChecker's constraints g >= 0: pairs taking their first member from `first`
    (n, 3) and their second from `second`, then obstacles and table edges from `first`.
    `tables` is CollisionChecker.constraint_tables()."""
    pair_first, pair_second, pair_allow, obstacle_object, obstacle_row, obstacle_allow, \
        half, is_disc, obstacle_poses, margin, bounds, table_allow = tables
    pairs, obstacles, n = len(pair_first), len(obstacle_object), len(first)
    values = np.empty(pairs + obstacles + 4 * n)
    for k in range(pairs):
        a, b = pair_first[k], pair_second[k]
        values[k] = (footprint_signed_distance(first[a], half[a], is_disc[a], second[b],
                                               half[b], is_disc[b]) - margin + pair_allow[k])
    for k in range(obstacles):
        a, row = obstacle_object[k], obstacle_row[k]
        values[pairs + k] = (footprint_signed_distance(first[a], half[a], is_disc[a],
                                                       obstacle_poses[row - n], half[row],
                                                       is_disc[row])
                             - margin + obstacle_allow[k])
    for i in range(n):
        if is_disc[i]:
            hx = hy = half[i, 0]
        else:
            c, s = abs(math.cos(first[i, 2])), abs(math.sin(first[i, 2]))
            hx, hy = c * half[i, 0] + s * half[i, 1], s * half[i, 0] + c * half[i, 1]
        x, y, row = first[i, 0], first[i, 1], pairs + obstacles + 4 * i
        values[row] = x - hx - bounds[0] + table_allow[i, 0]
        values[row + 1] = bounds[2] - x - hx + table_allow[i, 1]
        values[row + 2] = y - hy - bounds[1] + table_allow[i, 2]
        values[row + 3] = bounds[3] - y - hy + table_allow[i, 3]
    return values


@kernel
def _constraint_jacobian(state: np.ndarray, step: float, tables: tuple) -> np.ndarray:
    """d g / d state (C, 3n) of _constraint_rows by forward differences: each constraint
    depends on one or two objects, so moving every object at once along one coordinate (first
    members of pairs only, then second members only) gives all its columns."""
    pair_first, pair_second, _, obstacle_object = tables[0], tables[1], tables[2], tables[3]
    pairs, obstacles, n = len(pair_first), len(obstacle_object), len(state)
    reference = _constraint_rows(state, state, tables)
    jacobian = np.zeros((len(reference), 3 * n))
    for d in range(3):
        shifted = state.copy()
        shifted[:, d] += step
        moved_first = _constraint_rows(shifted, state, tables)
        moved_second = _constraint_rows(state, shifted, tables)
        for k in range(pairs):
            jacobian[k, 3 * pair_first[k] + d] = (moved_first[k] - reference[k]) / step
            jacobian[k, 3 * pair_second[k] + d] = (moved_second[k] - reference[k]) / step
        for k in range(pairs, pairs + obstacles):
            jacobian[k, 3 * obstacle_object[k - pairs] + d] = ((moved_first[k] - reference[k])
                                                               / step)
        for i in range(n):
            for j in range(4):
                k = pairs + obstacles + 4 * i + j
                jacobian[k, 3 * i + d] = (moved_first[k] - reference[k]) / step
    return jacobian


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
        return _pair_distances(np.asarray(rows_a, np.int64), _floats(poses_a),
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
        """What _constraint_rows needs besides the states; built per call, as `tolerate`
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
        return _constraint_rows(state, state, self.constraint_tables())

    def constraint_jacobian(self, state: np.ndarray, step: float = 1e-6) -> np.ndarray:
        """d g / d state (C, 3n) by forward differences (_constraint_jacobian)."""
        return _constraint_jacobian(_floats(state), step, self.constraint_tables())

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
        return _swept_poses_clear(
            _floats(parent), np.asarray(moved, np.int64), _floats(start), _floats(change),
            np.asarray(steps, np.int64), *self.pose_tables())

    def pose_tables(self) -> tuple:
        """The arrays swept_pose_clear takes after `parent` and `turned` (shapes, allowances,
        margin, bounds), for compiled checks elsewhere; built per call, as `tolerate` replaces
        the allowances."""
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

    def ball_paths_clear(self, parent: np.ndarray, pushed: np.ndarray, start: np.ndarray,
                         end: np.ndarray, radius: float) -> np.ndarray:
        """(k,) True when the ball (radius) moving start->end (k, 2) keeps ball_margin from every
        object except the pushed one (k,) and from the obstacles, in state `parent` (n, 3)."""
        return _ball_paths_clear(_floats(parent), np.asarray(pushed, np.int64), _floats(start),
                                 _floats(end), self.shapes.half, self.shapes.is_disc,
                                 self.shapes.bounding_radius, self.shapes.obstacle_poses,
                                 radius + self.ball_margin)
