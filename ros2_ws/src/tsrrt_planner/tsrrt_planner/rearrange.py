"""REARRANGE: the improved planner's steering through clutter, one object at a time.

STEER (task_space_rrt.steer_push) pushes every object straight towards its target and gives up
on an object as soon as its push is blocked. On a crowded table objects lock each other in: a
platter needs the spot a plate sits in and the plate cannot get past the platter, so almost every
straight push is blocked. REARRANGE plans the moves in an order instead:

* an object whose target would stand in another pending object's straight way to its target
  waits until that one has gone (`corridor_blocks`: the platters' central targets would wall
  in a plate that still has to cross the table);
* of the rest, objects whose target footprint is free go first, each along a path of pushes
  found by a small best-first search over that object's pose with every other object fixed
  (`object_path`):
  variable-length pushes, the closed-form steering length among them, so a path can go around a
  neighbour, turn a box before sliding it, or leave the reach-limited strip near the robot;
* when no pending object can get to its target, an object standing on a pending target (or in
  the way of one) is parked: moved to a free pose on the table out of the blocked object's way
  and target, over as few other pending targets and ways as it can (`parking_poses`), or as far
  towards one as its search got if that is out of the way too; the blocked object then goes and
  the parked one follows later.

Every push of a path was checked with the full push validity (problem.pushes_valid) in the state
it is applied to, so a path added to the tree is consistent with the models and constraints.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from functools import cache

import numpy as np

from tsrrt_planner.kernels import (
    corridor_conflicts,
    search_object_path,
    targets_clear,
    ways_crossed_compiled,
)
from tsrrt_planner.problem import PlanningProblem, shortest_turn

Push = tuple[int, int, float]  # (object index, primitive, push length)
STEER_FRACTIONS = np.array([1.0, 0.5])  # closed-form push length and half of it
FIXED_LENGTHS = (0.01, 0.03, 0.06, 0.10)  # detour pushes of fixed length
PARKING_SPREAD = 0.08  # metres: spread of parking poses sampled around the object
BALL_ROOM = 0.04  # metres around an object the pusher needs (ball, approach, margins)
# metres a target may come inside the margin of the target next to it and still count as clear
# of it in corridor_blocks: optima (lower_bound, DIRECTGD) have neighbours touching at the
# margin, to SLSQP's tolerance on either side. Counted strictly, a target 0.4 um inside had
# every touching pair blocking the other's corridor; REARRANGE parked objects in circles, and
# clean's first plans from a demo's start ended 50-70 % above the bound (4 of 6 seeds), against
# 4.5-8.4 % (all 6) with the slack. Which side a bound falls on changed with nothing more than
# the order in which the process imported its libraries. Only there: the same slack in every
# clearance test (parking poses, sweeps, free targets) sent tset6 from 3.5 % to 23.8 % (median of
# 8 seeds)
CLEARANCE_SLACK = 1e-4
OFF_THE_TABLE = (1e3, 1e3)  # where approach_blockers puts an object to see a push without it
MEMO_SIZE = 4096  # answers a RearrangeMemo keeps (least recently asked go first)


def object_error(problem: PlanningProblem, index: int, poses: np.ndarray, goal: np.ndarray,
                 weight: float) -> np.ndarray:
    """Weighted distance (k,) of poses (k, 3) of object `index` to its goal pose (3,): the
    object's share of rho, heading reduced modulo its symmetry and weighted by `weight`."""
    period = problem.angle_period[index]
    delta = goal[None] - poses
    if period > 0:
        angle = (delta[:, 2] + period / 2) % period - period / 2
    else:
        angle = np.zeros(len(poses))
    return np.sqrt(delta[:, 0] ** 2 + delta[:, 1] ** 2 + (weight * angle) ** 2)


def pose_error(problem: PlanningProblem, index: int, pose: np.ndarray, goal: np.ndarray,
               weight: float) -> float:
    """object_error of one pose (3,), in scalar arithmetic (the same value, bit for bit):
    REARRANGE asks it of every pending object at every step, some 10,000 times a search,
    where numpy's per-call overhead was most of its cost."""
    period = float(problem.angle_period[index])
    dx, dy = float(goal[0] - pose[0]), float(goal[1] - pose[1])
    angle = (float(goal[2] - pose[2]) + period / 2) % period - period / 2 if period > 0 else 0.0
    return math.sqrt(dx * dx + dy * dy + (weight * angle) * (weight * angle))


def object_path(problem: PlanningProblem, state: np.ndarray, index: int, goal: np.ndarray,
                weight: float, tick: Callable[[], None], tolerance: float = 0.004,
                max_expansions: int = 48, batch: int = 4) -> tuple[list[Push], bool]:
    """Pushes that move object `index` from its pose in `state` (n, 3) towards `goal` (3,) with
    every other object fixed: weighted A* over the object's pose (f = remaining error +
    kernels.PATH_PUSH_COST per push), expanding `batch` nodes per validity check, duplicate
    poses pruned on a kernels.KEY_RESOLUTION grid. Compiled whole
    (kernels.search_object_path: the Python loop was most of REARRANGE's time); `tick` (the
    search's budget check) runs before it.

    Returns:
        (pushes, reached): the path to the first pose within `tolerance` of the goal (reached
        True) or, when the search ran out of expansions, to the closest pose found if it is
        closer than the start (reached False); an empty list when nothing helps.
    """
    tick()
    state = np.asarray(state, float)
    longest = float(problem.max_lengths[index])
    kinds, lengths, reached = search_object_path(
        state, index, np.asarray(goal, float), weight, float(problem.angle_period[index]),
        tolerance, max_expansions, batch,
        problem.primitives_of[index], STEER_FRACTIONS, detour_lengths(longest),
        problem.refusals_for(index, state), problem.geometry_tables(), problem.check_tables())
    return [(index, int(k), float(length))
            for k, length in zip(kinds.tolist(), lengths.tolist(), strict=True)], reached


class RearrangeMemo:
    """REARRANGE's questions that depend only on their arguments and the problem, answered
    once per search: object_path, approach_blockers and blockers_of. REARRANGE runs again
    and again from the same best node towards the same target, and asks the same questions
    until its first parking (parking poses are random): a fifth of a search's A* searches
    repeat one it made before (20 % of tset12's and 22 % of tset6's; the A* is half of either
    search's time), and 40 % of tset12's approach_blockers and blockers_of (an eighth of a
    3000-node search's time; the memo saves a third of it). The problem's refusals, the one
    part of it that may change, are counted in every key. The last `size` answers asked for
    are kept: 1024 A* answers alone held 98 % of the A* repeats in a 3000-node tset12
    search."""

    def __init__(self, problem: PlanningProblem, size: int = MEMO_SIZE) -> None:
        self.problem, self.size = problem, size
        self.answers: OrderedDict[tuple, tuple] = OrderedDict()

    def recall(self, key: tuple, answer: Callable[[], tuple]) -> tuple:
        """The answer kept for `key`, else answer()'s (then kept)."""
        key = (*key, len(self.problem.refused))
        known = self.answers.get(key)
        if known is not None:
            self.answers.move_to_end(key)
            return known
        known = self.answers[key] = answer()
        if len(self.answers) > self.size:
            self.answers.popitem(last=False)
        return known

    def object_path(self, state: np.ndarray, index: int, goal: np.ndarray, weight: float,
                    tick: Callable[[], None], tolerance: float = 0.004,
                    max_expansions: int = 48) -> tuple[list[Push], bool]:
        """object_path(problem, ...), `tick` run first whether the answer is kept or not."""
        tick()
        state, goal = np.asarray(state, float), np.asarray(goal, float)

        def search() -> tuple:
            path, reached = object_path(self.problem, state, index, goal, weight, lambda: None,
                                        tolerance, max_expansions)
            return tuple(path), reached

        path, reached = self.recall(("path", state.tobytes(), index, goal.tobytes(),
                                     float(weight), tolerance, max_expansions), search)
        return list(path), reached

    def approach_blockers(self, state: np.ndarray, target: np.ndarray, index: int,
                          weight: float) -> tuple[list[int], list[Push]]:
        """approach_blockers(problem, ...)."""
        blockers, pushes = self.recall(
            ("approach", state.tobytes(), target.tobytes(), index, float(weight)),
            lambda: tuple(map(tuple, approach_blockers(self.problem, state, target, index,
                                                       weight))))
        return list(blockers), list(pushes)

    def blockers_of(self, state: np.ndarray, target: np.ndarray, index: int) -> list[int]:
        """blockers_of(problem, ...)."""
        return list(self.recall(("blockers", state.tobytes(), target.tobytes(), index),
                                lambda: tuple(blockers_of(self.problem, state, target, index))))


def compile_kernels(problem: PlanningProblem) -> None:
    """Compile REARRANGE's kernels (or load them from numba's cache) before a search's clock
    starts: object_path's search and the corridor, target, parking and blocker checks."""
    start, goal = problem.start, problem.start.copy()
    goal[0] += (0.01, 0.0, 0.0)
    object_path(problem, start, 0, goal[0], 1.0, lambda: None, max_expansions=1)
    corridor_blocks(problem, start, goal, list(range(problem.n)))
    target_free(problem, start, goal, np.arange(problem.n))
    others = np.arange(1, problem.n)
    ways_crossed(problem, start, goal, 0, start[:1], 0, others)
    problem.pushes_valid_without(start, others, OFF_THE_TABLE, problem.action_objects[:1],
                                 problem.action_primitives[:1],
                                 np.full(1, problem.nominal_length))


@cache
def detour_lengths(longest: float) -> np.ndarray:
    """FIXED_LENGTHS cut to an object's longest push, each once (one 5 cm push, not two),
    made once per length (read-only): object_path asks for them some 7,000 times a search."""
    lengths = np.unique(np.minimum(FIXED_LENGTHS, longest))
    lengths.flags.writeable = False
    return lengths


@cache
def sweep_fractions(samples: int) -> np.ndarray:
    """np.linspace(0, 1, samples), made once (read-only): a 10-s tset12 search asks for
    some 20,000 sweeps, and linspace took half of straight_sweeps' time."""
    fractions = np.linspace(0.0, 1.0, samples)
    fractions.flags.writeable = False
    return fractions


def target_free(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
                indices: np.ndarray) -> np.ndarray:
    """(k, n) True where object j's current footprint keeps clear of the target footprint of
    each object of `indices` (an object's entry for itself is True), in one compiled pass
    (kernels.targets_clear): REARRANGE asks it for every pending object at every step."""
    shapes = problem.checker.shapes
    return targets_clear(np.asarray(indices, np.int64), np.ascontiguousarray(target, float),
                         np.ascontiguousarray(state, float), shapes.half, shapes.is_disc,
                         problem.checker.margin)


def corridor_blocks(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
                    pending: list[int], samples: int = 8) -> np.ndarray:
    """(n, n) True at [i, j] when object i placed at its target would stand in the corridor
    object j (pending, j != i) sweeps going straight from its pose in `state` to its target,
    turning evenly on the way (start included: j standing on i's target is such a conflict).
    Placing i first would then wall j in, so j should go first; in a cycle one of them has
    to be parked. Swept at its current heading instead, a long box that must turn a quarter
    to lie in a row would arrive across its neighbours' targets: clean's remote and the boxes
    beside it blocked each other, and the boxes were placed around the remote's slot."""
    turns = shortest_turn(target[:, 2] - state[:, 2], problem.angle_period)
    shapes = problem.checker.shapes
    return corridor_conflicts(np.asarray(pending, np.int64), np.ascontiguousarray(state, float),
                              np.ascontiguousarray(target, float), turns,
                              sweep_fractions(samples), shapes.half, shapes.is_disc,
                              problem.checker.margin - CLEARANCE_SLACK)


def blockers_of(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
                index: int) -> list[int]:
    """Objects in the way of `index` reaching its target: those standing on its target
    footprint, else those near the straight line from it to its target, closest first ("near":
    their bounding circles closer than BALL_ROOM, so they may block the pusher too)."""
    on_target = np.nonzero(~target_free(problem, state, target, np.array([index]))[0])[0]
    if len(on_target):
        return [int(j) for j in on_target]
    others = np.array([j for j in range(problem.n) if j != index], int)
    a, b = state[index, :2], target[index, :2]
    direction = b - a
    t = np.clip(((state[others, :2] - a) @ direction) / max(direction @ direction, 1e-12), 0, 1)
    distance = np.linalg.norm(a + t[:, None] * direction - state[others, :2], axis=1)
    reach = (problem.checker.shapes.bounding_radius[others]
             + problem.checker.shapes.bounding_radius[index] + BALL_ROOM)
    near = distance < reach
    return [int(j) for j in others[near][np.argsort(distance[near], kind="stable")]]


def approach_blockers(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
                      index: int, weight: float) -> tuple[list[int], list[Push]]:
    """When no push of nominal length that brings object `index` closer to its target is
    valid: the objects without which such a push, of nominal length or of the A*'s shortest,
    would become valid (standing where the ball must be), and those pushes. tset6's
    platter_2, 7 cm off its target in the arm's blind spot, could be pushed back only from
    its far end, where the plate placed in the corner beside it stood.

    The shortest pushes count because an object the arm cannot get behind may move only a
    little at a time: platter_2, 5 cm aside of its target in the blind spot and turned 3.5
    degrees, drifts back towards the base more than the face rule's 1 mm
    (STRANDED_RETREAT) in a 3-cm push, so only its 1-cm pushes are valid at all, and the
    plate in the corner stood where the ball must be for them. With nominal pushes alone no
    blocker was found, and 6 of 40 tset6 seeds (1500 nodes) ended 2.0-3.5 % above the bound
    with platter_2 aside."""
    nominal = min(problem.nominal_length, float(problem.max_lengths[index]))
    shortest = min(FIXED_LENGTHS[0], nominal)
    tried = np.array([nominal, shortest] if shortest < nominal else [nominal])
    own = problem.primitives_of[index]
    primitives, lengths = np.tile(own, len(tried)), np.repeat(tried, len(own))
    objects = np.full(len(primitives), index)
    before = pose_error(problem, index, state[index], target[index], weight)
    closer = object_error(problem, index, problem.predict(state, objects, primitives, lengths),
                          target[index], weight) < before
    if not closer.any():
        return [], []
    objects, primitives, lengths = objects[closer], primitives[closer], lengths[closer]
    valid = problem.pushes_valid(state, objects, primitives, lengths)
    if valid[lengths == nominal].any():
        return [], []
    blockers, freed = [], np.zeros(len(primitives), bool)
    # only an object close enough to touch it, the ball or the ball's path can block one of
    # these pushes; one taken off the table elsewhere can only make the face rule stricter.
    # Static obstacles (the shapes' rows from n on) never move, so they are never named.
    radius = problem.checker.shapes.bounding_radius[:problem.n]
    within = radius[index] + radius + float(lengths.max()) + 2 * BALL_ROOM
    near = np.nonzero(np.linalg.norm(state[:, :2] - state[index, :2], axis=1) < within)[0]
    near = near[near != index]
    without = problem.pushes_valid_without(state, near, OFF_THE_TABLE, objects, primitives,
                                           lengths)
    for j, now_valid in zip(near.tolist(), without & ~valid, strict=True):
        if now_valid.any():
            blockers.append(j)
            freed |= now_valid
    return blockers, [(index, int(primitive), float(length))
                      for primitive, length in zip(primitives[freed], lengths[freed], strict=True)]


def frees_a_push(problem: PlanningProblem, state: np.ndarray, index: int, pose: np.ndarray,
                 pushes: list[Push]) -> bool:
    """Whether one of `pushes` is valid with object `index` moved to `pose` (3,)."""
    if not pushes:
        return True
    moved = state.copy()
    moved[index] = pose
    return bool(problem.pushes_valid(moved, np.array([push[0] for push in pushes]),
                                     np.array([push[1] for push in pushes]),
                                     np.array([push[2] for push in pushes])).any())


def clear_of_way(problem: PlanningProblem, state: np.ndarray, target: np.ndarray, index: int,
                 poses: np.ndarray, blocked: int) -> np.ndarray:
    """(k,) True where object `index` at poses (k, 3) is out of the `blocked` object's way:
    clear of its target and of the corridor it sweeps going straight there at its current
    heading (start included)."""
    return ways_crossed(problem, state, target, index, poses, blocked, np.zeros(0, int))[0]


def ways_crossed(problem: PlanningProblem, state: np.ndarray, target: np.ndarray, index: int,
                 poses: np.ndarray, blocked: int, others: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For object `index` at poses (k, 3): whether it is out of the `blocked` object's way
    (clear_of_way), and how many of `others` (m,) have their target within its margin and
    their straight way there (as for `blocked`) crossed by it; the counts only where it is
    out of the way (ways_crossed_compiled: parking asked this of 200 poses at a time, some
    2000 times in a 3000-node tset12 search)."""
    shapes = problem.checker.shapes
    return ways_crossed_compiled(index, np.ascontiguousarray(poses, float),
                                 np.ascontiguousarray(state, float),
                                 np.ascontiguousarray(target, float), blocked,
                                 np.asarray(others, np.int64), sweep_fractions(8), shapes.half,
                                 shapes.is_disc, problem.checker.margin)


def parking_poses(problem: PlanningProblem, state: np.ndarray, target: np.ndarray,
                  index: int, pending: list[int], rng: np.random.Generator, blocked: int,
                  samples: int = 192) -> np.ndarray:
    """Free poses (k, 3) for object `index` at its current heading, sampled half around it and
    half anywhere on the table: on the table clear of every other object now and of the
    `blocked` object's target and the corridor it sweeps going straight there
    (clear_of_way). Those clear of the targets of the other pending objects come first, then
    those crossing the fewest of their corridors, then the nearest. A pose on another pending
    target is a last resort, not ruled out: twelve objects on tset12's table left 277 of 440
    parking attempts without a single pose clear of every pending target, and REARRANGE stuck."""
    x_min, y_min, x_max, y_max = problem.scenario.table.bounds
    near = samples // 2  # half near the object (short moves), half anywhere on the table
    poses = np.column_stack([
        np.concatenate([state[index, 0] + rng.normal(0.0, PARKING_SPREAD, near),
                        rng.uniform(x_min, x_max, samples - near)]),
        np.concatenate([state[index, 1] + rng.normal(0.0, PARKING_SPREAD, near),
                        rng.uniform(y_min, y_max, samples - near)]),
        np.full(samples, state[index, 2])])
    poses = poses[problem.checker.moved_objects_valid(state, np.full(samples, index), poses)]
    others = np.array([j for j in pending if j not in (index, blocked)], int)
    out_of_way, on_targets, crossed = ways_crossed(problem, state, target, index, poses,
                                                   blocked, others)
    poses, on_targets, crossed = poses[out_of_way], on_targets[out_of_way], crossed[out_of_way]
    distance = np.linalg.norm(poses[:, :2] - state[index, :2], axis=1)
    return poses[np.lexsort((distance, crossed, on_targets))]
