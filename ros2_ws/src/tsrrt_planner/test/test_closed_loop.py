"""Learning in place keeps objects on the table; divergence is flagged only when unexplained."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import load_scenario
from tsrrt_executor.push_primitives import ball_path_points, push_geometry
from tsrrt_executor.reachability import default_map
from tsrrt_planner import closed_loop
from tsrrt_planner.closed_loop import (
    MIN_MEASURED_SHARE,
    ExecutionFailed,
    LearningArea,
    PredictionTracker,
    PushOutcome,
    TaskReport,
    TaskSettings,
    _negligible,
    footprint_gap,
    learn_in_place,
    plan_from,
    run_task,
    scenario_at,
    update_model_with_push,
)
from tsrrt_planner.errors import ModelError
from tsrrt_planner.lower_bound import lower_bound
from tsrrt_planner.model_learning import (
    ConfidenceStoppingRule,
    DisplacementStats,
    ForwardModel,
    MirrorCheck,
    ModelStore,
    mirrored,
)
from tsrrt_planner.problem import MAX_PLANNED_PUSH, PlanningProblem
from tsrrt_planner.push_rule import SimulatedPusher, learn_all
from tsrrt_planner.reachability import AnnulusReachability
from tsrrt_planner.task_space_rrt import TASK_SPACE_RRT


def _executor(pusher: SimulatedPusher):
    def execute(object_id: str, primitive: int, push_length: float) -> PushOutcome:
        before = pusher.poses[object_id]
        _, after = pusher.apply_action(object_id, primitive, push_length)
        return PushOutcome(before, after)
    return execute


@pytest.mark.parametrize("object_id", ["scale", "remote", "eraser"])
def test_learning_in_place_converges_and_stays_on_the_table(object_id: str) -> None:
    scenario = load_scenario("clean")
    spec = scenario.object(object_id)
    pusher = SimulatedPusher(scenario.objects, seed=3)
    visited = []

    def execute(object_id: str, primitive: int, push_length: float) -> PushOutcome:
        outcome = _executor(pusher)(object_id, primitive, push_length)
        visited.append(outcome.after)
        return outcome

    result = learn_in_place(spec, spec.pose, execute, ConfidenceStoppingRule())
    assert result.converged
    assert set(result.models) == {1, 2, 3, 4, 5, 6}
    assert result.trials == len(visited)
    x_min, y_min, x_max, y_max = scenario.table.bounds
    for pose in visited:
        assert x_min - 0.05 <= pose.x <= x_max + 0.05 and y_min - 0.05 <= pose.y <= y_max + 0.05
    # Models point the way their primitive pushes.
    assert result.models[1].mean[0] > 0 > result.models[2].mean[0]
    assert result.models[3].mean[1] > 0 > result.models[4].mean[1]
    assert result.models[5].mean[2] > 0 > result.models[6].mean[2]


def _walk_near_edge_and_neighbour(area_on: bool):
    """The eraser 3 cm from the near edge, the remote 3 cm beside it; learn and record poses."""
    scenario = load_scenario("clean")
    spec, neighbour = scenario.object("eraser"), scenario.object("remote")
    x_min = scenario.table.bounds[0]
    start = Pose2D(x_min + 0.03 + spec.length / 2.0, 0.0, 0.0)
    neighbour_pose = Pose2D(start.x, start.y + spec.width / 2.0 + 0.03 + neighbour.width / 2.0,
                            0.0)
    area = LearningArea(scenario.table, ((neighbour, neighbour_pose),), edge_margin=0.02,
                        clearance=0.015)
    pusher = SimulatedPusher(scenario.objects, seed=5)
    pusher.poses["eraser"] = start
    visited = []

    def execute(object_id: str, primitive: int, push_length: float) -> PushOutcome:
        outcome = _executor(pusher)(object_id, primitive, push_length)
        visited.append(outcome.after)
        return outcome

    result = learn_in_place(spec, start, execute, ConfidenceStoppingRule(),
                            area=area if area_on else None)
    worst_edge = min(area.edge_distance(spec, pose) for pose in visited)
    worst_gap = min(footprint_gap(spec, pose, neighbour, neighbour_pose) for pose in visited)
    return result, worst_edge, worst_gap


def test_learning_leaves_room_for_an_object_still_to_be_learned() -> None:
    """The remote's learning walk (pusher seed 0) ends 1.4 cm from the eraser, which started
    5 cm away; with the eraser still to be learned, the learned remote is pushed on until it
    is LEAVE_ROOM away again."""
    scenario = load_scenario("clean")
    remote, eraser = scenario.object("remote"), scenario.object("eraser")
    start = Pose2D(*scenario.table.center, 0.0)
    eraser_pose = Pose2D(start.x, start.y + remote.width / 2.0 + 0.05 + eraser.width / 2.0,
                         0.0)

    def learn(waiting: frozenset[str]) -> tuple[bool, float]:
        pusher = SimulatedPusher(scenario.objects, seed=0)
        pusher.poses["remote"] = start
        area = LearningArea(scenario.table, ((eraser, eraser_pose),), waiting=waiting)
        result = learn_in_place(remote, start, _executor(pusher), ConfidenceStoppingRule(),
                                area=area)
        return result.converged, footprint_gap(remote, result.pose, eraser, eraser_pose)

    converged, gap = learn(frozenset())
    assert converged and gap < closed_loop.LEAVE_ROOM   # the walk does crowd the eraser
    converged, gap = learn(frozenset({"eraser"}))
    assert converged and gap >= closed_loop.LEAVE_ROOM


def test_learning_area_keeps_the_object_off_the_edge_and_away_from_neighbours() -> None:
    result, worst_edge, worst_gap = _walk_near_edge_and_neighbour(area_on=True)
    assert result.converged and set(result.models) == {1, 2, 3, 4, 5, 6}
    # Predictions use the learned mean; the pusher's noise may cost a few millimetres.
    assert worst_edge > 0.02 - 0.006 and worst_gap > 0.015 - 0.006
    # Without the area the same walk does come closer (so the check above can fail).
    _, edge_unguarded, gap_unguarded = _walk_near_edge_and_neighbour(area_on=False)
    assert min(edge_unguarded - 0.02, gap_unguarded - 0.015) < -0.006


def test_unlearnable_primitives_are_reported_with_the_reason() -> None:
    """A neighbour on each long side leaves no room to rotate: 5 and 6 are never tried."""
    scenario = load_scenario("clean")
    spec, neighbour = scenario.object("eraser"), scenario.object("remote")
    start = Pose2D(*scenario.table.center, 0.0)
    offset = spec.width / 2.0 + 0.012 + neighbour.width / 2.0
    others = ((neighbour, Pose2D(start.x, start.y + offset, 0.0)),
              (dataclasses.replace(neighbour, id="remote_2"),
               Pose2D(start.x, start.y - offset, 0.0)))
    area = LearningArea(scenario.table, others, edge_margin=0.02, clearance=0.015)
    pusher = SimulatedPusher(scenario.objects, seed=1)
    pusher.poses["eraser"] = start
    result = learn_in_place(spec, start, _executor(pusher), ConfidenceStoppingRule(), area=area)
    assert not result.converged
    rotations = [r for r in result.skipped if r.startswith(("primitive 5:", "primitive 6:"))]
    assert len(rotations) == 2 and all("'remote" in reason for reason in rotations)


def test_learning_area_accepts_a_push_that_improves_a_tight_start() -> None:
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    area = LearningArea(scenario.table, edge_margin=0.02)
    x_min = scenario.table.bounds[0]
    tight = Pose2D(x_min + 0.005 + spec.length / 2.0, 0.0, 0.0)
    assert area.problem(spec, tight, Pose2D(tight.x + 0.04, 0.0, 0.0)) is None
    reason = area.problem(spec, tight, Pose2D(tight.x - 0.004, 0.0, 0.0))
    assert reason is not None and "table edge" in reason


def test_learning_area_keeps_pushes_within_reach() -> None:
    """A push towards the base that takes the near face's approach point inside the arm's
    minimum radius is refused; one away from the base is fine."""
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    area = LearningArea(scenario.table, reach=AnnulusReachability(0.25, 0.75))
    start = Pose2D(0.35, 0.0, 0.0)   # near face's approach point at 0.35 - 0.06 - 0.027 = 0.263
    assert area.unreachable_pushes(spec, start) == 0
    reason = area.problem(spec, start, Pose2D(0.33, 0.0, 0.0))
    assert reason is not None and "out of the arm's reach" in reason
    assert area.problem(spec, start, Pose2D(0.40, 0.0, 0.0)) is None
    # Room counts unreachable pushes, so repositioning heads back into reach.
    assert area.room(spec, Pose2D(0.31, 0.0, 0.0)) < area.room(spec, Pose2D(0.40, 0.0, 0.0)) - 0.04


def test_learning_area_counts_turns_out_of_reach_not_only_faces() -> None:
    """The clean demo's eraser, walked along its long axis into the base's dead zone: from
    there every face's approach point is still as reachable as before, but a turn is not."""
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    area = LearningArea(scenario.table, reach=default_map())
    start, dead_zone = Pose2D(0.339, 0.125, 1.809), Pose2D(0.344, 0.074, 1.819)
    lost = [p for p in (5, 6) if not default_map().reachable(ball_path_points(push_geometry(
        spec.shape, spec.length, spec.width, spec.height, dead_zone, p))).all()]
    assert lost, "the dead-zone pose must cost a turn for this test to say anything"
    reason = area.problem(spec, start, dead_zone, primitive=2)
    assert reason is not None and "out of the arm's reach" in reason
    assert area.room(spec, dead_zone) < area.room(spec, start)


def test_a_rotation_trial_must_leave_the_turn_undoable() -> None:
    """A trial of 5 may not end where 6 (which turns it back) is out of reach or blocked."""
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    after = Pose2D(0.45, 0.0, 0.3)
    back = ball_path_points(push_geometry(spec.shape, spec.length, spec.width, spec.height,
                                          after, 6))
    nearest = float(np.linalg.norm(back, axis=1).min())
    short_arm = LearningArea(scenario.table, reach=AnnulusReachability(0.2, nearest - 1e-3))
    reason = short_arm.problem(spec, after, after, primitive=5)
    assert reason is not None and "turned back from there (primitive 6)" in reason
    assert short_arm.problem(spec, after, after, primitive=3) is None
    plate = load_scenario("tset3").objects[0]
    in_the_way = Pose2D(*back[len(back) // 2], 0.0)
    blocked = LearningArea(scenario.table, ((plate, in_the_way),))
    assert "turned back" in blocked.problem(spec, after, after, primitive=5)
    assert LearningArea(scenario.table, reach=AnnulusReachability()).problem(
        spec, after, after, primitive=5) is None


def test_footprint_gap_of_boxes_and_discs() -> None:
    scenario = load_scenario("tset3")
    plate = next(o for o in scenario.objects if o.shape == "cylinder")
    box = load_scenario("clean").object("eraser")
    radius = plate.length / 2.0
    assert footprint_gap(plate, Pose2D(0, 0, 0), plate, Pose2D(2 * radius + 0.01, 0, 0)) == (
        pytest.approx(0.01))
    assert footprint_gap(box, Pose2D(0, 0, 0), plate,
                         Pose2D(box.length / 2 + radius + 0.02, 0, 0)) == pytest.approx(0.02)
    assert footprint_gap(plate, Pose2D(box.length / 2 + radius - 0.01, 0, 0), box,
                         Pose2D(0, 0, 0)) == pytest.approx(-0.01)


def test_blocked_pushes_are_skipped_and_retried_later() -> None:
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    pusher = SimulatedPusher(scenario.objects, seed=2)
    refusals = []

    def execute(object_id: str, primitive: int, push_length: float) -> PushOutcome:
        if primitive == 3 and len(refusals) < 2:
            refusals.append(primitive)
            raise ExecutionFailed(2, "ball path blocked by 'remote'", blocked=True)
        return _executor(pusher)(object_id, primitive, push_length)

    result = learn_in_place(spec, spec.pose, execute, ConfidenceStoppingRule())
    assert refusals == [3, 3] and result.converged


def test_learning_gives_up_when_every_remaining_push_is_blocked() -> None:
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    pusher = SimulatedPusher(scenario.objects, seed=2)

    def execute(object_id: str, primitive: int, push_length: float) -> PushOutcome:
        if primitive in (3, 4):
            raise ExecutionFailed(2, "out of reach", blocked=True)
        return _executor(pusher)(object_id, primitive, push_length)

    result = learn_in_place(spec, spec.pose, execute, ConfidenceStoppingRule())
    assert not result.converged and set(result.models) == {1, 2, 5, 6}


def test_learning_continues_from_prior_statistics() -> None:
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    pusher = SimulatedPusher(scenario.objects, seed=4)
    first = learn_in_place(spec, spec.pose, _executor(pusher), ConfidenceStoppingRule())
    again = learn_in_place(spec, pusher.poses["eraser"], _executor(pusher),
                           ConfidenceStoppingRule(),
                           prior=first.statistics)
    assert again.trials == 0 and again.converged
    assert again.models[1].count == first.models[1].count


def _table_executor(displacements: dict[int, list[float]], pushes: list[int]):
    """Pushes the eraser by a fixed displacement per primitive, with a small scatter (so the
    confidence rule has spread to judge), recording the primitives it was asked for."""
    poses = {"eraser": load_scenario("clean").object("eraser").pose}

    def execute(object_id: str, primitive: int, push_length: float) -> PushOutcome:
        pushes.append(primitive)
        scatter = 0.0005 * (-1) ** len(pushes)
        delta = np.array(displacements[primitive]) * push_length / 0.05 + scatter
        before = poses[object_id]
        poses[object_id] = before.apply_displacement(delta)
        return PushOutcome(before, poses[object_id])
    return execute, poses


SYMMETRIC = {1: [0.05, 0.001, 0.01], 2: [-0.05, 0.001, -0.01],
             3: [0.0, 0.05, -0.01], 4: [0.0, -0.05, 0.01],
             5: [-0.005, 0.02, 0.5], 6: [-0.005, -0.02, -0.5]}


def test_the_mirror_check_learns_each_second_primitive_from_one_confirming_trial() -> None:
    spec = load_scenario("clean").object("eraser")
    pushes: list[int] = []
    execute, poses = _table_executor(SYMMETRIC, pushes)
    rule = ConfidenceStoppingRule(0.004, 0.035)
    result = learn_in_place(spec, poses["eraser"], execute, rule, mirror=MirrorCheck())
    assert result.converged
    assert sorted(pushes) == [1, 1, 1, 2, 3, 3, 3, 4, 5, 5, 5, 6]
    assert all(result.models[p].count == 1 for p in (2, 4, 6))
    # The second of each pair is planned with its partner's mirror image until it has its own.
    store = ModelStore(result.models.values(), {"eraser": "eraser"})
    planned = store.model_for("eraser", "eraser", 4)
    assert planned.count == 3
    np.testing.assert_allclose(planned.mean, mirrored(result.models[3], 4).mean)
    # Without the check every primitive has its own rule's trials.
    pushes.clear()
    execute, poses = _table_executor(SYMMETRIC, pushes)
    assert learn_in_place(spec, poses["eraser"], execute, rule).converged
    assert len(pushes) == 18


def test_a_trial_that_does_not_mirror_its_partner_is_learned_in_full() -> None:
    spec = load_scenario("clean").object("eraser")
    lopsided = {**SYMMETRIC, 4: [0.0, -0.05, -0.04]}  # turns 2.3 deg the wrong way
    pushes: list[int] = []
    execute, poses = _table_executor(lopsided, pushes)
    rule = ConfidenceStoppingRule(0.004, 0.035)
    result = learn_in_place(spec, poses["eraser"], execute, rule, mirror=MirrorCheck())
    assert result.converged
    assert pushes.count(4) == 3 and pushes.count(2) == pushes.count(6) == 1
    np.testing.assert_allclose(result.models[4].mean[2], -0.04, atol=0.001)


def test_the_mirror_check_needs_a_partner_that_is_learned() -> None:
    rule = ConfidenceStoppingRule(0.004, 0.035)
    check = MirrorCheck()
    partner = DisplacementStats()
    own = DisplacementStats()
    own.update(np.array([-0.05, 0.001, -0.01]))
    for delta in ([0.05, 0.001, 0.01], [0.0501, 0.0012, 0.011]):
        partner.update(np.array(delta))
    assert not check.confirmed(2, {1: partner, 2: own}, rule)  # two trials: rule not met
    partner.update(np.array([0.0499, 0.0008, 0.009]))
    assert check.confirmed(2, {1: partner, 2: own}, rule)
    assert not check.confirmed(2, {1: partner, 2: DisplacementStats()}, rule)
    with pytest.raises(ModelError, match="tolerances must be > 0"):
        MirrorCheck(position_tolerance=0.0)


def test_other_execution_failures_propagate() -> None:
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")

    def execute(object_id: str, primitive: int, push_length: float) -> PushOutcome:
        raise ExecutionFailed(4, "tracking failed")

    with pytest.raises(ExecutionFailed, match="tracking failed"):
        learn_in_place(spec, spec.pose, execute, ConfidenceStoppingRule())


def test_disc_learns_only_translation_primitives() -> None:
    scenario = load_scenario("tset3")
    spec = scenario.object("plate_1")
    pusher = SimulatedPusher(scenario.objects, seed=1)
    result = learn_in_place(spec, spec.pose, _executor(pusher), ConfidenceStoppingRule())
    assert set(result.models) == {1, 2, 3, 4}


def test_learning_stops_when_cancelled() -> None:
    scenario = load_scenario("clean")
    spec = scenario.object("eraser")
    pusher = SimulatedPusher(scenario.objects, seed=0)
    calls = []
    result = learn_in_place(spec, spec.pose, _executor(pusher), ConfidenceStoppingRule(),
                            cancelled=lambda: len(calls) > 0, on_trial=calls.append)
    assert result.trials == 1 and not result.converged


def test_executed_push_updates_model_with_eq9_at_nominal_length() -> None:
    deltas = np.array([[0.040, 0.001, 0.01], [0.042, -0.002, 0.0], [0.038, 0.0, -0.01]])
    statistics = DisplacementStats()
    for delta in deltas:
        statistics.update(delta)
    store = ModelStore([ForwardModel.from_stats("eraser", 1, 0.05, statistics)],
                       {"eraser": "eraser"})
    before = Pose2D(0.4, 0.0, 0.3)
    observed = np.array([0.020, 0.001, 0.005])  # a 2.5 cm push
    after = before.apply_displacement(observed)
    update_model_with_push(store, "eraser", "eraser", 1, 0.025, PushOutcome(before, after))
    all_deltas = np.vstack([deltas, observed * 2.0])
    model = store.get("eraser", 1)
    np.testing.assert_allclose(model.mean, all_deltas.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(model.variance, all_deltas.var(axis=0), atol=1e-12)


def test_a_push_its_model_does_not_explain_is_learned_from_clipped() -> None:
    """Clipped to the divergence rule for one push: 4 mm + 3 sigma, 2 deg + 3 sigma."""
    statistics = DisplacementStats()
    for rotation in (0.001, -0.001, 0.0):
        statistics.update(np.array([0.05, 0.0, rotation]))
    store = ModelStore([ForwardModel.from_stats("eraser", 1, 0.05, statistics)],
                       {"eraser": "eraser"})
    gate = PredictionTracker(load_scenario("clean").objects)
    before = Pose2D(0.4, 0.0, 0.3)
    bumped = PushOutcome(before, before.apply_displacement(np.array([0.03, 0.0, 0.21])))
    assert update_model_with_push(store, "eraser", "eraser", 1, 0.03, bumped,
                                  gate=gate) == "clipped"
    model = store.get("eraser", 1)
    limit = math.radians(2.0) + 3.0 * math.sqrt(2e-6 / 3) * 0.6     # for a 3-cm push
    assert model.count == 4
    np.testing.assert_allclose(model.mean[2], (limit / 0.6) / 4, rtol=1e-6)
    usual = np.array([0.032, 0.002, 0.02])
    assert update_model_with_push(store, "eraser", "eraser", 1, 0.03,
                                  PushOutcome(before, before.apply_displacement(usual)),
                                  gate=gate) == "folded"
    # without the gate, or with too few trials of its own to judge by, it is folded in whole
    few = ModelStore([ForwardModel("eraser", 1, 0.05, 2, np.array([0.05, 0.0, 0.0]),
                                   np.full(3, 1e-8))], {"eraser": "eraser"})
    assert update_model_with_push(few, "eraser", "eraser", 1, 0.03, bumped,
                                  gate=gate) == "folded"
    np.testing.assert_allclose(few.get("eraser", 1).mean[2], 0.21 / 0.6 / 3, rtol=1e-9)


def test_a_push_too_short_to_measure_leaves_its_model_as_it_was() -> None:
    """A 5-mm push rescaled to 5 cm multiplies what perception sees of it by ten: a 0.5-deg
    turn would enter the model as 5 deg. Pushes under MIN_MEASURED_SHARE of the model's length
    are executed and checked, but not learned from; from that share on they are."""
    model = ForwardModel("eraser", 1, 0.05, 10, np.array([0.05, 0.0, 0.0]), np.full(3, 1e-6))
    store = ModelStore([model], {"eraser": "eraser"})
    before = Pose2D(0.4, 0.0, 0.3)
    short = MIN_MEASURED_SHARE * 0.05 * 0.9
    turned = PushOutcome(before, before.apply_displacement(np.array([short, 0.0, 0.009])))
    assert update_model_with_push(store, "eraser", "eraser", 1, short, turned) == "too short"
    assert store.get("eraser", 1) is model
    enough = MIN_MEASURED_SHARE * 0.05
    moved = PushOutcome(before, before.apply_displacement(np.array([enough, 0.0, 0.0])))
    assert update_model_with_push(store, "eraser", "eraser", 1, enough, moved) == "folded"
    assert store.get("eraser", 1).count == 11


def test_push_planned_with_a_mirrored_model_starts_the_objects_own() -> None:
    store = ModelStore([ForwardModel("eraser", 1, 0.05, 4, np.array([0.05, 0.0, 0.01]),
                                     np.full(3, 1e-6))], {"eraser": "eraser"})
    before = Pose2D(0.4, 0.0, 0.3)
    observed = np.array([-0.048, 0.001, -0.012])
    update_model_with_push(store, "eraser", "eraser", 2, 0.05,
                           PushOutcome(before, before.apply_displacement(observed)))
    own = store.get("eraser", 2)
    assert own.count == 1
    np.testing.assert_allclose(own.mean, observed, atol=1e-12)


def test_divergence_uses_accumulated_uncertainty_and_flags_unpushed_motion() -> None:
    scenario = load_scenario("clean")
    statistics = DisplacementStats()
    for dx in (0.040, 0.044, 0.036, 0.040):
        statistics.update(np.array([dx, 0.0, 0.0]))
    model = ForwardModel.from_stats("eraser", 1, 0.05, statistics)  # sigma ~2.8 mm in x
    tracker = PredictionTracker(scenario.objects, sigmas=3.0, position_floor=0.004,
                                angle_floor=math.radians(2.0))
    predicted = {o.id: o.pose for o in scenario.objects}
    tracker.pushed("eraser", model, 0.05)
    eraser = predicted["eraser"]
    within = dict(predicted, eraser=Pose2D(eraser.x + 0.010, eraser.y, eraser.theta))
    assert tracker.diverged(predicted, within) == []
    beyond = dict(predicted, eraser=Pose2D(eraser.x + 0.02, eraser.y, eraser.theta))
    [problem] = tracker.diverged(predicted, beyond)
    assert problem.object_id == "eraser" and problem.reason == "outside the model's confidence"
    remote = predicted["remote"]
    bumped = dict(predicted, remote=Pose2D(remote.x, remote.y + 0.006, remote.theta))
    [problem] = tracker.diverged(predicted, bumped)
    assert problem.object_id == "remote" and problem.reason == "moved although not pushed"
    # A half turn of a box is no change at all.
    flipped = dict(predicted, remote=Pose2D(remote.x, remote.y, remote.theta + math.pi))
    assert tracker.diverged(predicted, flipped) == []
    missing = {k: v for k, v in predicted.items() if k != "scale"}
    [problem] = tracker.diverged(predicted, missing)
    assert problem.reason == "not observed"


class _SimulatedRobot:
    """A physics-free robot for the task loop: the plausible push rule with noise, plus bumps."""

    def __init__(self, scenario, seed: int, bump_after: int | None = None) -> None:
        self.pusher = SimulatedPusher(scenario.objects, seed=seed)
        self.bump_after = bump_after
        self.pushes = 0

    def observe(self) -> dict[str, Pose2D]:
        return dict(self.pusher.poses)

    def execute(self, object_id: str, primitive: int, push_length: float) -> PushOutcome:
        before = self.pusher.poses[object_id]
        _, after = self.pusher.apply_action(object_id, primitive, push_length)
        self.pushes += 1
        if self.pushes == self.bump_after:
            # Someone bumps the table: another object slides 2 cm.
            other = next(i for i in self.pusher.poses if i != object_id)
            pose = self.pusher.poses[other]
            self.pusher.poses[other] = Pose2D(pose.x - 0.02, pose.y, pose.theta)
        return PushOutcome(before, after)


def _task(name: str, seed: int, bump_after: int | None = None):
    scenario = load_scenario(name)
    store = learn_all(scenario.objects, seed=seed)
    problem = PlanningProblem(scenario, store, AnnulusReachability())
    bound = lower_bound(problem, starts=8, seed=0)
    robot = _SimulatedRobot(scenario, seed=seed + 100, bump_after=bump_after)
    # A node budget (with a generous time limit) keeps the test independent of machine load.
    settings = TaskSettings(planning_budget_s=30.0, planning_max_nodes=300, max_pushes=60)
    report = run_task(scenario, store, robot, AnnulusReachability(), settings, bound.cost,
                      target=bound.state)
    return scenario, report


def test_a_first_plan_far_above_the_bound_is_made_again_with_the_next_seed(monkeypatch) -> None:
    """The first search is cut to its start (paper mode, 1 node: 90 % above tset3's bound); the
    task makes the first plan again with seed 1 and executes that one."""
    seeds = []

    def first_one_fails(problem, workers, mode, seed, **kwargs):
        seeds.append(seed)
        if len(seeds) == 1:
            kwargs["max_nodes"] = 1
            mode = "paper-nogd"
        return TASK_SPACE_RRT(problem, mode, seed, **kwargs)

    monkeypatch.setattr(closed_loop, "plan_in_parallel", first_one_fails)
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    bound = lower_bound(PlanningProblem(scenario, store, AnnulusReachability()), starts=8, seed=0)
    settings = TaskSettings(planning_budget_s=30.0, planning_max_nodes=150, max_pushes=30)
    plans = []
    report = run_task(scenario, store, _SimulatedRobot(scenario, seed=100), AnnulusReachability(),
                      settings, bound.cost, target=bound.state, on_plan=plans.append)
    assert seeds[:2] == [0, 1]
    assert plans[0].mode == "tsrrt" and plans[0].seed == 1 and plans[0].steps
    assert report.pushes > 0 and report.final_cost < report.start_cost


def test_the_first_plan_gets_the_first_plan_budget(monkeypatch) -> None:
    budgets, deadlines, stalls, starts = [], [], [], []

    def recording(problem, workers, mode, seed, **kwargs):
        budgets.append(kwargs["time_budget_s"])
        deadlines.append(kwargs["soft_deadline"])
        stalls.append(kwargs["stall"])
        starts.append(float(problem.objective.cost(problem.start)))
        return TASK_SPACE_RRT(problem, mode, seed, **kwargs)

    monkeypatch.setattr(closed_loop, "plan_in_parallel", recording)
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    bound = lower_bound(PlanningProblem(scenario, store, AnnulusReachability()), starts=8, seed=0)
    settings = TaskSettings(planning_budget_s=30.0, first_planning_budget_s=40.0,
                            planning_max_nodes=150, max_pushes=30)
    run_task(scenario, store, _SimulatedRobot(scenario, seed=100), AnnulusReachability(),
             settings, bound.cost, target=bound.state)
    assert len(budgets) >= 2
    assert budgets[0] == 40.0 and set(budgets[1:]) == {30.0}
    # ... but past the usual budget only while it is more than first_plan_gap above the bound
    assert deadlines[0].seconds == 30.0
    assert deadlines[0].cost == pytest.approx(bound.cost + 0.1 * abs(bound.cost))
    assert set(deadlines[1:]) == {None}
    # ... and within that gap it stops once it stalls, as later plans do near their aim
    assert stalls[0].window_s == settings.stall_s and stalls[0].ceiling == deadlines[0].cost
    scale = max(abs(starts[0]), starts[0] - bound.cost)
    assert stalls[0].tolerance == pytest.approx(settings.convergence * scale)


def test_plans_charge_their_pushes_a_share_of_the_gain_a_push_must_make(monkeypatch) -> None:
    charges = []

    def recording(problem, workers, mode, seed, **kwargs):
        charges.append((float(problem.objective.cost(problem.start)), kwargs["push_cost"]))
        return TASK_SPACE_RRT(problem, mode, seed, **kwargs)

    monkeypatch.setattr(closed_loop, "plan_in_parallel", recording)
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    bound = lower_bound(PlanningProblem(scenario, store, AnnulusReachability()), starts=8, seed=0)
    poses = {o.id: o.pose for o in scenario.objects}
    for share in (0.5, 0.0):
        settings = TaskSettings(planning_max_nodes=20, push_cost_share=share)
        plan_from(scenario, poses, store, AnnulusReachability(), settings, bound.cost,
                  bound.state, lambda: False)
    (start, charged), (_, free) = charges
    # half of `convergence` of the task's scale for every pushes_per_convergence pushes
    scale = max(abs(start), start - bound.cost)
    assert charged == pytest.approx(0.5 * settings.convergence * scale
                                    / settings.pushes_per_convergence)
    assert free == 0.0


def test_plans_search_as_many_seeds_at_once_as_the_settings_ask() -> None:
    """Worker 0 is the one-worker search (a node budget), so two workers plan no worse."""
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    bound = lower_bound(PlanningProblem(scenario, store, AnnulusReachability()), starts=8, seed=0)
    poses = {o.id: o.pose for o in scenario.objects}
    plans = [plan_from(scenario, poses, store, AnnulusReachability(),
                       TaskSettings(planning_max_nodes=40, planning_workers=workers),
                       bound.cost, bound.state, lambda: False)[1] for workers in (1, 2)]
    assert plans[0].nodes == 40 and plans[1].nodes == 80
    settings = TaskSettings()
    start = float(plans[0].costs[0])
    push_cost = (settings.push_cost_share * settings.convergence
                 * max(abs(start), start - bound.cost) / settings.pushes_per_convergence)
    charged = [plan.best_cost + push_cost * len(plan.steps) for plan in plans]
    assert charged[1] <= charged[0]


def test_task_loop_lowers_the_cost_and_converges() -> None:
    _, report = _task("tset3", seed=0)
    assert report.stop_reason in ("converged", "push budget")
    assert report.pushes > 0
    assert report.final_cost < report.start_cost
    assert len(report.costs) == report.pushes + 1
    assert len(report.visited) == report.pushes + 1


def test_task_loop_replans_after_a_bump() -> None:
    _, report = _task("tset3", seed=0, bump_after=2)
    assert report.replans >= 1
    assert any(d.reason == "moved although not pushed" for d in report.divergences)
    assert report.final_cost < report.start_cost


def test_a_task_does_not_converge_on_a_world_that_moved_while_it_planned() -> None:
    """The task starts at its optimum, so its first plan has nothing to do; while it is made,
    the platter is bumped 3 cm. Declaring convergence from the observation the plan started
    from would leave the platter where the bump put it."""
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    bound = lower_bound(PlanningProblem(scenario, store, AnnulusReachability()), starts=8,
                        seed=0)
    at_optimum = scenario_at(scenario, {spec.id: Pose2D(*bound.state[i])
                                        for i, spec in enumerate(scenario.objects)})
    robot = _SimulatedRobot(at_optimum, seed=100)
    bumped: list[Pose2D] = []

    def bump_while_planning(phase: str, report) -> None:
        if phase == "planning" and not bumped:
            pose = robot.pusher.poses["platter_1"]
            robot.pusher.poses["platter_1"] = Pose2D(pose.x - 0.03, pose.y, pose.theta)
            bumped.append(pose)

    settings = TaskSettings(planning_budget_s=30.0, planning_max_nodes=300, max_pushes=60)
    report = run_task(at_optimum, store, robot, AnnulusReachability(), settings, bound.cost,
                      target=bound.state, on_event=bump_while_planning)
    assert bumped and report.converged
    assert report.divergences[0].object_id == "platter_1"
    assert report.divergences[0].reason == "moved although not pushed"
    assert report.replans >= 1 and report.pushes >= 1
    problem = PlanningProblem(at_optimum, store, AnnulusReachability())
    true_state = np.array([robot.pusher.poses[o.id].as_array() for o in scenario.objects])
    assert report.final_cost == pytest.approx(float(problem.objective.cost(true_state)))
    # pushed back: less than half of what the bump cost (distance_to_point, weight 2, 3 cm)
    assert report.final_cost - bound.cost < 0.5 * 2.0 * 0.03


def test_a_replan_is_given_the_plan_it_replaces(monkeypatch) -> None:
    import tsrrt_planner.closed_loop as closed_loop

    calls = []
    real_plan_from = closed_loop.plan_from

    def recording_plan_from(*args, **kwargs):
        problem, result = real_plan_from(*args, **kwargs)
        calls.append((kwargs.get("replaced"), result, kwargs.get("good_enough_cost"),
                      kwargs.get("stall"), kwargs.get("give_up")))
        return problem, result

    monkeypatch.setattr(closed_loop, "plan_from", recording_plan_from)
    _, report = _task("tset3", seed=0, bump_after=2)
    assert report.replans >= 1
    # the first plan has no aim (plan_from stalls it within first_plan_gap of the bound); later
    # ones stop when they stall for 2 s, at 1 % of the task's range (the larger scale here), a
    # replan only near what it replaces promised
    assert calls[0][0] is None and calls[0][2] is None and calls[0][3] is None
    task_range = report.start_cost - report.lower_bound
    promised = float(np.min(calls[1][0][0].costs))
    stall = calls[1][3]
    assert (stall.window_s, stall.tolerance) == pytest.approx((2.0, 0.01 * task_range))
    assert stall.ceiling == pytest.approx(promised + 0.01 * task_range)
    # ... and above that only after 3 s without such a gain, once it has one worth executing
    assert stall.far_window_s == pytest.approx(3.0)
    assert stall.far_below == pytest.approx(float(calls[1][1].costs[0]) - 0.01 * task_range)
    # a fresh plan after the first stalls only near the lower bound
    fresh = [call for k, call in enumerate(calls) if k > 0 and call[0] is None]
    assert fresh, "the task ended without a fresh plan after its first"
    assert fresh[0][3].ceiling - fresh[0][3].tolerance == pytest.approx(report.lower_bound)
    # a plan after the first gives up after 4 s without a gain worth executing (1 % of the
    # larger of its start cost and the task's range); a replan only when it starts within 6
    # such gains of the best cost promised so far (not mid-way through a detour)
    assert calls[0][4] is None
    for k, (replaced_plan, result, _, _, give_up) in enumerate(calls[1:], start=1):
        start = float(result.costs[0])
        worth = 0.01 * max(abs(start), task_range)
        promised_before = min(float(np.min(call[1].costs)) for call in calls[:k])
        if replaced_plan is not None and start - promised_before > 6 * worth:
            assert give_up is None
            continue
        assert give_up.seconds == 4.0
        assert give_up.cost == pytest.approx(start - worth)
    assert calls[1][4] is None    # the bump left the replan far above the promise
    replaced, executed = calls[1][0]
    assert replaced is calls[0][1] and executed == 2   # the bump came after the second push
    # the replan may stop once it is within `convergence` (1 %) of what the replaced plan
    # promised
    assert calls[1][2] == pytest.approx(promised + 0.01 * abs(promised))


def test_a_long_plan_after_the_first_must_gain_convergence_for_every_ten_pushes() -> None:
    report = TaskReport(lower_bound=0.08, start_cost=0.38)   # range 0.3: convergence is 0.003
    settings = TaskSettings()
    assert not _negligible(0.0035, 0.09, report, settings)              # the first plan
    assert not _negligible(0.0035, 0.09, report, settings, pushes=10)
    assert _negligible(0.0035, 0.09, report, settings, pushes=20)      # needs 0.006
    assert not _negligible(0.0065, 0.09, report, settings, pushes=20)
    assert _negligible(0.0029, 0.09, report, settings, pushes=3)       # below 0.003 anyway


def test_improvement_is_judged_against_the_task_range_when_the_optimum_is_zero() -> None:
    """Figures of a real run (two boxes pushed to points: optimum 0, start 0.16): at a cost of
    0.0018 a plan promised 0.0005 more through nine pushes that went up to 0.22 and back. That
    is below 1 % of the task's range, so it is not worth executing; a plan from 0.028 that gains
    0.027 is. With a negative optimum (tset3-like costs) the rule is 1 % of the cost as before."""
    from tsrrt_planner.closed_loop import TaskReport, _negligible

    settings = TaskSettings(convergence=0.01)
    zero_optimum = TaskReport(start_cost=0.16, lower_bound=0.0)
    assert _negligible(0.0005, 0.0018, zero_optimum, settings)
    assert not _negligible(0.027, 0.028, zero_optimum, settings)
    no_bound = TaskReport(start_cost=0.16)
    assert not _negligible(0.0005, 0.0018, no_bound, settings)
    tset3 = TaskReport(start_cost=-0.044, lower_bound=-0.484)
    assert _negligible(0.004, -0.37, tset3, settings)
    assert not _negligible(0.005, -0.37, tset3, settings)


class _RobotBumpingThePushedObject(_SimulatedRobot):
    """The table is bumped during the second push: the pushed object itself ends 3 cm aside."""

    def execute(self, object_id: str, primitive: int, push_length: float) -> PushOutcome:
        outcome = super().execute(object_id, primitive, push_length)
        if self.pushes != 2:
            return outcome
        pose = self.pusher.poses[object_id]
        self.pusher.poses[object_id] = Pose2D(pose.x, pose.y + 0.03, pose.theta)
        return PushOutcome(outcome.before, self.pusher.poses[object_id])


def test_task_loop_replans_when_the_pushed_object_itself_is_bumped() -> None:
    """The bumped push must be judged by the model the plan used: folded into the model first,
    an outlier with few samples widens its own tolerance and passes as noise."""
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    # Few samples, as a robot learns them (min_trials 3): a bump weighs on the variance.
    for (object_id, primitive), model in list(store.models.items()):
        few = DisplacementStats(3, model.mean.copy(), model.m2 * 2.0 / max(model.count - 1, 1))
        store.add(ForwardModel.from_stats(object_id, primitive, model.push_length, few),
                  store.classes[object_id])
    problem = PlanningProblem(scenario, store, AnnulusReachability())
    bound = lower_bound(problem, starts=8, seed=0)
    robot = _RobotBumpingThePushedObject(scenario, seed=100)
    # Three pushes: the bumped one and the check after it are all this test needs.
    settings = TaskSettings(planning_budget_s=30.0, planning_max_nodes=300, max_pushes=3)
    report = run_task(scenario, store, robot, AnnulusReachability(), settings, bound.cost,
                      target=bound.state)
    assert report.pushes >= 2
    assert any(d.reason == "outside the model's confidence" for d in report.divergences)
    assert report.replans >= 1


class _RobotTurningOnLongPushes(_SimulatedRobot):
    """Pushes longer than `longer_than` turn their object 0.2 rad more than the push rule says,
    as the eraser's worst 10-cm pushes did in the simulator: not linear in the push length."""

    def __init__(self, scenario, seed: int, longer_than: float) -> None:
        super().__init__(scenario, seed)
        self.longer_than = longer_than

    def execute(self, object_id: str, primitive: int, push_length: float) -> PushOutcome:
        outcome = super().execute(object_id, primitive, push_length)
        if push_length <= self.longer_than:
            return outcome
        pose = self.pusher.poses[object_id]
        self.pusher.poses[object_id] = Pose2D(pose.x, pose.y, pose.theta + 0.2)
        return PushOutcome(outcome.before, self.pusher.poses[object_id])


@pytest.mark.parametrize("length,longer_than,capped", [
    (0.08, 0.06, True),     # a long push that turned the object off: held to 5 cm
    (0.05, 0.0, False),     # the same miss at the learned length: the model says nothing longer
    (0.08, 1.0, False),     # a long push off in position only (the plan expected no motion)
])
def test_an_object_whose_long_push_turned_it_off_is_held_to_the_learned_length(
        monkeypatch, length: float, longer_than: float, capped: bool) -> None:
    """A plan of one platter_1 push whose predicted states stand still, so that the task
    replans after it; the next plan is empty. The cap must reach the next plan's problem and
    the model file (saved through on_model_update)."""
    from tsrrt_planner.task_space_rrt import PlanResult, PlanStep

    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    robot = _RobotTurningOnLongPushes(scenario, seed=1, longer_than=longer_than)
    platter = [o.id for o in scenario.objects].index("platter_1")
    start = PlanningProblem(scenario_at(scenario, robot.observe()), store, AnnulusReachability())
    primitive = next(p for p in range(1, 5) if start.pushes_valid(
        start.start, np.array([platter]), np.array([p]), np.array([0.08]))[0])
    longest: list[float] = []

    def scripted_plan_from(scenario_, poses, store_, *args, **kwargs):
        problem = PlanningProblem(scenario_at(scenario_, poses), store_, AnnulusReachability())
        longest.append(float(problem.max_lengths[platter]))
        steps = () if robot.pushes else (PlanStep("platter_1", primitive, length),)
        states = np.stack([problem.start] * (len(steps) + 1))
        costs = np.array([float(problem.objective.cost(problem.start))] * (len(steps) + 1))
        costs[1:] -= 0.5
        return problem, PlanResult("tsrrt", 0, steps, states, costs, 1, 0.0, (), "time")

    monkeypatch.setattr(closed_loop, "plan_from", scripted_plan_from)
    monkeypatch.setattr(closed_loop, "execution_noise_cost", lambda *args: 0.0)
    saved: list[dict[str, float]] = []
    report = run_task(scenario, store, robot, AnnulusReachability(), TaskSettings(), -10.0,
                      on_model_update=lambda: saved.append(dict(store.push_caps)))
    assert report.pushes == 1 and report.replans >= 1
    learned = store.get("platter_1", primitive).push_length
    assert longest[0] == MAX_PLANNED_PUSH
    if capped:
        assert report.capped == ["platter_1"] and store.push_caps == {"platter_1": learned}
        assert longest[-1] == learned and saved[-1] == {"platter_1": learned}
    else:
        assert report.capped == [] and store.push_caps == {} and longest[-1] == MAX_PLANNED_PUSH


class _RobotRefusingTheFirstPush(_SimulatedRobot):
    """The executor refuses the first push before moving (UNREACHABLE from the observed pose),
    or with `failure` fails it another way."""

    def __init__(self, scenario, seed: int, failure: ExecutionFailed | None = None) -> None:
        super().__init__(scenario, seed)
        self.refused = 0
        self.failure = failure

    def execute(self, object_id: str, primitive: int, push_length: float) -> PushOutcome:
        if self.refused == 0:
            self.refused += 1
            raise self.failure or ExecutionFailed(
                2, f"primitive {primitive} on {object_id!r}: out of reach", blocked=True)
        return super().execute(object_id, primitive, push_length)


def test_task_loop_replans_when_a_push_is_refused() -> None:
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    bound = lower_bound(PlanningProblem(scenario, store, AnnulusReachability()), starts=8, seed=0)
    robot = _RobotRefusingTheFirstPush(scenario, seed=100)
    settings = TaskSettings(planning_budget_s=30.0, planning_max_nodes=300, max_pushes=2)
    report = run_task(scenario, store, robot, AnnulusReachability(), settings, bound.cost,
                      target=bound.state)
    assert robot.refused == 1 and report.replans >= 1
    assert report.divergences[0].reason.startswith("push refused: primitive")
    assert report.pushes == 2   # the task went on after the refusal


class _RobotRefusingOnePushWhereItStands(_SimulatedRobot):
    """The executor refuses the first push it is sent, and the same push again whenever it is
    sent from the same scene (every object within 1 mm): its check sees the same geometry."""

    def __init__(self, scenario, seed: int) -> None:
        super().__init__(scenario, seed)
        self.refusals: list[tuple[str, int]] = []
        self.refused_where: tuple[str, int, dict[str, Pose2D]] | None = None

    def execute(self, object_id: str, primitive: int, push_length: float) -> PushOutcome:
        poses = self.observe()
        if self.refused_where is None:
            self.refused_where = (object_id, primitive, poses)
        refused_id, refused_primitive, where = self.refused_where
        same_scene = all(math.dist(poses[i].as_array()[:2], where[i].as_array()[:2]) < 0.001
                         for i in poses)
        if (object_id, primitive) == (refused_id, refused_primitive) and same_scene:
            self.refusals.append((object_id, primitive))
            raise ExecutionFailed(2, f"primitive {primitive} on {object_id!r}: the approach or "
                                     "push path of the ball is blocked", blocked=True)
        return super().execute(object_id, primitive, push_length)


def test_a_refused_push_is_not_planned_again_from_the_scene_it_was_refused_in() -> None:
    """A tset6 demo's replan put back the push the executor had refused two pushes before, from
    the same scene to 0.3 mm, and it was refused again."""
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    problem = PlanningProblem(scenario, store, AnnulusReachability())
    state = problem.start
    lengths = np.full(len(problem.action_objects), 0.02)

    def valid(at: np.ndarray, of: PlanningProblem = problem) -> np.ndarray:
        return of.pushes_valid(at, problem.action_objects, problem.action_primitives, lengths)

    before = valid(state)
    k = int(np.argmax(before))
    assert before[k]
    problem.refuse(int(problem.action_objects[k]), int(problem.action_primitives[k]), state)
    after = valid(state)
    assert not after[k]
    np.testing.assert_array_equal(np.delete(after, k), np.delete(before, k))
    # 2 mm off, the same scene as the executor sees it; 1 cm off, the push is planned again
    fresh = PlanningProblem(scenario, store, AnnulusReachability())
    for offset, refused in ((0.002, True), (0.01, False)):
        nearby = state.copy()
        nearby[int(problem.action_objects[k]), 0] += offset
        assert valid(nearby)[k] == (not refused and valid(nearby, fresh)[k])

    robot = _RobotRefusingOnePushWhereItStands(scenario, seed=100)
    bound = lower_bound(fresh, starts=8, seed=0)
    settings = TaskSettings(planning_budget_s=30.0, planning_max_nodes=300, max_pushes=2)
    report = run_task(scenario, store, robot, AnnulusReachability(), settings, bound.cost,
                      target=bound.state)
    assert len(robot.refusals) == 1 and report.replans == 1 and report.pushes == 2


def test_task_loop_replans_after_a_push_stopped_part_way_and_stops_on_a_lost_object() -> None:
    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    bound = lower_bound(PlanningProblem(scenario, store, AnnulusReachability()), starts=8, seed=0)
    settings = TaskSettings(planning_budget_s=30.0, planning_max_nodes=300, max_pushes=2)
    tracking = ExecutionFailed(4, "tool error 12.1 mm exceeds max_tool_error", recoverable=True)
    robot = _RobotRefusingTheFirstPush(scenario, seed=100, failure=tracking)
    report = run_task(scenario, store, robot, AnnulusReachability(), settings, bound.cost,
                      target=bound.state)
    assert report.replans >= 1 and report.pushes == 2
    lost = ExecutionFailed(5, "'plate_1' is lost or missing in the settled observation")
    with pytest.raises(ExecutionFailed, match="lost"):
        run_task(scenario, store, _RobotRefusingTheFirstPush(scenario, seed=100, failure=lost),
                 AnnulusReachability(), settings, bound.cost, target=bound.state)


def test_a_replan_aims_at_the_best_any_plan_of_the_task_promised(monkeypatch) -> None:
    """Plans (scripted) whose first push always diverges: the first promises 0.5 below the
    start, the replan after it only 0.1. The next replan may stop (`good_enough_cost`) only near
    the first promise, not near the second, which the observed state could already meet."""
    import tsrrt_planner.closed_loop as closed_loop
    from tsrrt_planner.task_space_rrt import PlanResult, PlanStep

    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    robot = _SimulatedRobot(scenario, seed=1)
    problem = PlanningProblem(scenario, store, AnnulusReachability())
    now = float(problem.objective.cost(problem.start))
    gains = iter([0.5, 0.1])
    aims: list[float | None] = []

    def scripted_plan_from(scenario_, poses, *args, **kwargs):
        aims.append(kwargs.get("good_enough_cost"))
        gain = next(gains, 0.0)
        steps = (PlanStep("platter_1", 3, 0.05),) if gain else ()
        # predicted states that stand still: the executed push diverges from them
        states = np.stack([problem.start] * (len(steps) + 1))
        costs = np.array([now] + [now - gain] * len(steps))
        return problem, PlanResult("tsrrt", 0, steps, states, costs, 1, 0.0, (), "time")

    monkeypatch.setattr(closed_loop, "plan_from", scripted_plan_from)
    monkeypatch.setattr(closed_loop, "execution_noise_cost", lambda *args: 0.0)
    # a bound the first plan gets within 20 % of (else it would be made twice: the retry rule)
    report = run_task(scenario, store, robot, AnnulusReachability(), TaskSettings(), now - 0.55)
    assert report.replans == 2 and len(aims) == 3
    assert aims[0] is None
    best = now - 0.5
    assert aims[1] == pytest.approx(best + 0.01 * abs(best))
    assert aims[2] == pytest.approx(best + 0.01 * abs(best))


def _tset3_with_fake_plans():
    """tset3 as a simulated robot observes it, a maker of plans of platter_1 pushes with given
    cost changes from there (`fake_plan`), the start cost and the execution noise of a 6-push
    plan: for tests of how the task loop treats a plan of a given shape."""
    from tsrrt_planner.closed_loop import execution_noise_cost
    from tsrrt_planner.task_space_rrt import PlanResult, PlanStep

    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    robot = _SimulatedRobot(scenario, seed=1)
    start = np.array([robot.observe()[o.id].as_array() for o in scenario.objects])
    problem = PlanningProblem(scenario, store, AnnulusReachability())
    now = float(problem.objective.cost(start))

    def fake_plan(costs) -> PlanResult:
        steps = tuple(PlanStep("platter_1", 3, 0.05) for _ in costs)
        return PlanResult("tsrrt", 0, steps, np.stack([start] * (len(costs) + 1)),
                          np.array([now] + [now + c for c in costs]), 1, 0.0, (), "time")

    noise = execution_noise_cost(problem, fake_plan([0.0] * 6 + [-1e-9]), store)
    return scenario, store, robot, problem, fake_plan, now, noise


def test_a_plan_that_detours_for_less_than_its_errors_cost_is_not_executed(monkeypatch) -> None:
    """A plan that parks an object (cost up by 10 times its gain) to win less than its pushes'
    errors cost is not executed: the task stops. The same plan winning more than its errors
    cost is, and of a plan that first gains and then detours for too little only the first
    part (however much the first part gains)."""
    scenario, store, robot, problem, fake_plan, now, noise = _tset3_with_fake_plans()

    def plan(costs):
        def fake_plan_from(scenario_, poses, *args, **kwargs):
            return problem, fake_plan(costs)
        return fake_plan_from

    assert noise > 0.0
    settings = TaskSettings(max_pushes=1)
    small, large = [0.0] * 5 + [10 * noise, -noise / 2], [0.0] * 5 + [10 * noise, -2 * noise]
    monkeypatch.setattr(closed_loop, "plan_from", plan(small))
    report = run_task(scenario, store, robot, AnnulusReachability(), settings, -1.0)
    assert report.converged and report.pushes == 0
    assert report.predicted_cost == report.final_cost   # the detour was not executed
    monkeypatch.setattr(closed_loop, "plan_from", plan(large))
    first_planned: list[int] = []
    run_task(scenario, store, robot, AnnulusReachability(), TaskSettings(max_pushes=7), -1.0,
             on_event=lambda phase, report: first_planned.append(report.planned)
             if phase == "executing" and report.pushes == 0 else None)
    assert first_planned == [7]
    monkeypatch.setattr(closed_loop, "plan_from",
                        plan([-0.02, 0.0, 0.0, 0.0, 0.0, 0.2, -0.02 - noise / 2]))
    report = run_task(scenario, store, robot, AnnulusReachability(),
                      TaskSettings(max_pushes=5), -1.0)
    assert report.planned == 1


def test_a_first_plan_whose_gain_is_all_in_a_detour_is_made_again(monkeypatch) -> None:
    """The first plan's whole gain lies behind a detour its pushes' errors would eat: nothing
    of it is worth executing, but the task is far from converged (the soak's 24-push plan for a
    one-push task, CI). A second search with the next seed finds a direct plan, executed."""
    scenario, store, robot, problem, fake_plan, now, noise = _tset3_with_fake_plans()
    detour, direct = [0.0] * 5 + [10 * noise, -0.9 * noise], [-0.9 * noise]
    seeds: list[int] = []

    def fake_plan_from(scenario_, poses, store_, reachability, settings, *args, **kwargs):
        seeds.append(settings.seed)
        return problem, fake_plan(detour if settings.seed == 0 else direct)

    monkeypatch.setattr(closed_loop, "plan_from", fake_plan_from)
    bound = now - noise   # a task range of `noise`: the gain is 90 % of it
    settings = TaskSettings(max_pushes=1)
    assert 0.9 * noise > settings.convergence * max(abs(now), noise)
    report = run_task(scenario, store, robot, AnnulusReachability(), settings, bound)
    assert seeds == [0, 1]
    assert report.pushes == 1 and report.stop_reason == "push budget"
    assert report.predicted_cost == pytest.approx(now - 0.9 * noise)


def test_a_plan_longer_than_the_push_budget_left_goes_to_the_best_state_within_it(
        monkeypatch) -> None:
    """Not half-way into a detour: of a plan down, up and down again, with 4 pushes left the
    task executes the first 2 (the best state within 4); it stops on the push budget."""
    from tsrrt_planner.task_space_rrt import PlanResult, PlanStep

    scenario = load_scenario("tset3")
    store = learn_all(scenario.objects, seed=0)
    problem = PlanningProblem(scenario, store, AnnulusReachability())
    robot = _SimulatedRobot(scenario, seed=100)
    now = float(problem.objective.cost(problem.start))
    costs = np.array([now, now - 0.02, now - 0.04, now + 0.2, now + 0.3, now - 0.1])
    plan = PlanResult("tsrrt", 0, tuple(PlanStep("platter_1", 3, 0.01) for _ in costs[1:]),
                      np.stack([problem.start] * len(costs)), costs, 1, 0.0, (), "time")
    monkeypatch.setattr(closed_loop, "plan_from", lambda *args, **kwargs: (problem, plan))
    monkeypatch.setattr(closed_loop, "execution_noise_cost", lambda *args: 1.0)
    planned: list[int] = []

    def on_event(phase: str, report) -> None:
        if phase == "executing" and report.pushes == 0:
            planned.append(report.planned)

    report = run_task(scenario, store, robot, AnnulusReachability(),
                      TaskSettings(max_pushes=4, detour_max_climb=1e9), -1.0, on_event=on_event)
    assert planned[0] == 2
    assert report.pushes <= 4 and report.stop_reason == "push budget" and not report.converged


def test_a_detour_is_cut_before_the_climb_only_when_it_gains_less_than_its_errors_cost(
) -> None:
    """Two boxes (a real run): from 0.004 a plan went up to 0.3 to win 0.003, and executed, it
    walked the boxes away from the goal; cut before the climb, one push is left. The same
    climb for a gain larger than the errors is a way round or out, and is executed (session
    7: clean was cut to nothing at 144 % above the bound, the obstacle task 13 cm from its
    goal, by a rule that looked at the climb alone)."""
    from tsrrt_planner.closed_loop import steps_worth_executing

    settings = TaskSettings(detour_max_climb=2.0)
    polish = np.array([0.004, 0.0035, 0.1, 0.3, 0.05, 0.001])
    assert steps_worth_executing(polish, settings, noise_cost=0.005) == 1
    assert steps_worth_executing(polish, settings, noise_cost=0.001) == 5
    aside = np.array([-0.371, -0.38, -0.30, -0.25, -0.40, -0.482])
    assert steps_worth_executing(aside, settings, noise_cost=0.005) == 5
    straight = np.array([0.004, 0.003, 0.001])
    assert steps_worth_executing(straight, settings, noise_cost=0.005) == 2
    # a first part that gains more than the errors cost by itself goes first
    gain_then_detour = np.array([0.3, 0.2, 0.1, 0.5, 0.05])
    assert steps_worth_executing(gain_then_detour, settings, noise_cost=0.01) == 2
    little_then_detour = np.array([0.3, 0.28, 0.9, 0.1])
    assert steps_worth_executing(little_then_detour, settings, noise_cost=0.05) == 3
    assert steps_worth_executing(little_then_detour, settings, noise_cost=0.01) == 1


def test_execution_noise_cost_grows_with_the_pushes_and_their_variance() -> None:
    """No pushes, no noise; more pushes of the same primitive, more; a noisier model, more."""
    from tsrrt_planner.closed_loop import execution_noise_cost
    from tsrrt_planner.task_space_rrt import PlanResult, PlanStep

    scenario = load_scenario("clean")
    store = learn_all(scenario.objects, seed=0)
    problem = PlanningProblem(scenario, store, AnnulusReachability())
    start = problem.start

    def cost_of(pushes: int, model_store: ModelStore) -> float:
        steps = tuple(PlanStep("remote", 1, 0.05) for _ in range(pushes))
        costs = np.linspace(1.0, 0.0, pushes + 1)   # best at the end
        plan = PlanResult("tsrrt", 0, steps, np.stack([start] * (pushes + 1)), costs, 1, 0.0,
                          (), "time")
        return execution_noise_cost(problem, plan, model_store)

    assert cost_of(0, store) == 0.0
    assert 0.0 < cost_of(1, store) < cost_of(4, store) < cost_of(16, store)
    noisier = ModelStore(store.models.values(), store.classes)
    model = noisier.get("remote", 1)
    noisier.add(dataclasses.replace(model, m2=model.m2 * 16.0))
    assert cost_of(4, noisier) > cost_of(4, store)
