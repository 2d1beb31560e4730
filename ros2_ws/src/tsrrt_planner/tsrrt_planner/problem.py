"""The planning problem: start state, objective, forward models and every constraint on a push.

A push (object i, primitive p, length l) moves object i by the learned mean displacement
scaled to l (model_learning.ForwardModel.predict). In the world frame that is affine in l: the
pose changes by l * u with u = (R(theta_i) r_xy, r_theta), r the model's displacement per
metre, so steering a push towards a target is a one-dimensional least-squares problem
(task_space_rrt.steer_push).

A push is valid when (all checked in `pushes_valid`, vectorised over candidates):
* the object ends on the table, clear of every other object and obstacle (collision.py), and so
  does every intermediate pose at most `max_substep` of travel apart (no tunnelling through a
  neighbour during a long push);
* the ball's path from the approach point to the end of the push keeps clear of every other
  object (the pusher must be able to reach the contact point);
* the arm reaches the approach point and the end point (reachability.py).
Push geometry (contact point, direction, approach clearance) comes from the executor's
tsrrt_executor.push_primitives so that planner and executor agree on it.
"""

from __future__ import annotations

import math

import numpy as np

from tsrrt_common.robot_model import BALL_RADIUS
from tsrrt_common.scenario import Scenario
from tsrrt_executor.push_primitives import (
    APPROACH_CLEARANCE,
    DEFAULT_PUSH_LENGTH,
    primitive_vector_in_object_frame,
    primitives_for,
)
from tsrrt_planner.collision import CollisionChecker
from tsrrt_planner.errors import PlannerError
from tsrrt_planner.model_learning import MIN_PUSH_LENGTH, ModelStore
from tsrrt_planner.objectives import Objective, ObjectSet, build_objective
from tsrrt_planner.reachability import AnnulusReachability, Reachability

MAX_PLANNED_PUSH = 0.10  # longest push the planner uses; the linear model is fitted at 0.05


class PlanningProblem:
    """Everything a planner needs, as arrays in state order (n objects, 6 primitive slots).

    Args:
        scenario: table, objects, obstacles and objective.
        models: forward models covering every object and its primitives.
        reachability: arm reach model (default AnnulusReachability()).
        margin: clearance kept between footprints, metres.
        max_substep: longest object travel between two collision-checked poses of a push.
        max_start_violation: overlap or overhang (beyond the margin) tolerated in the start.
    """

    def __init__(self, scenario: Scenario, models: ModelStore,
                 reachability: Reachability | None = None, margin: float = 0.005,
                 max_substep: float = 0.03, max_start_violation: float = 0.003) -> None:
        self.scenario = scenario
        self.objects = ObjectSet.from_specs(scenario.objects)
        self.n = len(self.objects)
        self.objective: Objective = build_objective(scenario)
        self.checker = CollisionChecker(self.objects, scenario.obstacles, scenario.table.bounds,
                                        margin=margin)
        self.reachability = reachability or AnnulusReachability()
        self.max_substep = max_substep
        models.check_covers([(o.id, o.object_class, o.shape) for o in scenario.objects])
        shapes = [o.shape for o in scenario.objects]
        self.rates, self.available = models.rate_table(self.objects.ids, shapes)
        self.contact = np.zeros((self.n, 6, 2))
        self.direction = np.zeros((self.n, 6, 2))
        for i, spec in enumerate(scenario.objects):
            for p in primitives_for(spec.shape):
                contact, direction = primitive_vector_in_object_frame(
                    spec.shape, spec.length, spec.width, p)
                self.contact[i, p - 1], self.direction[i, p - 1] = contact, direction
        self.start = np.array([o.pose.as_array() for o in scenario.objects])
        # An observed start may break the margin by a little; plan from it without deepening
        # that (CollisionChecker.tolerate). A real overlap or an object far off the table is an
        # error in the observation or the scenario.
        self.start_violation = self.checker.tolerate(self.start)
        if self.start_violation > margin + max_start_violation:
            raise PlannerError(
                f"{scenario.name}: the start state violates the constraints by "
                f"{1000 * self.start_violation:.1f} mm (objects overlap or leave the table)")
        self.action_objects, self.action_primitives = np.nonzero(self.available)
        self.action_primitives = self.action_primitives + 1
        self.nominal_length = DEFAULT_PUSH_LENGTH
        self.min_length, self.max_length = MIN_PUSH_LENGTH, MAX_PLANNED_PUSH
        # symmetry period of each object's heading (0 for discs: heading irrelevant)
        self.angle_period = np.array([0.0 if o.shape != "box" else 2 * math.pi / max(
            o.symmetry, 1) for o in scenario.objects])

    # ------------------------------------------------------------------ forward model
    def push_directions(self, state: np.ndarray, objects: np.ndarray,
                        primitives: np.ndarray) -> np.ndarray:
        """World pose change per metre of push, u (k, 3), for pushes on state (n, 3)."""
        rate = self.rates[objects, primitives - 1]  # (k, 3)
        theta = state[objects, 2]
        c, s = np.cos(theta), np.sin(theta)
        return np.column_stack([c * rate[:, 0] - s * rate[:, 1], s * rate[:, 0] + c * rate[:, 1],
                                rate[:, 2]])

    def predict(self, state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                lengths: np.ndarray) -> np.ndarray:
        """MODEL(s, a): new pose (k, 3) of the pushed object for each push (k,)."""
        return state[objects] + lengths[:, None] * self.push_directions(state, objects,
                                                                        primitives)

    def apply(self, state: np.ndarray, object_index: int, primitive: int,
              length: float) -> np.ndarray:
        """The whole next state (n, 3) after one push."""
        new = state.copy()
        new[object_index] = self.predict(state, np.array([object_index]), np.array([primitive]),
                                         np.array([length]))[0]
        return new

    # ------------------------------------------------------------------ constraints
    def pushes_valid(self, state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                     lengths: np.ndarray) -> np.ndarray:
        """(k,) validity of pushes on state (n, 3); see the module docstring for the rules."""
        k = len(objects)
        if k == 0:
            return np.zeros(0, bool)
        u = self.push_directions(state, objects, primitives)
        final = state[objects] + lengths[:, None] * u
        ok = self.checker.moved_objects_valid(state, objects, final)
        # intermediate poses, every max_substep of travel
        travel = lengths * np.maximum(np.linalg.norm(u[:, :2], axis=1),
                                      np.abs(u[:, 2]) * self.objects.half_length[objects])
        steps = np.ceil(travel / self.max_substep).astype(int)
        needs = np.nonzero(ok & (steps > 1))[0]
        if len(needs):
            rows = np.repeat(needs, steps[needs] - 1)
            fractions = np.concatenate([np.arange(1, s) / s for s in steps[needs]])
            poses = state[objects[rows]] + (fractions * lengths[rows])[:, None] * u[rows]
            mid_ok = self.checker.moved_objects_valid(state, objects[rows], poses)
            ok[needs] &= np.bincount(np.searchsorted(needs, rows), weights=~mid_ok,
                                     minlength=len(needs)) == 0
        alive = np.nonzero(ok)[0]
        if len(alive):
            start, end = self.ball_path(state, objects[alive], primitives[alive], lengths[alive])
            reach = self.reachability.reachable(start) & self.reachability.reachable(end)
            clear = self.checker.ball_paths_clear(state, objects[alive], start, end, BALL_RADIUS)
            ok[alive] = reach & clear
        return ok

    def ball_path(self, state: np.ndarray, objects: np.ndarray, primitives: np.ndarray,
                  lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ball-centre approach and end points (k, 2) in the world, as the executor moves it."""
        theta = state[objects, 2]
        c, s = np.cos(theta), np.sin(theta)
        rotation = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (k, 2, 2)
        contact = np.einsum("kij,kj->ki", rotation, self.contact[objects, primitives - 1])
        direction = np.einsum("kij,kj->ki", rotation, self.direction[objects, primitives - 1])
        touch = state[objects, :2] + contact - BALL_RADIUS * direction
        return touch - APPROACH_CLEARANCE * direction, touch + lengths[:, None] * direction

    def state_valid(self, state: np.ndarray) -> bool:
        return self.checker.state_valid(state)

    def angle_error(self, delta_theta: np.ndarray) -> np.ndarray:
        """Heading differences (..., n) reduced modulo each object's symmetry (0 for discs)."""
        period = np.where(self.angle_period > 0, self.angle_period, 1.0)
        wrapped = (delta_theta + period / 2) % period - period / 2
        return np.where(self.angle_period > 0, wrapped, 0.0)
