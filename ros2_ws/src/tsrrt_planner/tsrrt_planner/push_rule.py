"""A physically plausible, physics-free pushing rule, and a noisy pusher built on it.

Used where no simulator is in the loop: the unit tests pass `SimulatedPusher.apply_action` to
LEARN_MODEL as APPLY_ACTION, and the model files shipped for the benchmark scenarios
(data/models/<scenario>.yaml) were made by running LEARN_MODEL against it:

    python -m tsrrt_planner.push_rule --scenario tset6 --out .../data/models/tset6.yaml

The closed loop later replaces them with models learned in the simulator.

The rule (quasi-static pushing with a point pusher, Lynch & Mason style, simplified):

* Primitives 1-4 push through the face midpoint, so the object translates along the push by the
  pusher's travel times a transfer efficiency e (some travel is lost to compliance and slip;
  e falls with the object's friction coefficient: e = clip(0.95 - 0.25 (mu - 0.3), 0.75, 0.95)),
  with a small lateral drift (4 %) and a small rotation (0.02 rad per 5 cm) from uneven contact.
* Primitives 5-6 push at 0.45 length from the centre, perpendicular to the long axis. The object
  turns about a point on its long axis at length/6 on the other side of the centre (the centre of
  rotation of a uniformly supported bar pushed near its end), so dtheta = e l / (0.45 L + L/6)
  and the centre moves on a circle about that point.
* Noise: Gaussian, per component 8 % of the displacement plus 1.5 mm (position) or 0.02 rad.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import ObjectSpec, load_scenario
from tsrrt_executor.push_primitives import ROTATION_CONTACT_FRACTION, primitives_for
from tsrrt_planner.errors import ModelError
from tsrrt_planner.model_learning import (
    LEARN_MODEL,
    ConfidenceStoppingRule,
    ForwardModel,
    ModelStore,
)

NOMINAL = 0.05


def transfer_efficiency(friction: float) -> float:
    return float(np.clip(0.95 - 0.25 * (friction - 0.3), 0.75, 0.95))


def plausible_displacement(spec: ObjectSpec, primitive: int, push_length: float) -> np.ndarray:
    """Expected (dx, dy, dtheta) in the object frame for one push, (3,)."""
    if primitive not in primitives_for(spec.shape):
        raise ModelError(f"primitive {primitive} does not exist for {spec.id} ({spec.shape})")
    travel = transfer_efficiency(spec.friction) * push_length
    twist = 0.02 * push_length / NOMINAL
    if primitive in (1, 2, 3, 4):
        sign = 1.0 if primitive in (1, 3) else -1.0
        along = np.array([1.0, 0.0]) if primitive in (1, 2) else np.array([0.0, 1.0])
        lateral = np.array([along[1], along[0]])
        xy = sign * travel * along + 0.04 * travel * lateral
        return np.array([xy[0], xy[1], 0.0 if spec.shape != "box" else sign * twist])
    sign = 1.0 if primitive == 5 else -1.0
    pivot_x = -spec.length / 6.0
    arm = ROTATION_CONTACT_FRACTION * spec.length - pivot_x
    dtheta = sign * travel / arm
    dx = pivot_x * (1.0 - math.cos(dtheta))
    dy = -pivot_x * math.sin(dtheta)
    return np.array([dx, dy, dtheta])


def plausible_spread(expected: np.ndarray) -> np.ndarray:
    """Standard deviation (3,) of the rule's noise around an expected displacement."""
    return 0.08 * np.abs(expected) + np.array([0.0015, 0.0015, 0.02])


def rule_model(spec: ObjectSpec, primitive: int, push_length: float = NOMINAL) -> ForwardModel:
    """The rule as a forward model, for a primitive the robot has no trial of at all.

    Its variance is the rule's noise (count 1: m2 is the variance); the noise being generous
    (5.3 mm for a 5 cm push), the first execution of the push diverges from it only when the
    rule is far off, and that execution starts the object's own model either way.
    """
    expected = plausible_displacement(spec, primitive, push_length)
    return ForwardModel(spec.id, primitive, push_length, 1, expected,
                        plausible_spread(expected) ** 2)


def assume_rule_where_uncovered(store: ModelStore, objects: Sequence[ObjectSpec]) -> list[str]:
    """Give every primitive of `objects` that nothing learned covers (never tried: blocked
    while learning, and no class-mate or mirror partner has it) the rule's model, as the robot
    plans with it until the push is executed; returns "<id> primitive <p>" for each. Planned
    without them instead, the benchmark ended tset6 63-65 % above the bound with the models a
    demo had learned (4 seeds); planned as planner_node does, 3.6-21 %."""
    assumed = []
    for spec in objects:
        for primitive in primitives_for(spec.shape):
            if store.model_for(spec.id, spec.object_class, primitive) is None:
                store.assume(rule_model(spec, primitive))
                assumed.append(f"{spec.id} primitive {primitive}")
    return assumed


class SimulatedPusher:
    """APPLY_ACTION without physics: the plausible rule plus Gaussian noise, seeded."""

    def __init__(self, specs: Sequence[ObjectSpec], seed: int = 0) -> None:
        self.specs = {s.id: s for s in specs}
        self.poses = {s.id: s.pose for s in specs}
        self.rng = np.random.default_rng(seed)

    def apply_action(self, object_id: str, primitive: int, push_length: float
                     ) -> tuple[np.ndarray, Pose2D]:
        expected = plausible_displacement(self.specs[object_id], primitive, push_length)
        delta = expected + self.rng.normal(0.0, plausible_spread(expected))
        pose = self.poses[object_id].apply_displacement(delta)
        self.poses[object_id] = pose
        return delta, pose


def learn_all(specs: Sequence[ObjectSpec], seed: int = 0) -> ModelStore:
    """TASK_SPACE_RRT lines 1-2: LEARN_MODEL for every object, against the simulated pusher."""
    pusher = SimulatedPusher(specs, seed)
    store = ModelStore()
    for spec in specs:
        models, _ = LEARN_MODEL(spec.id, primitives_for(spec.shape), spec.pose,
                                pusher.apply_action, ConfidenceStoppingRule())
        for model in models.values():
            store.add(model, spec.object_class)
    return store


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", required=True, help="shipped scenario name or file path")
    parser.add_argument("--out", required=True, type=Path, help="model file to write")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    scenario = load_scenario(args.scenario)
    store = learn_all(scenario.objects, args.seed)
    store.save(args.out)
    counts = [m.count for m in store.models.values()]
    print(f"wrote {len(store.models)} models ({sum(counts)} pushes) to {args.out}")


if __name__ == "__main__":
    main()
