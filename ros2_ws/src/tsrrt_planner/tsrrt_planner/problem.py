"""The planning problem: start state, objective, forward models and every constraint on a push.

A push (object i, primitive p, length l) moves object i by the learned mean displacement
scaled to l (model_learning.ForwardModel.predict). In the world frame that is affine in l: the
pose changes by l * u with u = (R(theta_i) r_xy, r_theta), r the model's displacement per
metre, so steering a push towards a target is a one-dimensional least-squares problem
(task_space_rrt.steer_push).

A push is valid when (all checked in `pushes_valid`, vectorised over candidates):
* it is no longer than the object's `longest_push` (the learned length, or twice that for an
  object whose pushes are consistent and whose longer pushes have not turned it off in the
  closed loop);
* the object ends on the table, clear of every other object and obstacle (collision.py), and so
  does every intermediate pose at most `max_substep` of travel apart (no tunnelling through a
  neighbour during a long push);
* the ball's path from the approach point to the end of the push keeps clear of every other
  object (the pusher must be able to reach the contact point);
* the arm reaches every ball position from the approach point to the end point (by default
  the executor's Pinocchio-IK grid, tsrrt_executor.reachability.default_map(), so plans only
  use pushes the robot can do);
* with a face allowance (`with_face_allowance`, the improved planner's), it does not leave more
  objects of a kind short of reachable faces than the target needs (see there), nor push one
  that stays short of a face against the push of the face the arm cannot reach
  (`keeps_face_rule`);
* the robot has not refused it before moving from (nearly) this state (`refuse`: the closed
  loop marks such pushes, so that a replan does not send the same push again).
Push geometry (contact point, direction, approach clearance) comes from the executor's
tsrrt_executor.push_primitives so that planner and executor agree on it. All but the refusals
are checked in one compiled pass (`kernels.pushes_valid_compiled`), reach looked up on a grid
(reachability.py).

An object that no push can reach where it stands (`out_of_reach`) needs no models: nothing
can be planned with it, and it stays where it is, as an obstacle the objective still counts.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import numpy as np

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import BALL_RADIUS
from tsrrt_common.scenario import ObjectSpec, Scenario
from tsrrt_executor.push_primitives import (
    APPROACH_CLEARANCE,
    DEFAULT_PUSH_LENGTH,
    ROTATION_PRIMITIVES,
    ball_path_points,
    primitive_vector_in_object_frame,
    primitives_for,
    push_geometry,
)
from tsrrt_executor.reachability import default_map
from tsrrt_planner.collision import CollisionChecker
from tsrrt_planner.errors import PlannerError
from tsrrt_planner.kernels import (
    REFUSED_RADIUS,
    faces_reached,
    keeps_face_rule,
    points_reached,
    pushes_valid_compiled,
    pushes_valid_without,
    refused_pushes,
    stranded_objects,
)
from tsrrt_planner.model_learning import MIN_PUSH_LENGTH, ModelStore
from tsrrt_planner.objectives import Objective, ObjectSet, build_objective
from tsrrt_planner.reachability import GridReachability, Reachability, rasterised

MAX_PLANNED_PUSH = 0.10  # longest push the planner uses; the linear model is fitted at 0.05
# An object whose translation pushes at the learned length scatter less than this (std of the
# slip across the push and of the turn) may be pushed up to MAX_PLANNED_PUSH (longest_push).
CONSISTENT_SIDE_STD = 0.003       # m, the executor's consistency target
CONSISTENT_TURN_STD = math.radians(3.0)
NO_REFUSALS = np.zeros((0, 4))   # refusals_for's answer while nothing was refused
NO_REFUSALS.flags.writeable = False
REACH_SPACING = 0.005  # metres between checked ball positions, as push_is_executable samples
# Metres an object short of a face may move against the push of its unreachable face (model
# drift of a sideways push: about 1 mm in 3 cm): further, only that face could undo the move.
STRANDED_RETREAT = 0.001


def _to_world(c: np.ndarray, s: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Vectors `local` (..., 2) given in frames whose headings have cosines c and sines s
    (broadcast against local[..., 0]), in the world frame."""
    world = np.empty_like(local)
    world[..., 0] = c * local[..., 0] - s * local[..., 1]
    world[..., 1] = s * local[..., 0] + c * local[..., 1]
    return world


def shortest_turn(delta_theta: np.ndarray, period: np.ndarray) -> np.ndarray:
    """Heading differences reduced to the shortest turn modulo `period` (broadcast with them;
    a period of 0, a disc's, turns by nothing)."""
    safe = np.where(period > 0, period, 1.0)
    return np.where(period > 0, (delta_theta + safe / 2) % safe - safe / 2, 0.0)


def push_in_reach(spec: ObjectSpec, pose: Pose2D, primitive: int, reachability: Reachability,
                  push_length: float = DEFAULT_PUSH_LENGTH, table_height: float = 0.0) -> bool:
    """Whether the arm reaches every ball position of the push, from the approach point to its
    end (else the executor would answer UNREACHABLE)."""
    geometry = push_geometry(spec.shape, spec.length, spec.width, spec.height, pose, primitive,
                             push_length, table_height=table_height)
    return bool(reachability.reachable(ball_path_points(geometry)).all())


def out_of_reach(spec: ObjectSpec, reachability: Reachability,
                 table_height: float = 0.0) -> bool:
    """True when the arm reaches no push of the object at `spec.pose`, not even the shortest."""
    return not any(push_in_reach(spec, spec.pose, primitive, reachability, MIN_PUSH_LENGTH,
                                 table_height) for primitive in primitives_for(spec.shape))


def longest_push(models: ModelStore, spec: ObjectSpec) -> float:
    """Longest push the planner may ask of the object. Its models are linear fits at the
    learned length (5 cm), so a longer push extrapolates. That holds for an object that goes
    where it is pushed; a light box that slips and turns a few millimetres and degrees per
    5 cm turns more than linearly with length (eraser: mean |dtheta| 2.8 deg under 4.5 cm,
    7.8 deg beyond 7 cm), and in the closed loop its 8-10 cm pushes ended 1-2.6 cm off and
    forced replans; such an object is pushed no further than it was learned. Nor is one whose
    executed longer push turned it outside its prediction in the closed loop
    (ModelStore.cap_push): a few 5-cm trials cannot tell that the eraser is such an object."""
    lengths = []
    translations = [p for p in primitives_for(spec.shape) if p <= 4]  # along x (1, 2), y (3, 4)
    for primitive in translations:
        model = models.model_for(spec.id, spec.object_class, primitive)
        if model is None:
            continue
        std = np.sqrt(model.variance)
        side = std[1] if primitive <= 2 else std[0]
        consistent = side <= CONSISTENT_SIDE_STD and std[2] <= CONSISTENT_TURN_STD
        lengths.append(MAX_PLANNED_PUSH if consistent else model.push_length)
    return min(min(lengths, default=DEFAULT_PUSH_LENGTH), models.push_caps.get(spec.id, math.inf))


class PlanningProblem:
    """Everything a planner needs, as arrays in state order (n objects, 6 primitive slots).

    Args:
        scenario: table, objects, obstacles and objective.
        models: forward models covering every object and its primitives (but objects out
            of reach).
        reachability: arm reach model (default: the executor's IK grid, default_map()).
        margin: clearance kept between footprints, metres.
        ball_margin: clearance kept between the ball's path and the objects it must not touch:
            the executor's own (path_clearance, 3 mm) plus 3 mm, because a plan's later pushes
            start from predicted states a few millimetres off what will be observed (at 3 mm,
            five of eight replans of a tset6 task were pushes the executor then refused).
        max_substep: longest object travel between two collision-checked poses of a push.
        max_start_overlap: overlap of footprints (beyond the margin) tolerated in the start.
        max_start_overhang: overhang past a table edge tolerated in the start.
    """

    def __init__(self, scenario: Scenario, models: ModelStore,
                 reachability: Reachability | None = None, margin: float = 0.005,
                 ball_margin: float = 0.006,
                 max_substep: float = 0.03, max_start_overlap: float = 0.003,
                 max_start_overhang: float = 0.03) -> None:
        self.scenario = scenario
        self.objects = ObjectSet.from_specs(scenario.objects)
        self.n = len(self.objects)
        self.objective: Objective = build_objective(scenario)
        self.checker = CollisionChecker(self.objects, scenario.obstacles, scenario.table.bounds,
                                        margin=margin, ball_margin=ball_margin)
        self.reachability = reachability if reachability is not None else default_map()
        # the push checks look reach up on a grid (reachability.py)
        self.reach_cells = (self.reachability.reach_cells()
                            if isinstance(self.reachability, GridReachability)
                            else rasterised(self.reachability, scenario.table.bounds))
        self.max_substep = max_substep
        models.check_covers([(o.id, o.object_class, o.shape) for o in scenario.objects
                             if not out_of_reach(o, self.reachability, scenario.table.height)],
                            every_primitive=False, borrow=True)
        shapes = [o.shape for o in scenario.objects]
        self.rates, self.available = models.rate_table(
            self.objects.ids, shapes, [o.object_class for o in scenario.objects])
        self.contact = np.zeros((self.n, 6, 2))
        self.direction = np.zeros((self.n, 6, 2))
        for i, spec in enumerate(scenario.objects):
            for p in primitives_for(spec.shape):
                contact, direction = primitive_vector_in_object_frame(
                    spec.shape, spec.length, spec.width, p)
                self.contact[i, p - 1], self.direction[i, p - 1] = contact, direction
        # A disc's heading is never observed (perception keeps it at the scenario's, 0), so the
        # executor pushes it along the same axes whatever a model says it turned. And a disc is
        # symmetric about the line it is pushed along, so the push moves it along that line:
        # a side drift in its model is noise, and a drift of the same sign for the pushes 1 and
        # 2 (their mirror images) let POLISH walk a plate sideways by pushing it back and forth
        # (a tset6 demo executed 70 such pushes of 3 cm, each 1.2 mm sideways).
        disc = self.objects.is_disc
        along = self.direction[disc]                                     # (d, 6, 2) unit vectors
        self.rates[disc, :, :2] = (self.rates[disc, :, :2] * along).sum(-1, keepdims=True) * along
        self.rates[disc, :, 2] = 0.0
        self.start = np.array([o.pose.as_array() for o in scenario.objects])
        # An observed start may break the margin by a little, and an object may overhang an
        # edge (it still rests on the table); plan from it without making either worse
        # (CollisionChecker.tolerate). A real overlap or a large overhang is an error in the
        # observation or the scenario.
        overlap, overhang = self.checker.tolerate(self.start)
        if overlap > margin + max_start_overlap or overhang > max_start_overhang:
            raise PlannerError(
                f"{scenario.name}: the start state violates the constraints (footprints "
                f"{1000 * max(overlap - margin, 0.0):.1f} mm into each other, "
                f"{1000 * overhang:.1f} mm past a table edge)")
        # contiguous copies: np.nonzero's are strided views, and a kernel handed both a view and
        # a contiguous array (a slice of it) compiles once for each layout
        objects, primitives = np.nonzero(self.available)
        self.action_objects, self.action_primitives = np.ascontiguousarray(objects), primitives + 1
        # each object's own primitives, asked for by every A* search (rearrange.object_path)
        self.primitives_of = tuple(self.action_primitives[self.action_objects == i]
                                   for i in range(self.n))
        # ... and the actions (indices into action_objects) that turn it (lost_turn)
        turning = np.isin(self.action_primitives, ROTATION_PRIMITIVES)
        self.turns_of = tuple(np.nonzero(turning & (self.action_objects == i))[0]
                              for i in range(self.n))
        self.nominal_length = DEFAULT_PUSH_LENGTH
        # longest push per object (longest_push) and over all of them
        self.max_lengths = np.array([longest_push(models, o) for o in scenario.objects])
        self.min_length, self.max_length = MIN_PUSH_LENGTH, float(self.max_lengths.max())
        # symmetry period of each object's heading (0 for discs: heading irrelevant)
        self.angle_period = np.array([0.0 if o.shape != "box" else 2 * math.pi / max(
            o.symmetry, 1) for o in scenario.objects])
        # translation primitives (faces) per object, and the face rule (with_face_allowance)
        self.full_faces = self.available[:, :4].sum(axis=1)
        # where the ball lands for each translation primitive, in the object frame (n, 4, 2)
        self.approach_offsets = (self.contact[:, :4] - (BALL_RADIUS + APPROACH_CLEARANCE)
                                 * self.direction[:, :4])
        self.face_group = np.arange(self.n)
        self.face_allowance: np.ndarray | None = None
        self.face_tables = self._face_tables()
        self.retreat_limit = STRANDED_RETREAT
        # (object index, primitive, state) of pushes the robot refused before moving
        self.refused: list[tuple[int, int, np.ndarray]] = []
        self._compile_kernels()

    def _compile_kernels(self) -> None:
        """Compile the push checks' and the objective's kernels (or load them from numba's
        cache) now, as the collision checker does its own: on a fresh install they took 0.5 s of
        a first plan's first second (and REARRANGE's, `rearrange.compile_kernels`, 0.7 s
        more); loading the objective's from the cache takes 0.1-0.5 s."""
        self.objective.cost(self.start)
        one, pose = np.zeros(1, np.int64), self.start[:1]
        self.pushes_valid(self.start, one, one + 1, np.full(1, self.min_length))
        self.reachable_faces(one, pose)
        self._approaches_reached(one, pose)

    def with_face_allowance(self, targets: Sequence[np.ndarray],
                            groups: Sequence[np.ndarray]) -> PlanningProblem:
        """A copy whose pushes may not strand more objects of a group than `targets` need.

        Near the robot's base the arm cannot get behind an object (x >= 0.33 m straight
        ahead): pushed there, it has lost the face from which it could be pushed back, often
        for good. On clean, 2 of 6 seeds ended 61-65 % above the lower bound with the remote
        stranded at x = 0.32-0.38 m. An object short of reachable faces (`reachable_faces`
        below its translation primitives) is stranded; a push may strand an object only while
        its group (`groups`: interchangeable objects; others alone) then has no more stranded
        objects than it had or than the equally good `targets` (n, 3) need (the fewest): tset6's
        optimum puts a plate in a corner near the base in every variant (one stranded plate
        allowed), but its platters fit where they keep every face (none allowed).
        """
        variant = copy.copy(self)
        variant.face_group = np.arange(self.n)
        for group in groups:
            variant.face_group[group] = group[0]
        stranded = np.array([self.short_of_faces(np.asarray(target, float))
                             for target in targets])   # (targets, n)
        per_group = np.array([np.bincount(variant.face_group, weights=row, minlength=self.n)
                              for row in stranded])
        variant.face_allowance = per_group.min(axis=0)
        variant.face_tables = variant._face_tables()
        return variant

    def with_retreat_limit(self, limit: float) -> PlanningProblem:
        """A copy whose face rule lets an object short of a face move up to `limit` metres
        against the push of a face the arm cannot reach (STRANDED_RETREAT: 1 mm)."""
        variant = copy.copy(self)
        variant.retreat_limit = float(limit)
        return variant

    def _face_tables(self) -> tuple[np.ndarray, ...]:
        """The face rule's arrays as kernels.pushes_valid_compiled takes them, contiguous so
        that every call uses one compiled signature."""
        allowance = np.zeros(self.n) if self.face_allowance is None else self.face_allowance
        return (np.ascontiguousarray(self.approach_offsets),
                np.ascontiguousarray(self.available[:, :4]),
                np.ascontiguousarray(self.rates[:, :4]), self.full_faces, self.face_group,
                np.asarray(allowance, float))

    def refuse(self, object_index: int, primitive: int, state: np.ndarray) -> None:
        """Mark a push the robot refused before moving in `state` (n, 3) invalid from states
        within REFUSED_RADIUS of it. The executor checks the observed poses with its own
        geometry: a tset6 demo's replan put back the push refused two pushes before, from the
        same state to 0.3 mm, and it was refused again."""
        self.refused.append((int(object_index), int(primitive), np.array(state, dtype=float)))

    def refusals_for(self, index: int, state: np.ndarray) -> np.ndarray:
        """(m, 4) primitive and pose (x, y, theta) of object `index` for each of its refused
        pushes (`refuse`) that stand for `state` (n, 3): refused with every other object
        within REFUSED_RADIUS of where it is now."""
        if not self.refused:
            return NO_REFUSALS
        others = np.arange(self.n) != index
        rows = [[primitive, *where[index]] for obj, primitive, where in self.refused
                if obj == index and np.abs(state[others, :2] - where[others, :2]).max(
                    initial=0.0) <= REFUSED_RADIUS]
        return np.array(rows, float).reshape(-1, 4)

    def _refused_here(self, state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                      before: np.ndarray) -> np.ndarray:
        """(k,) True for pushes refused from (nearly) this state (`refuse`)."""
        refused = np.zeros(len(objects), bool)
        for index in {obj for obj, _, _ in self.refused}:
            rows = np.nonzero(objects == index)[0]
            if len(rows):
                refused[rows] = refused_pushes(
                    np.asarray(primitives[rows], np.int64), np.asarray(before[rows], float),
                    self.refusals_for(index, state), self.angle_period[index])
        return refused

    def geometry_tables(self) -> tuple:
        """What batch_push_geometry needs besides the pushes, then the longest push per object
        and the shortest push, for compiled searches (rearrange.object_path)."""
        return (self.rates, self.contact, self.direction, self.objects.half_length,
                self.max_substep, BALL_RADIUS, APPROACH_CLEARANCE, self.max_lengths,
                self.min_length)

    def check_tables(self) -> tuple:
        """Everything pushes_valid_compiled checks a push against but the state: the collision
        checker's arrays, the ball's clearance, the reach grid and its sampling, whether the
        face rule applies, its tables and the retreat limit (STRANDED_RETREAT)."""
        return (self.checker.pose_tables(), BALL_RADIUS + self.checker.ball_margin,
                self.reach_cells, REACH_SPACING, self.face_allowance is not None,
                self.face_tables, self.retreat_limit)

    # ------------------------------------------------------------------ forward model
    def push_directions(self, state: np.ndarray, objects: np.ndarray,
                        primitives: np.ndarray, poses: np.ndarray | None = None) -> np.ndarray:
        """World pose change per metre of push, u (k, 3), for pushes on state (n, 3).

        `poses` (k, 3), here and below, optionally replaces the pushed object's pose in
        `state` per push, so pushes of one object from several poses (the other objects as in
        `state`) go in one batch."""
        rate = self.rates[objects, primitives - 1]  # (k, 3)
        theta = (state[objects] if poses is None else poses)[:, 2]
        u = rate.copy()
        u[:, :2] = _to_world(np.cos(theta), np.sin(theta), rate[:, :2])
        return u

    def predict(self, state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                lengths: np.ndarray, poses: np.ndarray | None = None) -> np.ndarray:
        """MODEL(s, a): new pose (k, 3) of the pushed object for each push (k,)."""
        before = state[objects] if poses is None else poses
        return before + lengths[:, None] * self.push_directions(state, objects, primitives,
                                                                poses)

    def apply(self, state: np.ndarray, object_index: int, primitive: int,
              length: float) -> np.ndarray:
        """The whole next state (n, 3) after one push: `predict` for one push, on scalars
        (plans are replayed one push at a time, tens of thousands of times a second)."""
        new = state.copy()
        rx, ry, rt = self.rates[object_index, primitive - 1]
        theta = state[object_index, 2]
        c, s = np.cos(theta), np.sin(theta)
        new[object_index, 0] += length * (c * rx - s * ry)
        new[object_index, 1] += length * (s * rx + c * ry)
        new[object_index, 2] += length * rt
        return new

    # ------------------------------------------------------------------ constraints
    def pushes_valid(self, state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                     lengths: np.ndarray, poses: np.ndarray | None = None) -> np.ndarray:
        """(k,) validity of pushes on state (n, 3); see the module docstring for the rules."""
        if len(objects) == 0:
            return np.zeros(0, bool)
        before = np.asarray(state[objects] if poses is None else poses, float)
        ok = self._not_refused(state, objects, primitives, before)
        return pushes_valid_compiled(np.asarray(state, float), np.asarray(objects, np.int64),
                                     np.asarray(primitives, np.int64),
                                     np.asarray(lengths, float), before, ok,
                                     self.geometry_tables(), self.check_tables())

    def pushes_valid_without(self, state: np.ndarray, removed: np.ndarray,
                             away: tuple[float, float], objects: np.ndarray,
                             primitives: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """(r, k) `pushes_valid` of pushes (k,) with each object of `removed` (r,), none of
        them pushed, in turn moved to `away` (x, y), in one compiled pass."""
        before = np.asarray(state[objects], float)
        ok = np.empty((len(removed), len(objects)), bool)
        for row, j in enumerate(removed):
            without = state.copy()
            without[j, :2] = away
            ok[row] = self._not_refused(without, objects, primitives, before)
        return pushes_valid_without(np.asarray(state, float), np.asarray(removed, np.int64),
                                    np.asarray(away, float), np.asarray(objects, np.int64),
                                    np.asarray(primitives, np.int64),
                                    np.asarray(lengths, float), before, ok,
                                    self.geometry_tables(), self.check_tables())

    def _not_refused(self, state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                     before: np.ndarray) -> np.ndarray:
        """(k,) pushes not refused from `state` (`refuse`), the rule the compiled checks take
        as given; they check the lengths themselves."""
        if self.refused:
            return ~self._refused_here(state, objects, primitives, before)
        return np.ones(len(objects), bool)

    def reachable_faces(self, objects: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """(k,) how many translation primitives (1-4) of each object at `poses` (k, 3) start
        from an approach point the arm reaches."""
        return faces_reached(np.asarray(objects, np.int64), np.asarray(poses, float),
                             self.approach_offsets, self.available[:, :4], *self.reach_cells)

    def short_of_faces(self, state: np.ndarray) -> np.ndarray:
        """(n,) True for the objects of `state` (n, 3) that are short of a reachable face
        (stranded, in `with_face_allowance`'s words)."""
        return self.reachable_faces(np.arange(self.n), state) < self.full_faces

    def stranded_pushes(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the objects of `state` (n, 3) short of a reachable face: (n,) how many
        translation primitives they have whose approach point the arm cannot reach, and
        (n, 2) the world direction of the push of one of them (zeros elsewhere). Nothing can
        push such an object along that direction, and the face rule keeps it from being pushed
        against it."""
        everyone = np.arange(self.n)
        missing = ~self._approaches_reached(everyone, state) & self.available[:, :4]
        directions = _to_world(np.cos(state[:, 2:]), np.sin(state[:, 2:]),
                               self.rates[:, :4, :2])                        # (n, 4, 2)
        first = np.argmax(missing, axis=1)
        direction = directions[everyone, first] * missing.any(axis=1)[:, None]
        norms = np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
        return missing.sum(axis=1), direction / norms

    def _approaches_reached(self, objects: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """(k, 4) whether the arm reaches the approach point of each translation primitive
        (1-4) of `objects` at `poses` (k, 3), whether the object has that primitive or not."""
        approach = poses[:, None, :2] + _to_world(                     # (k, 4, 2)
            np.cos(poses[:, 2:]), np.sin(poses[:, 2:]), self.approach_offsets[objects])
        return points_reached(approach.reshape(-1, 2), *self.reach_cells).reshape(
            len(objects), 4)

    def keeps_faces(self, state: np.ndarray, objects: np.ndarray, before: np.ndarray,
                    final: np.ndarray) -> np.ndarray:
        """(k,) the face rule (`with_face_allowance`, keeps_face_rule) for moving `objects`
        from `before` to `final` (k, 3), the other objects as in `state`; all True without
        the rule."""
        _, _, reach, _, face_rule, faces, retreat_limit = self.check_tables()
        if not face_rule:
            return np.ones(len(objects), bool)
        stranded = stranded_objects(np.asarray(state, float), faces, reach)
        return np.array([keeps_face_rule(int(o), np.asarray(b, float), np.asarray(f, float),
                                         stranded, faces, reach, retreat_limit)
                         for o, b, f in zip(objects, before, final, strict=True)], bool)

    def state_valid(self, state: np.ndarray) -> bool:
        return self.checker.state_valid(state)

    def angle_error(self, delta_theta: np.ndarray) -> np.ndarray:
        """Heading differences (..., n) reduced modulo each object's symmetry (0 for discs)."""
        return shortest_turn(delta_theta, self.angle_period)
