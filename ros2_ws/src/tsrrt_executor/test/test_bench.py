"""The benchmark's bookkeeping: trial scenarios, ground truth in perception's frame, statistics."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D, convex_polygons_separated
from tsrrt_common.scenario import parse_scenario
from tsrrt_executor.bench import (
    BENCH_CENTRE,
    STAGING_POSE,
    Trial,
    ground_truth_displacement,
    make_trials,
    one_object_document,
    statistics,
)


def test_trials_cover_every_class_and_primitive_near_the_bench_centre():
    trials = make_trials(["clean", "tset3"], 2, seed=0)
    keys = {(t.spec.object_class, t.primitive) for t in trials}
    assert keys == {(c, p) for c in ("scale", "remote", "eraser", "platter") for p in range(1, 7)
                    } | {("plate", p) for p in range(1, 5)}
    assert len(trials) == 2 * len(keys)
    for trial in trials:
        assert math.dist((trial.pose.x, trial.pose.y), BENCH_CENTRE) <= 0.02 * math.sqrt(2)
        assert abs(trial.pose.theta) <= 0.3


def test_staging_pose_is_on_the_table_and_clear_of_every_trial():
    trials = make_trials(["clean", "tset3"], 5, seed=0)
    for staged in {trial.spec.object_class: trial.spec for trial in trials}.values():
        staging = staged.footprint(STAGING_POSE)
        # parse_scenario raises if the object is not entirely on the table
        parse_scenario(one_object_document(Trial(staged, trials[0].table, 1, STAGING_POSE)),
                       "staging")
        for trial in trials:
            assert convex_polygons_separated(staging, trial.spec.footprint(trial.pose), 0.005)


def test_trial_scenario_file_has_the_object_alone_at_its_pose():
    trial = make_trials(["clean"], 2, seed=1)[7]
    scenario = parse_scenario(one_object_document(trial), "bench")
    (spec,) = scenario.objects
    assert (spec.id, spec.object_class, spec.mass, spec.friction) == (
        trial.spec.id, trial.spec.object_class, trial.spec.mass, trial.spec.friction)
    assert spec.pose == pytest.approx(trial.pose)
    assert scenario.table == trial.table.table


def test_ground_truth_displacement_is_taken_in_perceptions_frame():
    # Perception reports the box turned by pi from the simulator's heading (same pose, symmetry
    # 2): the truth must be rotated into perception's frame, not the simulator's.
    perceived_before = SimpleNamespace(theta=math.pi / 2 + math.pi)
    before = Pose2D(0.5, 0.0, math.pi / 2)
    after = Pose2D(0.5, 0.03, math.pi / 2 + 0.1)
    np.testing.assert_allclose(ground_truth_displacement(perceived_before, before, after, "box"),
                               [-0.03, 0.0, 0.1], atol=1e-12)
    disc = ground_truth_displacement(SimpleNamespace(theta=0.0), before, after, "cylinder")
    np.testing.assert_allclose(disc, [0.0, 0.03, 0.0], atol=1e-12)   # a disc has no heading


def test_statistics_need_two_samples():
    table = statistics({("eraser", 1): [np.array([0.05, 0.0, 0.0]), np.array([0.04, 0.01, 0.1])],
                        ("eraser", 2): [np.array([-0.05, 0.0, 0.0])]})
    assert list(table["eraser"]) == ["1"]
    assert table["eraser"]["1"]["mean"] == pytest.approx([0.045, 0.005, 0.05])
    assert table["eraser"]["1"]["std"][0] == pytest.approx(np.std([0.05, 0.04], ddof=1), abs=1e-5)
