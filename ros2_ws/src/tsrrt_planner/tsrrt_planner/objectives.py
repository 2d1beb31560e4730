"""Objective terms of Sec. III-A (Eq. 1-6) plus the paper's future-work terms.

An Objective is the weighted sum (Eq. 6) of terms, each applied to a named subset of the
movable objects. Costs and analytic gradients work on a state array of shape (..., n, 3)
holding (x, y, theta) of every movable object in scenario order, so the planner can score a whole
batch of candidate states in one call.

Interpretation choices (repeated in docs/planner.md):

* Eq. 1 ``spread``: the printed double sum over p1, p2 in P counts every pair twice (and each
  plate with itself, at distance 0). We sum each unordered pair once, i.e. half the printed value;
  the weight absorbs the factor. Where two centres coincide the gradient is taken as 0.
* Eq. 2 ``distance_to_point``: Euclidean distance of each object centre to a point, either
  given as [x, y] or ``table_center`` (Eq. 5: the point that maximises the smallest distance to the
  table edges, i.e. the centre of the bounds). Gradient 0 exactly at the point.
* Eq. 3 ``orthogonality``: the printed |mod(theta, pi/2)| jumps from pi/2 to 0 at theta = pi/2, so
  a box at 89 degrees would count as the worst possible. We use the intended meaning, the angular
  distance to the nearest multiple of pi/2, d(theta) = |theta - (pi/2) round(theta / (pi/2))|, in
  [0, pi/4]. It is a sum of absolute values (kinks at the optimum and at pi/4); the smooth
  alternative (1 - cos 4 theta) / 8 has the same minima but a vanishing gradient near them, which
  makes gradient descent crawl the last degrees, so the planner and lower bound use d(theta) and
  treat its kinks with subgradients. Discs (symmetry 0) have no observable heading and contribute
  0.
* Eq. 4 ``table_bounds``: the hard bound (the footprint lies on the table) is a planner
  constraint, always enforced. The term is an optional soft penalty sum max(0, margin - c)^2 over
  the clearances c between the footprint's axis-aligned extent and the four edges, to keep
  objects `margin` away from the edges.
* ``cluster_by_class`` (future work: "clustering by similarity"): the sum of distances between
  every pair of the term's objects that share a class.
* ``keep_clear``: for each object whose axis-aligned extent overlaps the rectangle
  [xmin, ymin, xmax, ymax], the shortest axis-parallel distance that would move it out.
* ``align`` (future work: "a minimization of differences over a set of object features"): the
  sum over pairs of boxes of the angular distance of theta_i - theta_j to the nearest multiple of
  pi/2, so all boxes share one heading modulo a right angle. Discs contribute 0.

Costs of the terms without trigonometry are compiled (kernels.py), one loop over a batch of
states: the planner scores single states and batches of hundreds tens of thousands of times a
second, and numpy's per-call overhead and temporaries made that a seventh of a tset12 search.
Each state's sum is added up in the order numpy sums a contiguous array (pairwise), so a state
costs the same, to the last bit, alone or in a batch. The extent terms stay in numpy (its float64
sin and cos may be its own SIMD code, which a kernel's would not match).

Gradients are analytic; at the kinks listed above a subgradient (the 0 or one-sided value) is
returned. Tests compare them with central finite differences away from kinks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tsrrt_common.scenario import OBJECTIVE_TERM_PARAMS, ObjectiveTermSpec, ObjectSpec, Scenario
from tsrrt_planner.errors import ObjectiveError
from tsrrt_planner.kernels import (
    add_heading_differences,
    add_pair_distances,
    add_point_distances,
    add_right_angle_distances,
)

HALF_PI = math.pi / 2.0


def right_angle_residual(theta: np.ndarray) -> np.ndarray:
    """Signed angle from theta to the nearest multiple of pi/2, in [-pi/4, pi/4]."""
    return theta - HALF_PI * np.round(theta / HALF_PI)


def compile_cost_kernels() -> None:
    """Compile every compiled term's kernel (or load it from numba's cache), whichever terms
    the first objective has (compile_kernels.py)."""
    states, first, second = np.zeros((1, 2, 3)), np.zeros(1, np.int64), np.ones(1, np.int64)
    total = np.zeros(1)
    add_pair_distances(states, first, second, 1.0, total)
    add_point_distances(states, first, np.zeros(2), 1.0, total)
    add_right_angle_distances(states, first, 1.0, total)
    add_heading_differences(states, first, second, 1.0, total)


def _lengths(vectors: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """Euclidean lengths over the last axis: np.linalg.norm's values without its per-call
    overhead (gradients are evaluated thousands of times a second)."""
    return np.sqrt((vectors * vectors).sum(axis=-1, keepdims=keepdims))


def axis_aligned_half_extents(theta: np.ndarray, half_length: np.ndarray,
                              half_width: np.ndarray, is_disc: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Half extents of rotated footprints along world x and y, and their derivatives in theta.

    Args:
        theta: (..., k) headings.
        half_length, half_width, is_disc: (k,) footprint data (a disc has half_length = radius).

    Returns:
        hx, hy, dhx_dtheta, dhy_dtheta, each (..., k).
    """
    c, s = np.cos(theta), np.sin(theta)
    hx = np.abs(c) * half_length + np.abs(s) * half_width
    hy = np.abs(s) * half_length + np.abs(c) * half_width
    dhx = -np.sign(c) * s * half_length + np.sign(s) * c * half_width
    dhy = np.sign(s) * c * half_length - np.sign(c) * s * half_width
    radius = np.broadcast_to(half_length, hx.shape)
    hx = np.where(is_disc, radius, hx)
    hy = np.where(is_disc, radius, hy)
    dhx = np.where(is_disc, 0.0, dhx)
    dhy = np.where(is_disc, 0.0, dhy)
    return hx, hy, dhx, dhy


@dataclass(frozen=True)
class ObjectSet:
    """Footprint data of the movable objects, in state order."""

    ids: tuple[str, ...]
    classes: tuple[str, ...]
    half_length: np.ndarray  # (n,) half the length; the radius for a disc
    half_width: np.ndarray   # (n,)
    is_disc: np.ndarray      # (n,) bool

    @classmethod
    def from_specs(cls, specs: Sequence[ObjectSpec]) -> ObjectSet:
        return cls(
            ids=tuple(s.id for s in specs),
            classes=tuple(s.object_class for s in specs),
            half_length=np.array([s.length / 2.0 for s in specs]),
            half_width=np.array([s.width / 2.0 for s in specs]),
            is_disc=np.array([s.shape != "box" for s in specs]),
        )

    def __len__(self) -> int:
        return len(self.ids)


class ObjectiveTerm:
    """One weighted term; subclasses define the unweighted cost and its gradient.

    Attributes:
        name: "terms[i] type", used in error messages and per-term reports.
        weight: non-negative finite weight (alpha, beta, gamma of Eq. 6).
        indices: (k,) state rows of the objects this term applies to.
        object_ids: ids of those objects.
    """

    type_name = ""

    def __init__(self, name: str, weight: float, indices: np.ndarray,
                 objects: ObjectSet, params: dict[str, Any], table_bounds: Sequence[float]
                 ) -> None:
        self.name = name
        self.weight = weight
        self.indices = indices
        self.object_ids = tuple(objects.ids[i] for i in indices)
        self.objects = objects
        self.table_bounds = tuple(float(b) for b in table_bounds)
        self._configure(params)

    def _configure(self, params: dict[str, Any]) -> None:
        """Read term parameters (already checked against OBJECTIVE_TERM_PARAMS)."""

    def fail(self, problem: str) -> ObjectiveError:
        return ObjectiveError(f"objective {self.name}: {problem}")

    def cost(self, states: np.ndarray) -> np.ndarray:
        """Unweighted cost (...,) of states (..., n, 3)."""
        states = np.ascontiguousarray(states, dtype=float)
        flat = states.reshape(-1, *states.shape[-2:])
        total = np.zeros(len(flat))
        self.add_weighted_cost(flat, 1.0, total)
        return total.reshape(states.shape[:-2])

    def add_weighted_cost(self, states: np.ndarray, weight: float, total: np.ndarray) -> None:
        """total (k,) += weight * the costs of contiguous float states (k, n, 3), in place:
        Objective.cost's sum, the value of `total + weight * cost` without numpy's
        temporaries (a few us each)."""
        raise NotImplementedError

    def gradient(self, states: np.ndarray) -> np.ndarray:
        """Unweighted gradient (..., n, 3) of `cost` with respect to states (..., n, 3)."""
        raise NotImplementedError


def _pair_matrix(n: int, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(pairs, n) incidence matrix: +1 at the first object of a pair, -1 at the second."""
    matrix = np.zeros((len(first), n))
    matrix[np.arange(len(first)), first] = 1.0
    matrix[np.arange(len(first)), second] = -1.0
    return matrix


class _PairDistanceTerm(ObjectiveTerm):
    """sign * sum of centre distances over a set of object pairs (Eq. 1 and clustering)."""

    sign = 1.0

    def _pairs(self) -> list[tuple[int, int]]:
        raise NotImplementedError

    def _configure(self, params: dict[str, Any]) -> None:
        pairs = self._pairs()
        if not pairs:
            raise self.fail(self._no_pair_problem)
        self.first = np.array([p[0] for p in pairs])
        self.second = np.array([p[1] for p in pairs])
        self.incidence = _pair_matrix(len(self.objects), self.first, self.second)

    _no_pair_problem = "needs at least two objects"

    def add_weighted_cost(self, states: np.ndarray, weight: float, total: np.ndarray) -> None:
        # weight * (sign * cost) == (sign * weight) * cost for sign +-1, bit for bit
        add_pair_distances(states, self.first, self.second, self.sign * weight, total)

    def gradient(self, states: np.ndarray) -> np.ndarray:
        delta = states[..., self.first, :2] - states[..., self.second, :2]  # (..., P, 2)
        distance = _lengths(delta, keepdims=True)
        unit = np.divide(delta, distance, out=np.zeros_like(delta), where=distance > 1e-12)
        grad = np.zeros_like(states)
        grad[..., :2] = self.sign * np.einsum("pn,...pd->...nd", self.incidence, unit)
        return grad


class SpreadTerm(_PairDistanceTerm):
    """Eq. 1: minus the distance between every (unordered) pair: objects far from each other."""

    type_name = "spread"
    sign = -1.0

    def _pairs(self) -> list[tuple[int, int]]:
        idx = list(self.indices)
        return [(a, b) for k, a in enumerate(idx) for b in idx[k + 1:]]


class ClusterByClassTerm(_PairDistanceTerm):
    """Future work: distance between every pair of the term's objects that share a class."""

    type_name = "cluster_by_class"
    sign = 1.0
    _no_pair_problem = "no two of its objects share a class, so there is nothing to cluster"

    def _pairs(self) -> list[tuple[int, int]]:
        idx = list(self.indices)
        classes = self.objects.classes
        return [(a, b) for k, a in enumerate(idx) for b in idx[k + 1:]
                if classes[a] == classes[b]]


class DistanceToPointTerm(ObjectiveTerm):
    """Eq. 2 (with Eq. 5): distance of each object centre to a point, default the table centre."""

    type_name = "distance_to_point"

    def _configure(self, params: dict[str, Any]) -> None:
        raw = params.get("point", "table_center")
        if raw == "table_center":
            x_min, y_min, x_max, y_max = self.table_bounds
            self.point = np.array([(x_min + x_max) / 2.0, (y_min + y_max) / 2.0])  # Eq. 5
        elif (isinstance(raw, (list, tuple)) and len(raw) == 2
              and all(isinstance(v, (int, float)) and math.isfinite(v) for v in raw)):
            self.point = np.array(raw, dtype=float)
        else:
            raise self.fail(f"point must be [x, y] or 'table_center', got {raw!r}")

    def add_weighted_cost(self, states: np.ndarray, weight: float, total: np.ndarray) -> None:
        add_point_distances(states, self.indices, self.point, weight, total)

    def gradient(self, states: np.ndarray) -> np.ndarray:
        delta = states[..., self.indices, :2] - self.point
        distance = _lengths(delta, keepdims=True)
        grad = np.zeros_like(states)
        grad[..., self.indices, :2] = np.divide(delta, distance, out=np.zeros_like(delta),
                                                where=distance > 1e-12)
        return grad


class OrthogonalityTerm(ObjectiveTerm):
    """Eq. 3: angular distance of each box's heading to the nearest multiple of pi/2."""

    type_name = "orthogonality"

    def _configure(self, params: dict[str, Any]) -> None:
        self.boxes = self.indices[~self.objects.is_disc[self.indices]]

    def add_weighted_cost(self, states: np.ndarray, weight: float, total: np.ndarray) -> None:
        add_right_angle_distances(states, self.boxes, weight, total)

    def gradient(self, states: np.ndarray) -> np.ndarray:
        grad = np.zeros_like(states)
        grad[..., self.boxes, 2] = np.sign(right_angle_residual(states[..., self.boxes, 2]))
        return grad


class AlignTerm(ObjectiveTerm):
    """Future work: every pair of boxes shares one heading modulo pi/2."""

    type_name = "align"

    def _configure(self, params: dict[str, Any]) -> None:
        boxes = [int(i) for i in self.indices if not self.objects.is_disc[i]]
        pairs = [(a, b) for k, a in enumerate(boxes) for b in boxes[k + 1:]]
        if not pairs:
            raise self.fail("needs at least two boxes (discs have no heading to align)")
        self.first = np.array([p[0] for p in pairs])
        self.second = np.array([p[1] for p in pairs])
        self.incidence = _pair_matrix(len(self.objects), self.first, self.second)

    def add_weighted_cost(self, states: np.ndarray, weight: float, total: np.ndarray) -> None:
        add_heading_differences(states, self.first, self.second, weight, total)

    def gradient(self, states: np.ndarray) -> np.ndarray:
        difference = states[..., self.first, 2] - states[..., self.second, 2]
        sign = np.sign(right_angle_residual(difference))  # (..., P)
        grad = np.zeros_like(states)
        grad[..., 2] = np.einsum("pn,...p->...n", self.incidence, sign)
        return grad


class _ExtentTerm(ObjectiveTerm):
    """Shared helper: axis-aligned extents of the term's objects. Costs in numpy, of states
    of any batch shape."""

    def add_weighted_cost(self, states: np.ndarray, weight: float, total: np.ndarray) -> None:
        total += weight * self.cost(states)

    def _extents(self, states: np.ndarray) -> tuple[np.ndarray, ...]:
        objects = self.objects
        return axis_aligned_half_extents(states[..., self.indices, 2],
                                         objects.half_length[self.indices],
                                         objects.half_width[self.indices],
                                         objects.is_disc[self.indices])


class TableBoundsTerm(_ExtentTerm):
    """Eq. 4 as a soft penalty: sum max(0, margin - clearance)^2 over the four table edges."""

    type_name = "table_bounds"

    def _configure(self, params: dict[str, Any]) -> None:
        margin = params.get("margin", 0.0)
        if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not (
                math.isfinite(margin) and margin >= 0.0):
            raise self.fail(f"margin must be a finite number >= 0, got {margin!r}")
        self.margin = float(margin)

    def _clearances(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clearances (..., k, 4) to x_min, x_max, y_min, y_max and their (x, y, theta) partials
        (..., k, 4, 3)."""
        x_min, y_min, x_max, y_max = self.table_bounds
        x, y = states[..., self.indices, 0], states[..., self.indices, 1]
        hx, hy, dhx, dhy = self._extents(states)
        clear = np.stack([x - hx - x_min, x_max - x - hx, y - hy - y_min, y_max - y - hy], -1)
        one, zero = np.ones_like(x), np.zeros_like(x)
        partials = np.stack([
            np.stack([one, zero, -dhx], -1), np.stack([-one, zero, -dhx], -1),
            np.stack([zero, one, -dhy], -1), np.stack([zero, -one, -dhy], -1)], -2)
        return clear, partials

    def cost(self, states: np.ndarray) -> np.ndarray:
        clear, _ = self._clearances(states)
        return (np.maximum(0.0, self.margin - clear) ** 2).sum(axis=(-1, -2))

    def gradient(self, states: np.ndarray) -> np.ndarray:
        clear, partials = self._clearances(states)
        violation = np.maximum(0.0, self.margin - clear)  # (..., k, 4)
        grad = np.zeros_like(states)
        grad[..., self.indices, :] = np.einsum("...ke,...ked->...kd", -2.0 * violation, partials)
        return grad


class KeepClearTerm(_ExtentTerm):
    """Future work ("maximize distance to obstacles"): leave a rectangle of the table free."""

    type_name = "keep_clear"

    def _configure(self, params: dict[str, Any]) -> None:
        region = params.get("region")
        if not (isinstance(region, (list, tuple)) and len(region) == 4 and all(
                isinstance(v, (int, float)) and math.isfinite(v) for v in region)
                and region[0] < region[2] and region[1] < region[3]):
            raise self.fail(f"region must be [xmin, ymin, xmax, ymax] with xmin < xmax and "
                            f"ymin < ymax, got {region!r}")
        self.region = tuple(float(v) for v in region)

    def _escapes(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distances (..., k, 4) to leave the region along -x, +x, -y, +y, and partials."""
        r_xmin, r_ymin, r_xmax, r_ymax = self.region
        x, y = states[..., self.indices, 0], states[..., self.indices, 1]
        hx, hy, dhx, dhy = self._extents(states)
        escapes = np.stack([x + hx - r_xmin, r_xmax - x + hx, y + hy - r_ymin, r_ymax - y + hy],
                           -1)
        one, zero = np.ones_like(x), np.zeros_like(x)
        partials = np.stack([
            np.stack([one, zero, dhx], -1), np.stack([-one, zero, dhx], -1),
            np.stack([zero, one, dhy], -1), np.stack([zero, -one, dhy], -1)], -2)
        return escapes, partials

    def cost(self, states: np.ndarray) -> np.ndarray:
        escapes, _ = self._escapes(states)
        shortest = escapes.min(axis=-1)
        return np.maximum(shortest, 0.0).sum(axis=-1)

    def gradient(self, states: np.ndarray) -> np.ndarray:
        escapes, partials = self._escapes(states)
        choice = escapes.argmin(axis=-1)  # (..., k)
        chosen = np.take_along_axis(partials, choice[..., None, None], axis=-2)[..., 0, :]
        inside = escapes.min(axis=-1) > 0.0
        grad = np.zeros_like(states)
        grad[..., self.indices, :] = np.where(inside[..., None], chosen, 0.0)
        return grad


TERM_CLASSES: dict[str, type[ObjectiveTerm]] = {
    cls.type_name: cls for cls in (SpreadTerm, DistanceToPointTerm, OrthogonalityTerm,
                                   TableBoundsTerm, ClusterByClassTerm, KeepClearTerm, AlignTerm)
}
assert set(TERM_CLASSES) == set(OBJECTIVE_TERM_PARAMS), "objective terms and schema disagree"


class Objective:
    """Eq. 6: C(s) = sum_k w_k c_k(s), over states (..., n, 3)."""

    def __init__(self, terms: Sequence[ObjectiveTerm], objects: ObjectSet) -> None:
        self.terms = tuple(terms)
        self.objects = objects

    @classmethod
    def from_specs(cls, specs: Sequence[ObjectiveTermSpec], objects: ObjectSet,
                   table_bounds: Sequence[float]) -> Objective:
        """Build from term specs; every problem raises ObjectiveError naming the term."""
        if not specs:
            raise ObjectiveError("objective: no terms given")
        index_of = {object_id: i for i, object_id in enumerate(objects.ids)}
        terms = []
        for k, spec in enumerate(specs):
            name = f"terms[{k}] {spec.type}"
            if spec.type not in TERM_CLASSES:
                raise ObjectiveError(f"objective {name}: unknown term type {spec.type!r}; "
                                     f"known: {sorted(TERM_CLASSES)}")
            weight = spec.weight
            if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not (
                    math.isfinite(weight) and weight >= 0.0):
                raise ObjectiveError(f"objective {name}: weight must be a finite number >= 0, "
                                     f"got {weight!r}")
            unknown_params = set(spec.params) - OBJECTIVE_TERM_PARAMS[spec.type]
            if unknown_params:
                raise ObjectiveError(
                    f"objective {name}: unknown parameters {sorted(unknown_params)}; allowed: "
                    f"{sorted(OBJECTIVE_TERM_PARAMS[spec.type])}")
            if not spec.object_ids:
                raise ObjectiveError(f"objective {name}: the term applies to no object")
            missing = [i for i in spec.object_ids if i not in index_of]
            if missing:
                raise ObjectiveError(f"objective {name}: unknown objects {missing}; known: "
                                     f"{list(objects.ids)}")
            indices = np.array(sorted({index_of[i] for i in spec.object_ids}))
            terms.append(TERM_CLASSES[spec.type](name, float(weight), indices, objects,
                                                 dict(spec.params), table_bounds))
        return cls(terms, objects)

    def cost(self, states: np.ndarray) -> np.ndarray | float:
        """C of states (..., n, 3) -> (...,); a single state gives a float."""
        states = np.ascontiguousarray(states, dtype=float)
        flat = states.reshape(-1, *states.shape[-2:])
        total = np.zeros(len(flat))
        for term in self.terms:
            term.add_weighted_cost(flat, term.weight, total)
        return float(total[0]) if states.ndim == 2 else total.reshape(states.shape[:-2])

    def gradient(self, states: np.ndarray) -> np.ndarray:
        """dC/ds (..., n, 3) of states (..., n, 3)."""
        states = np.asarray(states, dtype=float)
        return sum(term.weight * term.gradient(states) for term in self.terms)

    def term_costs(self, state: np.ndarray) -> dict[str, float]:
        """Weighted cost of every term for one state (n, 3), keyed by term name."""
        return {t.name: float(t.weight * t.cost(np.asarray(state, dtype=float)))
                for t in self.terms}


def build_objective(scenario: Scenario) -> Objective:
    """The objective of a scenario over its movable objects, in scenario order."""
    return Objective.from_specs(scenario.objective, ObjectSet.from_specs(scenario.objects),
                                scenario.table.bounds)
