"""The planner's compiled inner loops (numba), all in one file.

The planner checks a few dozen pushes at a time, thousands of times a second; as numpy arrays
that cost mostly per-call overhead, so the checks are scalar loops compiled with numba, with early
exits. The modules that use them (collision.py, reachability.py, problem.py, rearrange.py) wrap
them; what each computes is documented there.

Why one file: numba's on-disk cache (`cache=True`, in __pycache__, so only a first run compiles)
is invalidated only when a kernel's own source file changes, and a cached kernel carries the code
of every kernel it calls (numba's documented limitation: "changes in symbols defined in another
file are not recognised"). REARRANGE's search calls the push check, which calls the collision and
reach tests; were they in other files, changing a test would leave the search running the old
one from the cache. For the same reason the constants the kernels use live here.

Sections: footprint and ball-path collision tests; reach lookups on a grid; push geometry and the
whole push check; REARRANGE's A* over one object's pose; the objective's terms; matching
interchangeable objects to target slots; the tree's nearest neighbour.
"""

from __future__ import annotations

import heapq
import math

import numpy as np
from numba import njit

kernel = njit(cache=True, nogil=True)
inline_kernel = njit(cache=True, nogil=True, inline="always")

_BIG = 1e9
_CORNER_SIGNS = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))
# A refused push stays refused from states this close to the one it was refused in (every object
# within REFUSED_RADIUS metres, the pushed one also within REFUSED_TURN radians): observations of a
# still scene differ by well under a millimetre, and a plan that moved anything by more may have
# cleared the way.
REFUSED_RADIUS = 0.003
REFUSED_TURN = math.radians(2.0)
PATH_PUSH_COST = 0.01   # metres of remaining error one extra push is worth (weighted A*)
KEY_RESOLUTION = 0.002  # metres (and weighted radians) of the duplicate-pose grid


# ---------------- collision tests (collision.py)
@inline_kernel
def _point_box(px: float, py: float, hx: float, hy: float) -> float:
    """Signed distance of a point, given in a box's frame, to the box (half sizes hx, hy)."""
    qx, qy = abs(px) - hx, abs(py) - hy
    ox, oy = max(qx, 0.0), max(qy, 0.0)
    return math.sqrt(ox * ox + oy * oy) + min(max(qx, qy), 0.0)


@inline_kernel
def _corners_to_box(x: float, y: float, c: float, s: float, hx: float, hy: float,
                    bx: float, by: float, bc: float, bs: float, bhx: float, bhy: float) -> float:
    """Smallest signed distance of box (x, y, cos, sin; half sizes)'s corners to box b."""
    best = _BIG
    for sx, sy in _CORNER_SIGNS:
        lx, ly = sx * hx, sy * hy
        dx, dy = x + c * lx - s * ly - bx, y + s * lx + c * ly - by
        best = min(best, _point_box(dx * bc + dy * bs, -dx * bs + dy * bc, bhx, bhy))
    return best


@inline_kernel
def _box_box(ax: float, ay: float, ac: float, as_: float, ahx: float, ahy: float,
             bx: float, by: float, bc: float, bs: float, bhx: float, bhy: float) -> float:
    """Signed distance of two boxes, their headings given by their cosines and sines."""
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


@inline_kernel
def _box_disc(x: float, y: float, c: float, s: float, hx: float, hy: float, cx: float,
              cy: float, radius: float) -> float:
    """Signed distance of a box (heading as cosine c and sine s) and a disc."""
    dx, dy = cx - x, cy - y
    return _point_box(dx * c + dy * s, -dx * s + dy * c, hx, hy) - radius


@inline_kernel
def _footprint_distance(ax: float, ay: float, ac: float, as_: float, ahx: float, ahy: float,
                        disc_a: bool, bx: float, by: float, bc: float, bs: float, bhx: float,
                        bhy: float, disc_b: bool) -> float:
    """footprint_signed_distance on scalars, headings as cosines and sines: the pose checks
    pass no array views and turn each heading once."""
    if disc_a and disc_b:
        return math.hypot(ax - bx, ay - by) - ahx - bhx
    if disc_b:
        return _box_disc(ax, ay, ac, as_, ahx, ahy, bx, by, bhx)
    if disc_a:
        return _box_disc(bx, by, bc, bs, bhx, bhy, ax, ay, ahx)
    return _box_box(ax, ay, ac, as_, ahx, ahy, bx, by, bc, bs, bhx, bhy)


@kernel
def footprint_signed_distance(pose_a: np.ndarray, half_a: np.ndarray, disc_a: bool,
                              pose_b: np.ndarray, half_b: np.ndarray, disc_b: bool) -> float:
    """Signed distance between footprints at poses (3,) with half sizes (2,) (a disc's radius
    is half[0])."""
    return _footprint_distance(pose_a[0], pose_a[1], math.cos(pose_a[2]), math.sin(pose_a[2]),
                               half_a[0], half_a[1], disc_a, pose_b[0], pose_b[1],
                               math.cos(pose_b[2]), math.sin(pose_b[2]), half_b[0], half_b[1],
                               disc_b)


@inline_kernel
def _segment_point(sx: float, sy: float, ex: float, ey: float, px: float, py: float) -> float:
    dx, dy = ex - sx, ey - sy
    t = min(max(((px - sx) * dx + (py - sy) * dy) / max(dx * dx + dy * dy, 1e-18), 0.0), 1.0)
    return math.hypot(sx + t * dx - px, sy + t * dy - py)


@inline_kernel
def _slab(p: float, d: float, h: float) -> tuple[float, float]:
    """Parameter interval in which the line p + t d lies within [-h, h]."""
    if abs(d) > 1e-15:
        t1, t2 = (-h - p) / d, (h - p) / d
        return min(t1, t2), max(t1, t2)
    return (-_BIG, _BIG) if abs(p) <= h else (_BIG, -_BIG)


@inline_kernel
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


@inline_kernel
def _segment_footprint(sx: float, sy: float, ex: float, ey: float, x: float, y: float,
                       c: float, s: float, hx: float, hy: float, disc: bool) -> float:
    """segment_footprint_distance on scalars, the heading as cosine c and sine s."""
    if disc:
        return max(_segment_point(sx, sy, ex, ey, x, y) - hx, 0.0)
    return _segment_box(sx, sy, ex, ey, x, y, c, s, hx, hy)


@kernel
def pair_distances(rows_a: np.ndarray, poses_a: np.ndarray, rows_b: np.ndarray,
                   poses_b: np.ndarray, half: np.ndarray, is_disc: np.ndarray) -> np.ndarray:
    result = np.empty(len(rows_a))
    for i in range(len(rows_a)):
        a, b = rows_a[i], rows_b[i]
        result[i] = footprint_signed_distance(poses_a[i], half[a], is_disc[a], poses_b[i],
                                              half[b], is_disc[b])
    return result


@kernel
def targets_clear(indices: np.ndarray, target: np.ndarray, state: np.ndarray,
                  half: np.ndarray, is_disc: np.ndarray, threshold: float) -> np.ndarray:
    """(k, n) True where object j at its pose in `state` is at least `threshold` from object
    indices[r] at its pose in `target` (pair_distances' test); True for an object and itself."""
    clear = np.ones((len(indices), len(state)), np.bool_)
    for r in range(len(indices)):
        i = indices[r]
        for j in range(len(state)):
            if j != i:
                clear[r, j] = footprint_signed_distance(
                    target[i], half[i], is_disc[i], state[j], half[j], is_disc[j]) >= threshold
    return clear


@kernel
def neighbours(parent: np.ndarray, obstacle_poses: np.ndarray) -> np.ndarray:
    """(n + m, 4) x, y and the cosine and sine of the heading of every object of `parent`
    (n, 3), then of every obstacle: the footprint rows the pose and ball-path tests go through,
    each heading turned once per batch, not once per test."""
    rows = np.empty((len(parent) + len(obstacle_poses), 4))
    for row in range(len(rows)):
        pose = parent[row] if row < len(parent) else obstacle_poses[row - len(parent)]
        rows[row, 0], rows[row, 1] = pose[0], pose[1]
        rows[row, 2], rows[row, 3] = math.cos(pose[2]), math.sin(pose[2])
    return rows


@inline_kernel
def _half_extents(obj: int, c: float, s: float, half: np.ndarray, is_disc: np.ndarray
                  ) -> tuple[float, float]:
    """Half extents along world x and y of footprint `obj` turned to cosine c and sine s."""
    if is_disc[obj]:
        return half[obj, 0], half[obj, 0]
    return (abs(c) * half[obj, 0] + abs(s) * half[obj, 1],
            abs(s) * half[obj, 0] + abs(c) * half[obj, 1])


@inline_kernel
def _pose_clear(obj: int, x: float, y: float, theta: float, others: np.ndarray, n: int,
                half: np.ndarray, is_disc: np.ndarray, bounding: np.ndarray,
                pair_allowance: np.ndarray, obstacle_allowance: np.ndarray, margin: float,
                bounds: np.ndarray, table_allowance: np.ndarray) -> bool:
    """Object `obj` at (x, y, theta), the others as in `others` (`neighbours`: n objects, then
    the obstacles): on the table and clear of all."""
    c, s = math.cos(theta), math.sin(theta)
    hx, hy = _half_extents(obj, c, s, half, is_disc)
    if (x - hx - bounds[0] + table_allowance[obj, 0] < 0.0
            or bounds[2] - x - hx + table_allowance[obj, 1] < 0.0
            or y - hy - bounds[1] + table_allowance[obj, 2] < 0.0
            or bounds[3] - y - hy + table_allowance[obj, 3] < 0.0):
        return False
    for row in range(len(others)):
        if row == obj:
            continue
        ox, oy = others[row, 0], others[row, 1]
        reach = bounding[obj] + bounding[row] + margin
        if (x - ox) ** 2 + (y - oy) ** 2 > reach * reach:
            continue
        allowed = pair_allowance[obj, row] if row < n else obstacle_allowance[obj, row - n]
        if _footprint_distance(x, y, c, s, half[obj, 0], half[obj, 1], is_disc[obj], ox, oy,
                               others[row, 2], others[row, 3], half[row, 0], half[row, 1],
                               is_disc[row]) < margin - allowed:
            return False
    return True


@kernel
def swept_pose_clear(obj: int, before: np.ndarray, change: np.ndarray, steps: int,
                     others: np.ndarray, n: int, half: np.ndarray, is_disc: np.ndarray,
                     bounding: np.ndarray, pair_allowance: np.ndarray,
                     obstacle_allowance: np.ndarray, margin: float, bounds: np.ndarray,
                     table_allowance: np.ndarray) -> bool:
    """Object `obj` is clear at before + (j / steps) change (3,) for every j = 1..steps (the
    last is the end pose), the others as in `others` (`neighbours`, of n objects)."""
    count = max(steps, 1)
    for j in range(count, 0, -1):          # the end pose first: it fails most often
        fraction = j / count
        if not _pose_clear(obj, before[0] + fraction * change[0],
                           before[1] + fraction * change[1], before[2] + fraction * change[2],
                           others, n, half, is_disc, bounding, pair_allowance,
                           obstacle_allowance, margin, bounds, table_allowance):
            return False
    return True


@kernel
def swept_poses_clear(parent: np.ndarray, moved: np.ndarray, before: np.ndarray,
                      change: np.ndarray, steps: np.ndarray, half: np.ndarray,
                      is_disc: np.ndarray, bounding: np.ndarray, obstacle_poses: np.ndarray,
                      pair_allowance: np.ndarray, obstacle_allowance: np.ndarray,
                      margin: float, bounds: np.ndarray, table_allowance: np.ndarray
                      ) -> np.ndarray:
    """(k,) swept_pose_clear of each moved[i] from before[i] by change[i] in steps[i]."""
    others = neighbours(parent, obstacle_poses)
    ok = np.ones(len(moved), np.bool_)
    for i in range(len(moved)):
        ok[i] = swept_pose_clear(moved[i], before[i], change[i], steps[i], others, len(parent),
                                 half, is_disc, bounding, pair_allowance, obstacle_allowance,
                                 margin, bounds, table_allowance)
    return ok


@kernel
def ball_path_clear(pushed: int, start: np.ndarray, end: np.ndarray, others: np.ndarray,
                    half: np.ndarray, is_disc: np.ndarray, bounding: np.ndarray,
                    clearance: float) -> bool:
    """The ball's path start-end (2,) keeps `clearance` from every object but `pushed` and
    from the obstacles (`others`, their `neighbours` rows)."""
    for row in range(len(others)):
        if row == pushed:
            continue
        ox, oy = others[row, 0], others[row, 1]
        # a segment farther from a centre than the bounding circle plus clearance is clear
        if (_segment_point(start[0], start[1], end[0], end[1], ox, oy)
                > bounding[row] + clearance):
            continue
        if _segment_footprint(start[0], start[1], end[0], end[1], ox, oy, others[row, 2],
                              others[row, 3], half[row, 0], half[row, 1],
                              is_disc[row]) < clearance:
            return False
    return True


@kernel
def ball_paths_clear(parent: np.ndarray, pushed: np.ndarray, start: np.ndarray,
                     end: np.ndarray, half: np.ndarray, is_disc: np.ndarray,
                     bounding: np.ndarray, obstacle_poses: np.ndarray, clearance: float
                     ) -> np.ndarray:
    """(k,) ball_path_clear of each ball path start[i]-end[i] pushing pushed[i]."""
    others = neighbours(parent, obstacle_poses)
    ok = np.ones(len(pushed), np.bool_)
    for i in range(len(pushed)):
        ok[i] = ball_path_clear(pushed[i], start[i], end[i], others, half, is_disc, bounding,
                                clearance)
    return ok


@kernel
def constraint_rows(first: np.ndarray, second: np.ndarray, tables: tuple) -> np.ndarray:
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
        hx, hy = _half_extents(i, math.cos(first[i, 2]), math.sin(first[i, 2]), half, is_disc)
        x, y, row = first[i, 0], first[i, 1], pairs + obstacles + 4 * i
        values[row] = x - hx - bounds[0] + table_allow[i, 0]
        values[row + 1] = bounds[2] - x - hx + table_allow[i, 1]
        values[row + 2] = y - hy - bounds[1] + table_allow[i, 2]
        values[row + 3] = bounds[3] - y - hy + table_allow[i, 3]
    return values


@kernel
def constraint_jacobian(state: np.ndarray, step: float, tables: tuple) -> np.ndarray:
    """d g / d state (C, 3n) of constraint_rows by forward differences: each constraint
    depends on one or two objects, so moving every object at once along one coordinate (first
    members of pairs only, then second members only) gives all its columns."""
    pair_first, pair_second, _, obstacle_object = tables[0], tables[1], tables[2], tables[3]
    pairs, obstacles, n = len(pair_first), len(obstacle_object), len(state)
    reference = constraint_rows(state, state, tables)
    jacobian = np.zeros((len(reference), 3 * n))
    for d in range(3):
        shifted = state.copy()
        shifted[:, d] += step
        moved_first = constraint_rows(shifted, state, tables)
        moved_second = constraint_rows(state, shifted, tables)
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


# ---------------- reach lookups (reachability.py)
@inline_kernel
def _cell_reachable(x: float, y: float, x0: float, y0: float, step: float,
                    cells: np.ndarray) -> bool:
    col = math.floor((x - x0) / step + 1e-9)
    row = math.floor((y - y0) / step + 1e-9)
    if col < 0 or row < 0 or col >= cells.shape[1] or row >= cells.shape[0]:
        return False
    return cells[row, col]


@inline_kernel
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


# ---------------- push geometry and checks (problem.py)
@kernel
def batch_push_geometry(before: np.ndarray, rates: np.ndarray, contact: np.ndarray,
                        direction: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                        lengths: np.ndarray, half_length: np.ndarray, max_substep: float,
                        ball_radius: float, approach_clearance: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For pushes (k,) of objects at poses `before` (k, 3): the pose change (k, 3), how many
    poses along the way to check (one per max_substep of travel, a box's turn counted as the
    arc of its ends) and the ball's approach and end points (k, 2), as the executor moves it.
    One compiled pass: the planner checks a few dozen pushes at a time, thousands of times a
    second."""
    k = len(objects)
    change = np.empty((k, 3))
    steps = np.empty(k, np.int64)
    start = np.empty((k, 2))
    end = np.empty((k, 2))
    for i in range(k):
        obj, slot, length = objects[i], primitives[i] - 1, lengths[i]
        c, s = math.cos(before[i, 2]), math.sin(before[i, 2])
        rx, ry = rates[obj, slot, 0], rates[obj, slot, 1]
        ux, uy, ut = c * rx - s * ry, s * rx + c * ry, rates[obj, slot, 2]
        change[i, 0], change[i, 1], change[i, 2] = length * ux, length * uy, length * ut
        travel = length * max(math.sqrt(ux * ux + uy * uy), abs(ut) * half_length[obj])
        steps[i] = math.ceil(travel / max_substep)
        cx, cy = contact[obj, slot, 0], contact[obj, slot, 1]
        dx, dy = direction[obj, slot, 0], direction[obj, slot, 1]
        wdx, wdy = c * dx - s * dy, s * dx + c * dy
        touch_x = before[i, 0] + (c * cx - s * cy) - ball_radius * wdx
        touch_y = before[i, 1] + (s * cx + c * cy) - ball_radius * wdy
        start[i, 0] = touch_x - approach_clearance * wdx
        start[i, 1] = touch_y - approach_clearance * wdy
        end[i, 0], end[i, 1] = touch_x + length * wdx, touch_y + length * wdy
    return change, steps, start, end


@inline_kernel
def _turn_error(delta: float, period: float) -> float:
    """A heading difference reduced to the shortest turn modulo `period` (0 for a disc's 0)."""
    return (delta + period / 2) % period - period / 2 if period > 0 else 0.0


@inline_kernel
def _pose_error(x: float, y: float, theta: float, goal: np.ndarray, weight: float,
                period: float) -> float:
    """Weighted distance of a pose to `goal` (3,), its heading reduced modulo `period`
    (rearrange.object_error on one pose)."""
    dx, dy = goal[0] - x, goal[1] - y
    dt = _turn_error(goal[2] - theta, period)
    return math.sqrt(dx ** 2 + dy ** 2 + (weight * dt) ** 2)


@kernel
def steer_candidates(state: np.ndarray, target: np.ndarray, weights: np.ndarray,
                     objects: np.ndarray, primitives: np.ndarray, rates: np.ndarray,
                     period: np.ndarray, shortest: float, longest: np.ndarray,
                     fractions: np.ndarray, min_gain: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """STEER's candidate pushes (task_space_rrt.steer_push) from `state` (n, 3) towards
    `target`: for each (object, primitive) of `objects`, `primitives` (k,) whose closed-form
    length (the one that minimises rho, the pose being affine in the length; weights (n,) on
    the heading, reduced modulo `period`) is at least `shortest`, that length clipped to the
    object's `longest` times each of `fractions` (at least `shortest`). Returns the candidates'
    objects, primitives and lengths, fraction by fraction, and the indices into them, by
    falling rho^2 gain (stable), of those that remove more than `min_gain` of their object's
    squared error. Compiled: numpy spent most of a call in the overhead of a dozen small
    array operations, and STEER and the shortcuts call it thousands of times a second."""
    k = len(objects)
    ux, uy, ut = np.empty(k), np.empty(k), np.empty(k)
    ex, ey, et = np.empty(k), np.empty(k), np.empty(k)
    w2 = np.empty(k)
    ideal = np.empty(k)
    usable = np.zeros(k, np.bool_)
    for i in range(k):
        o, slot = objects[i], primitives[i] - 1
        c, s = math.cos(state[o, 2]), math.sin(state[o, 2])
        rx, ry = rates[o, slot, 0], rates[o, slot, 1]
        ux[i], uy[i], ut[i] = c * rx - s * ry, s * rx + c * ry, rates[o, slot, 2]
        ex[i], ey[i] = target[o, 0] - state[o, 0], target[o, 1] - state[o, 1]
        et[i] = _turn_error(target[o, 2] - state[o, 2], period[o])
        w2[i] = weights[o] ** 2
        along = ex[i] * ux[i] + ey[i] * uy[i] + w2[i] * et[i] * ut[i]
        norm = max(ux[i] * ux[i] + uy[i] * uy[i] + w2[i] * ut[i] * ut[i], 1e-12)
        ideal[i] = min(along / norm, longest[o])
        usable[i] = along / norm >= shortest
    rows = np.nonzero(usable)[0]
    m = len(rows)
    total = m * len(fractions)
    out_objects = np.empty(total, np.int64)
    out_primitives = np.empty(total, np.int64)
    lengths = np.empty(total)
    gain = np.empty(total)
    floor = np.empty(total)
    for f in range(len(fractions)):
        for r in range(m):
            i, j = rows[r], f * m + r
            length = max(ideal[i] * fractions[f], shortest)
            out_objects[j], out_primitives[j], lengths[j] = objects[i], primitives[i], length
            before = ex[i] * ex[i] + ey[i] * ey[i] + w2[i] * (et[i] * et[i])
            dx, dy, dt = ex[i] - length * ux[i], ey[i] - length * uy[i], et[i] - length * ut[i]
            gain[j] = before - (dx * dx + dy * dy + w2[i] * (dt * dt))
            floor[j] = max(min_gain * before, 1e-10)
    order = np.argsort(-gain, kind="mergesort")
    kept = order[gain[order] > floor[order]]
    return out_objects, out_primitives, lengths, kept


@kernel
def refused_pushes(primitives: np.ndarray, before: np.ndarray, refusals: np.ndarray,
                   period: float) -> np.ndarray:
    """(k,) True for pushes of one object with `primitives` (k,) from poses `before` (k, 3)
    that it was refused from (nearly) there: refusals (m, 4) are primitive, x, y, theta
    (`PlanningProblem.refusals_for`)."""
    refused = np.zeros(len(primitives), np.bool_)
    for i in range(len(primitives)):
        for r in range(len(refusals)):
            if primitives[i] != refusals[r, 0]:
                continue
            turn = _turn_error(before[i, 2] - refusals[r, 3], period)
            if (math.hypot(before[i, 0] - refusals[r, 1], before[i, 1] - refusals[r, 2])
                    <= REFUSED_RADIUS and abs(turn) <= REFUSED_TURN):
                refused[i] = True
                break
    return refused


@kernel
def stranded_objects(state: np.ndarray, faces: tuple, reach: tuple) -> np.ndarray:
    """(n,) True for the objects of `state` short of a reachable face; `faces` and `reach` as
    in PlanningProblem.check_tables()."""
    offsets, available, _, full, _, _ = faces
    x0, y0, step, cells = reach
    stranded = np.empty(len(state), np.bool_)
    for j in range(len(state)):
        stranded[j] = faces_reached_at(j, state[j], offsets, available, x0, y0, step,
                                       cells) < full[j]
    return stranded


@kernel
def keeps_face_rule(obj: int, before: np.ndarray, final: np.ndarray, stranded: np.ndarray,
                    faces: tuple, reach: tuple, retreat_limit: float) -> bool:
    """The face rule (PlanningProblem.with_face_allowance) for moving `obj` from `before` to
    `final` (3,), `stranded` being stranded_objects of the state it moves in: it may leave its
    group no more stranded objects than the allowance or than before, and an object short of a
    face may not move more than `retreat_limit` against the push of a face the arm cannot
    reach (only that face could undo the move)."""
    offsets, available, rates, full, group, allowance = faces
    x0, y0, step, cells = reach
    faces_before = faces_reached_at(obj, before, offsets, available, x0, y0, step, cells)
    faces_after = faces_reached_at(obj, final, offsets, available, x0, y0, step, cells)
    if faces_before < full[obj] and faces_after <= faces_before:
        c, s = math.cos(before[2]), math.sin(before[2])
        for f in range(4):
            if not available[obj, f] or approach_reached(obj, f, before[0], before[1], c, s,
                                                         offsets, x0, y0, step, cells):
                continue
            wx = c * rates[obj, f, 0] - s * rates[obj, f, 1]
            wy = s * rates[obj, f, 0] + c * rates[obj, f, 1]
            norm = max(math.sqrt(wx * wx + wy * wy), 1e-12)
            if (wx * (final[0] - before[0]) + wy * (final[1] - before[1])) / norm < -retreat_limit:
                return False
    if faces_after >= faces_before:
        return True
    in_group = 0
    for j in range(len(stranded)):
        if group[j] == group[obj] and stranded[j]:
            in_group += 1
    was = faces_before < full[obj]
    before_count = in_group - stranded[obj] + was
    after_count = before_count - was + (faces_after < full[obj])
    return after_count <= max(allowance[group[obj]], before_count)


@kernel
def pushes_geometry(before: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                    lengths: np.ndarray, geometry: tuple
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """batch_push_geometry with its tables from `geometry`
    (PlanningProblem.geometry_tables())."""
    rates, contact, direction, half_length, max_substep, ball_radius, clearance, _, _ = geometry
    return batch_push_geometry(before, rates, contact, direction, objects, primitives, lengths,
                               half_length, max_substep, ball_radius, clearance)


@inline_kernel
def _no_longer_than_allowed(objects: np.ndarray, lengths: np.ndarray, geometry: tuple,
                            ok: np.ndarray) -> None:
    """ok[i] = False for the pushes longer than their object may be pushed (the longest push
    per object, geometry_tables()), in place."""
    max_lengths = geometry[7]
    for i in range(len(objects)):
        if not lengths[i] <= max_lengths[objects[i]] + 1e-9:
            ok[i] = False


@kernel
def pushes_valid_compiled(state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                          lengths: np.ndarray, before: np.ndarray, ok: np.ndarray,
                          geometry: tuple, tables: tuple) -> np.ndarray:
    """`pushes_valid` in one compiled pass: each push (from poses `before`) still `ok` (k,)
    (refusals checked; updated in place) must be no longer than its object may be pushed, keep
    its way clear (swept_pose_clear), keep the face rule if the problem has one
    (keeps_face_rule), and keep the ball's path in reach and clear of the others. `geometry`
    and `tables` are PlanningProblem.geometry_tables() and check_tables(). A numpy version
    spent about 60 us a call in per-call overhead, most of a REARRANGE search's time; the push
    geometry (batch_push_geometry) is computed here, not in a second compiled call: 12 us a
    call for a few pushes instead of 30."""
    _no_longer_than_allowed(objects, lengths, geometry, ok)
    change, steps, start, end = pushes_geometry(before, objects, primitives, lengths, geometry)
    others, stranded = state_tables(state, tables)
    return _check_pushes(state, objects, before, change, steps, start, end, ok, tables, others,
                         stranded)


@kernel
def pushes_valid_without(state: np.ndarray, removed: np.ndarray, away: np.ndarray,
                         objects: np.ndarray, primitives: np.ndarray, lengths: np.ndarray,
                         before: np.ndarray, ok: np.ndarray, geometry: tuple, tables: tuple
                         ) -> np.ndarray:
    """pushes_valid_compiled (r, k) with each object of `removed` (r,) in turn moved to `away`
    (x, y), `ok` (r, k) as checked for each: what the pushes could do without that object
    (rearrange.approach_blockers asks it of every object near the pushed one)."""
    for r in range(len(removed)):
        _no_longer_than_allowed(objects, lengths, geometry, ok[r])
    change, steps, start, end = pushes_geometry(before, objects, primitives, lengths, geometry)
    without = state.copy()
    for r in range(len(removed)):
        j = removed[r]
        without[j, 0], without[j, 1] = away[0], away[1]
        others, stranded = state_tables(without, tables)
        _check_pushes(without, objects, before, change, steps, start, end, ok[r], tables,
                      others, stranded)
        without[j, 0], without[j, 1] = state[j, 0], state[j, 1]
    return ok


@kernel
def state_tables(state: np.ndarray, tables: tuple) -> tuple[np.ndarray, np.ndarray]:
    """What pushes in `state` (n, 3) are checked against besides `tables`: its `neighbours`
    and, with the face rule, its stranded_objects. A search over one object's pose computes
    them once."""
    collision, _, reach, _, face_rule, faces, _ = tables
    stranded = stranded_objects(state, faces, reach) if face_rule else np.zeros(0, np.bool_)
    return neighbours(state, collision[3]), stranded


@kernel
def _check_pushes(state: np.ndarray, objects: np.ndarray, before: np.ndarray,
                  change: np.ndarray, steps: np.ndarray, start: np.ndarray, end: np.ndarray,
                  ok: np.ndarray, tables: tuple, others: np.ndarray, stranded: np.ndarray
                  ) -> np.ndarray:
    """pushes_valid_compiled with the state's tables given (state_tables)."""
    collision, ball_clearance, reach, reach_spacing, face_rule, faces, retreat_limit = tables
    half, is_disc, bounding, _, pair_allow, obstacle_allow, margin, bounds, table_allow \
        = collision
    x0, y0, step, cells = reach
    n = len(state)
    final = np.empty(3)
    for i in range(len(objects)):
        if not ok[i]:
            continue
        o = objects[i]
        if not swept_pose_clear(o, before[i], change[i], steps[i], others, n, half, is_disc,
                                bounding, pair_allow, obstacle_allow, margin, bounds,
                                table_allow):
            ok[i] = False
            continue
        if face_rule:
            for d in range(3):
                final[d] = before[i, d] + change[i, d]
            if not keeps_face_rule(o, before[i], final, stranded, faces, reach, retreat_limit):
                ok[i] = False
                continue
        ok[i] = (segment_reached(start[i], end[i], reach_spacing, x0, y0, step, cells)
                 and ball_path_clear(o, start[i], end[i], others, half, is_disc, bounding,
                                     ball_clearance))
    return ok


# ---------------- REARRANGE's A* (rearrange.py)
@kernel
def pose_key(x: float, y: float, theta: float, weight: float, period: float) -> int:
    """One integer for a pose's duplicate-pose grid cell (KEY_RESOLUTION), heading reduced
    modulo the symmetry: 21 bits per axis, far more than a table needs."""
    kx = round(x / KEY_RESOLUTION)
    ky = round(y / KEY_RESOLUTION)
    kt = round(weight * (theta % period if period > 0 else 0.0) / KEY_RESOLUTION)
    offset = 1 << 20
    return ((kx + offset) << 42) | ((ky + offset) << 21) | (kt + offset)


@kernel
def expand_pushes(poses: np.ndarray, rates: np.ndarray, primitives: np.ndarray,
                  goal: np.ndarray, weight: float, period: float, longest: float,
                  shortest: float, fractions: np.ndarray, detours: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                             np.ndarray]:
    """The pushes to try on one object from each of `poses` (b, 3): per primitive (its pose
    change per metre of push, rates[primitive - 1]: x, y in the object frame, theta), the
    length that brings it closest to `goal` (closed form, the pose being affine in the length)
    times each of `fractions`, then each of the fixed `detours`; lengths below `shortest` are
    left out, steering lengths are clipped to [0, longest]. Compiled: the A* asks for a batch
    of a few poses at a time, far too small for numpy to pay off.

    Returns:
        rows (k,) into `poses`, primitives (k,), lengths (k,), the poses after the pushes
        (k, 3), their weighted errors to `goal` (object_error) and duplicate-pose keys
        (k,) (pose_key).
    """
    per_pose = len(primitives) * (len(fractions) + len(detours))
    total = len(poses) * per_pose
    rows = np.empty(total, np.int64)
    kinds = np.empty(total, np.int64)
    lengths = np.empty(total)
    new = np.empty((total, 3))
    errors = np.empty(total)
    keys = np.empty(total, np.int64)
    w2 = weight ** 2
    k = 0
    for b in range(len(poses)):
        x, y, theta = poses[b, 0], poses[b, 1], poses[b, 2]
        c, s = math.cos(theta), math.sin(theta)
        ex, ey, et = goal[0] - x, goal[1] - y, _turn_error(goal[2] - theta, period)
        for primitive in primitives:
            rx, ry, rt = rates[primitive - 1, 0], rates[primitive - 1, 1], rates[primitive - 1, 2]
            ux, uy = c * rx - s * ry, s * rx + c * ry
            ideal = ((ux * ex + uy * ey + rt * et * w2)
                     / max(ux * ux + uy * uy + rt * rt * w2, 1e-12))
            for m in range(len(fractions) + len(detours)):
                if m < len(fractions):
                    length = min(max(ideal * fractions[m], 0.0), longest)
                else:
                    length = detours[m - len(fractions)]
                if length < shortest:
                    continue
                nx, ny, nt = x + length * ux, y + length * uy, theta + length * rt
                rows[k], kinds[k], lengths[k] = b, primitive, length
                new[k, 0], new[k, 1], new[k, 2] = nx, ny, nt
                errors[k] = _pose_error(nx, ny, nt, goal, weight, period)
                keys[k] = pose_key(nx, ny, nt, weight, period)
                k += 1
    return rows[:k], kinds[:k], lengths[:k], new[:k], errors[:k], keys[:k]


@kernel
def search_object_path(state: np.ndarray, index: int, goal: np.ndarray, weight: float,
                       period: float, tolerance: float, max_expansions: int, batch: int,
                       primitives: np.ndarray, fractions: np.ndarray, detours: np.ndarray,
                       refusals: np.ndarray, geometry: tuple, checks: tuple
                       ) -> tuple[np.ndarray, np.ndarray, bool]:
    """rearrange.object_path's search, compiled whole: each round pops `batch` nodes, expands
    them (expand_pushes), drops poses already seen and checks the rest (pushes_valid_compiled)
    in one batch (_check_pushes, the state's tables made once). `geometry` is
    PlanningProblem.geometry_tables(), `checks` its check_tables().

    Returns:
        the path's primitives and lengths, and whether it reached the goal.
    """
    rates, max_lengths, shortest = geometry[0], geometry[7], geometry[8]
    longest = max_lengths[index]
    per_pose = len(primitives) * (len(fractions) + len(detours))
    capacity = 1 + max_expansions * per_pose
    poses = np.empty((capacity, 3))
    parents = np.empty(capacity, np.int64)
    kinds = np.empty(capacity, np.int64)
    lengths = np.empty(capacity)
    errors = np.empty(capacity)
    depths = np.empty(capacity, np.int64)
    poses[0] = state[index]
    parents[0], depths[0] = -1, 0
    errors[0] = _pose_error(poses[0, 0], poses[0, 1], poses[0, 2], goal, weight, period)
    if errors[0] <= tolerance:
        return np.zeros(0, np.int64), np.zeros(0), True
    size, best = 1, 0
    queue = [(errors[0], 0)]
    seen = {pose_key(poses[0, 0], poses[0, 1], poses[0, 2], weight, period)}
    others, stranded = state_tables(state, checks)   # the other objects never move here
    expansions = 0
    while len(queue) > 0 and expansions < max_expansions:
        count = min(batch, len(queue))
        nodes = np.empty(count, np.int64)
        for b in range(count):
            nodes[b] = heapq.heappop(queue)[1]
        expansions += count
        expanded = poses[nodes]
        rows, kind, length, new, error, keys = expand_pushes(
            expanded, rates[index], primitives, goal, weight, period, longest, shortest,
            fractions, detours)
        fresh = np.zeros(len(rows), np.bool_)
        for k in range(len(rows)):
            fresh[k] = keys[k] not in seen
        tried = np.nonzero(fresh)[0]
        if len(tried) == 0:
            continue
        objects = np.full(len(tried), index)
        tried_kinds, tried_lengths = kind[tried], length[tried]
        before = expanded[rows[tried]]
        ok = ~refused_pushes(tried_kinds, before, refusals, period)
        _no_longer_than_allowed(objects, tried_lengths, geometry, ok)
        change, steps, start, end = pushes_geometry(before, objects, tried_kinds, tried_lengths,
                                                    geometry)
        valid = tried[_check_pushes(state, objects, before, change, steps, start, end, ok,
                                    checks, others, stranded)]
        for k in valid[np.argsort(error[valid], kind="mergesort")]:
            if keys[k] in seen:
                continue
            seen.add(keys[k])
            child = size
            size += 1
            poses[child] = new[k]
            parents[child] = nodes[rows[k]]
            kinds[child], lengths[child], errors[child] = kind[k], length[k], error[k]
            depths[child] = depths[parents[child]] + 1
            if errors[child] < errors[best]:
                best = child
            if errors[child] <= tolerance:
                return _trace(parents, kinds, lengths, child) + (True,)
            heapq.heappush(queue, (errors[child] + PATH_PUSH_COST * depths[child], child))
    return _trace(parents, kinds, lengths, best) + (False,)


@kernel
def _trace(parents: np.ndarray, kinds: np.ndarray, lengths: np.ndarray, node: int
           ) -> tuple[np.ndarray, np.ndarray]:
    """Primitives and lengths of the pushes from the root to `node`."""
    depth, walk = 0, node
    while walk > 0:
        depth += 1
        walk = parents[walk]
    path_kinds = np.empty(depth, np.int64)
    path_lengths = np.empty(depth)
    for d in range(depth - 1, -1, -1):
        path_kinds[d], path_lengths[d] = kinds[node], lengths[node]
        node = parents[node]
    return path_kinds, path_lengths


@kernel
def ways_crossed_compiled(index: int, poses: np.ndarray, state: np.ndarray,
                          target: np.ndarray, blocked: int, others: np.ndarray,
                          fractions: np.ndarray, half: np.ndarray, is_disc: np.ndarray,
                          margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How object `index` at each of `poses` (k, 3) stands towards the pending objects'
    targets and ways (rearrange.parking_poses, clear_of_way), in one pass with early exits: a
    way is the object's straight sweep from its pose in `state` to its `target` position at
    its current heading, at `fractions` of the way.

    Returns:
        out_of_way (k,): clear of `blocked`'s target and way (only these are counted further);
        on_targets (k,): how many of `others` (m,) have their target footprint within the
            margin of it;
        crossed (k,): how many of their ways it stands in.
    """
    k = len(poses)
    out_of_way = np.zeros(k, np.bool_)
    on_targets = np.zeros(k, np.int64)
    crossed = np.zeros(k, np.int64)
    hx, hy, disc = half[index, 0], half[index, 1], is_disc[index]
    for p in range(k):
        x, y = poses[p, 0], poses[p, 1]
        c, s = math.cos(poses[p, 2]), math.sin(poses[p, 2])
        if not _stays_clear(x, y, c, s, hx, hy, disc, blocked, state, target, 0.0, fractions,
                            half, is_disc, margin, True):
            continue
        out_of_way[p] = True
        for j in others:
            gap = _footprint_distance(x, y, c, s, hx, hy, disc, target[j, 0], target[j, 1],
                                      math.cos(target[j, 2]), math.sin(target[j, 2]),
                                      half[j, 0], half[j, 1], is_disc[j])
            if not gap >= margin:
                on_targets[p] += 1
            if not _stays_clear(x, y, c, s, hx, hy, disc, j, state, target, 0.0, fractions,
                                half, is_disc, margin, False):
                crossed[p] += 1
    return out_of_way, on_targets, crossed


@inline_kernel
def _stays_clear(x: float, y: float, c: float, s: float, hx: float, hy: float, disc: bool,
                 j: int, state: np.ndarray, target: np.ndarray, turn: float,
                 fractions: np.ndarray, half: np.ndarray, is_disc: np.ndarray,
                 threshold: float, with_target: bool) -> bool:
    """Whether a footprint (x, y, cos, sin; half sizes) keeps `threshold` from object j's way
    (straight from its pose in `state` to its `target` position, turning by `turn` on the way,
    at `fractions` of it) and, `with_target`, from j's target footprint."""
    jc, js = math.cos(state[j, 2]), math.sin(state[j, 2])
    if with_target:
        gap = _footprint_distance(x, y, c, s, hx, hy, disc, target[j, 0], target[j, 1],
                                  math.cos(target[j, 2]), math.sin(target[j, 2]),
                                  half[j, 0], half[j, 1], is_disc[j])
        if not gap >= threshold:
            return False
    dx, dy = target[j, 0] - state[j, 0], target[j, 1] - state[j, 1]
    for f in fractions:
        if turn != 0.0:
            jc, js = math.cos(state[j, 2] + f * turn), math.sin(state[j, 2] + f * turn)
        gap = _footprint_distance(x, y, c, s, hx, hy, disc, state[j, 0] + f * dx,
                                  state[j, 1] + f * dy, jc, js, half[j, 0], half[j, 1],
                                  is_disc[j])
        if not gap >= threshold:
            return False
    return True


@kernel
def corridor_conflicts(pending: np.ndarray, state: np.ndarray, target: np.ndarray,
                       turns: np.ndarray, fractions: np.ndarray, half: np.ndarray,
                       is_disc: np.ndarray, threshold: float) -> np.ndarray:
    """rearrange.corridor_blocks in one compiled pass with early exits: (n, n) True at [i, j]
    (both `pending`, i != j) when object i at its `target` comes closer than `threshold` to
    object j anywhere on its way there, turning by turns[j] (_stays_clear)."""
    n = len(state)
    blocks = np.zeros((n, n), np.bool_)
    for i in pending:
        x, y = target[i, 0], target[i, 1]
        c, s = math.cos(target[i, 2]), math.sin(target[i, 2])
        for j in pending:
            if j != i and not _stays_clear(x, y, c, s, half[i, 0], half[i, 1], is_disc[i], j,
                                           state, target, turns[j], fractions, half, is_disc,
                                           threshold, False):
                blocks[i, j] = True
    return blocks


# ---------------- objective terms (objectives.py)
NUMPY_SUM_BLOCK = 128   # numpy's PW_BLOCKSIZE: the longest run it sums without splitting


@inline_kernel
def _numpy_block_sum(values: np.ndarray, start: int, count: int) -> float:
    """numpy's pairwise_sum of values[start:start + count] for count <= NUMPY_SUM_BLOCK."""
    if count < 8:
        total = -0.0
        for k in range(start, start + count):
            total += values[k]
        return total
    v = values[start:start + count]
    r0, r1, r2, r3, r4, r5, r6, r7 = v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]
    k = 8
    while k < count - count % 8:
        r0, r1, r2, r3 = r0 + v[k], r1 + v[k + 1], r2 + v[k + 2], r3 + v[k + 3]
        r4, r5, r6, r7 = r4 + v[k + 4], r5 + v[k + 5], r6 + v[k + 6], r7 + v[k + 7]
        k += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for m in range(k, count):
        total += v[m]
    return total


@inline_kernel
def _numpy_pairwise_sum(values: np.ndarray) -> float:
    """values (1-d) summed in the order numpy's pairwise_sum adds them
    (numpy/_core/src/umath/loops_utils.h.src): one by one below 8 values, in eight interleaved
    accumulators up to NUMPY_SUM_BLOCK, and above that the sum of two halves (the first a
    multiple of 8 long), each summed the same way. The halving runs on a stack, not by
    recursion, which numba's cache does not take in a kernel that others call."""
    if len(values) <= NUMPY_SUM_BLOCK:
        return _numpy_block_sum(values, 0, len(values))
    starts, counts = np.zeros(64, np.int64), np.zeros(64, np.int64)
    halves_done = np.zeros(64, np.int64)   # 0: neither half summed, 1: the first, 2: both
    sums = np.zeros(64)
    counts[0] = len(values)
    depth, summed = 1, 0
    while depth:
        top = depth - 1
        half = counts[top] // 2
        half -= half % 8
        if counts[top] <= NUMPY_SUM_BLOCK:
            sums[summed] = _numpy_block_sum(values, starts[top], counts[top])
            summed += 1
            depth -= 1
        elif halves_done[top] < 2:
            first = halves_done[top] == 0
            starts[depth] = starts[top] if first else starts[top] + half
            counts[depth] = half if first else counts[top] - half
            halves_done[depth] = 0
            halves_done[top] += 1
            depth += 1
        else:
            sums[summed - 2] = sums[summed - 2] + sums[summed - 1]
            summed -= 1
            depth -= 1
    return sums[0]


@inline_kernel
def _numpy_sum(values: np.ndarray) -> float:
    """values.sum() of a 1-d array, bit for bit: numpy starts from the identity 0.0."""
    return 0.0 + _numpy_pairwise_sum(values)


@kernel
def add_pair_distances(states: np.ndarray, first: np.ndarray, second: np.ndarray,
                       weight: float, total: np.ndarray) -> None:
    """total[s] += weight * the sum of the centre distances between objects first[p] and
    second[p] in state s of states (k, n, 3)."""
    lengths = np.empty(len(first))
    for s in range(len(states)):
        for p in range(len(first)):
            dx = states[s, first[p], 0] - states[s, second[p], 0]
            dy = states[s, first[p], 1] - states[s, second[p], 1]
            lengths[p] = math.sqrt(dx * dx + dy * dy)
        total[s] += weight * _numpy_sum(lengths)


@kernel
def add_point_distances(states: np.ndarray, indices: np.ndarray, point: np.ndarray,
                        weight: float, total: np.ndarray) -> None:
    """total[s] += weight * the sum of the distances of the `indices` objects' centres to
    `point` in state s."""
    lengths = np.empty(len(indices))
    for s in range(len(states)):
        for p in range(len(indices)):
            dx, dy = states[s, indices[p], 0] - point[0], states[s, indices[p], 1] - point[1]
            lengths[p] = math.sqrt(dx * dx + dy * dy)
        total[s] += weight * _numpy_sum(lengths)


@inline_kernel
def _right_angle_distance(theta: float) -> float:
    """|objectives.right_angle_residual(theta)|, the same operations."""
    return abs(theta - (math.pi / 2.0) * np.rint(theta / (math.pi / 2.0)))


@kernel
def add_right_angle_distances(states: np.ndarray, indices: np.ndarray, weight: float,
                              total: np.ndarray) -> None:
    """total[s] += weight * the sum over the `indices` objects of their heading's distance to
    a multiple of pi/2 in state s."""
    distances = np.empty(len(indices))
    for s in range(len(states)):
        for p in range(len(indices)):
            distances[p] = _right_angle_distance(states[s, indices[p], 2])
        total[s] += weight * _numpy_sum(distances)


@kernel
def add_heading_differences(states: np.ndarray, first: np.ndarray, second: np.ndarray,
                            weight: float, total: np.ndarray) -> None:
    """total[s] += weight * the sum over pairs of the distance of their heading difference to
    a multiple of pi/2 in state s."""
    distances = np.empty(len(first))
    for s in range(len(states)):
        for p in range(len(first)):
            distances[p] = _right_angle_distance(states[s, first[p], 2]
                                                 - states[s, second[p], 2])
        total[s] += weight * _numpy_sum(distances)


# ---------------- matching interchangeable objects to target slots (task_space_rrt.py)
@kernel
def min_cost_assignment(cost: np.ndarray) -> np.ndarray:
    """The column for each row of a square `cost` matrix that minimises the total: Crouse's
    shortest augmenting paths (IEEE Trans. AES 52(4), 2016), with the conventions of scipy's
    linear_sum_assignment (1.17) so that it picks the same one among equal totals and adds up in
    the same order: columns scanned from the last, and among equally short paths the first
    ending at a free column."""
    size = len(cost)
    u, v = np.zeros(size), np.zeros(size)
    shortest = np.empty(size)
    path = np.full(size, -1)
    col4row, row4col = np.full(size, -1), np.full(size, -1)
    rows_seen, columns_seen = np.zeros(size, np.bool_), np.zeros(size, np.bool_)
    remaining = np.empty(size, np.int64)
    for current in range(size):
        for k in range(size):
            remaining[k] = size - k - 1
        rows_seen[:], columns_seen[:], shortest[:] = False, False, np.inf
        left, row, sink, reached = size, current, -1, 0.0
        while sink == -1:
            index, lowest = -1, np.inf
            rows_seen[row] = True
            for k in range(left):
                j = remaining[k]
                r = reached + cost[row, j] - u[row] - v[j]
                if r < shortest[j]:
                    path[j], shortest[j] = row, r
                if shortest[j] < lowest or (shortest[j] == lowest and row4col[j] == -1):
                    lowest, index = shortest[j], k
            reached = lowest
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                row = row4col[j]
            columns_seen[j] = True
            left -= 1
            remaining[index] = remaining[left]
        u[current] += reached
        for i in range(size):
            if rows_seen[i] and i != current:
                u[i] += reached - shortest[col4row[i]]
        for j in range(size):
            if columns_seen[j]:
                v[j] -= reached - shortest[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == current:
                break
    return col4row


@kernel
def nearest_assignments(state: np.ndarray, targets: np.ndarray, members: np.ndarray,
                        starts: np.ndarray) -> np.ndarray:
    """task_space_rrt.assignment in one pass: (T, n) the slot of each of `targets` (T, n, 3)
    each object takes, the objects of each group (members[starts[g]:starts[g + 1]]) matched to
    their group's slots with the least total travel from `state` (n, 3)."""
    orders = np.empty((len(targets), len(state)), np.int64)
    for t in range(len(targets)):
        for i in range(len(state)):
            orders[t, i] = i
        for g in range(len(starts) - 1):
            group = members[starts[g]:starts[g + 1]]
            distance = np.empty((len(group), len(group)))
            for a in range(len(group)):
                for b in range(len(group)):
                    dx = state[group[a], 0] - targets[t, group[b], 0]
                    dy = state[group[a], 1] - targets[t, group[b], 1]
                    distance[a, b] = math.sqrt(dx * dx + dy * dy)
            columns = min_cost_assignment(distance)
            for a in range(len(group)):
                orders[t, group[a]] = group[columns[a]]
    return orders


# ---------------- the tree's nearest neighbour (task_space_rrt.py)
@kernel
def nearest_under_rho(states: np.ndarray, first: int, count: int, sample: np.ndarray,
                      weights: np.ndarray, period: np.ndarray) -> int:
    """The node nearest `sample` (n, 3) under Eq. 11's rho among node 0 and nodes first to
    count - 1 of `states` (m, n, 3), the first of equals: rho over the whole tree in numpy
    built five (m, n) temporaries, 8 ms a call over 6000 tset12 nodes (0.9 ms here)."""
    best, nearest = np.inf, 0
    n = sample.shape[0]
    for node in range(first - 1, count):
        row = 0 if node < first else node
        total = 0.0
        for i in range(n):
            dx = states[row, i, 0] - sample[i, 0]
            dy = states[row, i, 1] - sample[i, 1]
            turn = _turn_error(states[row, i, 2] - sample[i, 2], period[i]) * weights[i]
            total += dx * dx + dy * dy + turn * turn
        if total < best:
            best, nearest = total, row
    return nearest
