"""The face rule (PlanningProblem.with_face_allowance): pushes may not strand objects near the
robot's base, where the arm cannot get behind them, beyond what the target itself needs."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import load_scenario
from tsrrt_planner.bench import default_models, resolve_scenario
from tsrrt_planner.lower_bound import lower_bound
from tsrrt_planner.model_learning import ModelStore
from tsrrt_planner.problem import PlanningProblem
from tsrrt_planner.task_space_rrt import (
    TASK_SPACE_RRT,
    equivalent_targets,
    interchangeable_groups,
)


@pytest.fixture(scope="module")
def clean() -> PlanningProblem:
    scenario = load_scenario("clean")
    return PlanningProblem(scenario, ModelStore.load(default_models(scenario)))


# The remote across the table (long axis along y): the arm reaches every face at x = 0.42 m;
# at 0.36 m not its back face (the approach point 4 cm behind it is too close to the base).
ACROSS = np.pi / 2
FREE, STRANDED = [0.42, 0.0, ACROSS], [0.36, 0.0, ACROSS]
TOWARDS_BASE = 3   # the remote's primitive that pushes it along -x when it lies across


def with_remote_at(problem: PlanningProblem, pose: list[float]) -> np.ndarray:
    state = problem.start.copy()
    state[problem.objects.ids.index("remote")] = pose
    return state


def test_reachable_faces_counts_approach_points_the_arm_reaches(clean):
    remote = clean.objects.ids.index("remote")
    poses = np.array([FREE, STRANDED])
    assert clean.reachable_faces(np.array([remote, remote]), poses).tolist() == [4, 3]


def test_a_push_that_strands_an_object_is_refused_unless_the_target_needs_it(clean):
    remote = clean.objects.ids.index("remote")
    start = with_remote_at(clean, FREE)
    push = (np.array([remote]), np.array([TOWARDS_BASE]), np.array([0.06]))
    after = clean.predict(start, *push)
    assert clean.reachable_faces(push[0], after).tolist() == [3]
    groups = interchangeable_groups(clean)

    strict = clean.with_face_allowance([with_remote_at(clean, FREE)], groups)
    assert strict.face_allowance[remote] == 0
    assert not strict.pushes_valid(start, *push)[0]
    # a shorter push keeps every face
    assert strict.pushes_valid(start, push[0], push[1], np.array([0.04]))[0]
    # with a target that strands the remote anyway, or with the rule off, the push is fine
    lenient = clean.with_face_allowance([with_remote_at(clean, STRANDED)], groups)
    assert lenient.face_allowance[remote] == 1
    assert lenient.pushes_valid(start, *push)[0]
    assert clean.pushes_valid(start, *push)[0]
    assert clean.face_allowance is None   # the copy carries the rule, not the original


def test_an_object_that_starts_stranded_may_stay_so_but_not_go_further_in(clean):
    """The remote stranded across the table may move sideways, but not further towards the
    base: only its back face, which the arm cannot reach, could push it back out (tset6's
    platter_2, pushed 2 cm further in, ended every such plan 2-3 % above the bound)."""
    remote = clean.objects.ids.index("remote")
    start = with_remote_at(clean, STRANDED)
    strict = clean.with_face_allowance([with_remote_at(clean, FREE)],
                                       interchangeable_groups(clean))
    pose = np.array(STRANDED)
    finals = pose + np.array([[0.0, 0.03, 0.0], [0.0, -0.02, 0.1], [-0.0005, 0.02, 0.0],
                              [-0.02, 0.0, 0.0], [-0.005, 0.03, 0.0]])
    objects = np.full(len(finals), remote)
    assert (strict.reachable_faces(objects, finals) == 3).all()
    assert strict.keeps_faces(start, objects, np.tile(pose, (len(finals), 1)),
                              finals).tolist() == [True, True, True, False, False]
    further_in = (np.array([remote]), np.array([TOWARDS_BASE]), np.array([0.02]))
    assert not strict.pushes_valid(start, *further_in)[0]
    assert clean.pushes_valid(start, *further_in)[0]   # without the rule


def test_without_the_retreat_limit_a_stranded_object_may_go_further_in_but_no_free_one_in(
        clean):
    """What the plan's finishing polish checks its pushes on: the retreat limit keeps an
    object where the search's later pushes can reach it, and the plan's end has none; the
    allowance still holds, since a replan after a divergent execution has those pushes."""
    remote = clean.objects.ids.index("remote")
    strict = clean.with_face_allowance([with_remote_at(clean, FREE)],
                                       interchangeable_groups(clean))
    finishing = strict.with_retreat_limit(math.inf)
    further_in = (np.array([remote]), np.array([TOWARDS_BASE]), np.array([0.02]))
    assert finishing.pushes_valid(with_remote_at(clean, STRANDED), *further_in)[0]
    assert not strict.pushes_valid(with_remote_at(clean, STRANDED), *further_in)[0]
    strands = (np.array([remote]), np.array([TOWARDS_BASE]), np.array([0.06]))
    assert not finishing.pushes_valid(with_remote_at(clean, FREE), *strands)[0]


# tset12's optimum (lower_bound) but for the platters' and erasers' exact places; in the far
# corner at -y plate_6 stands where the arm reaches neither face that could push it back
TSET12_NEAR_OPTIMUM = {
    "plate_1": (0.33, 0.35, 0.0), "plate_2": (0.565, 0.35, 0.0), "plate_3": (0.435, -0.35, 0.0),
    "plate_4": (0.33, -0.35, 0.0), "plate_5": (0.67, 0.35, 0.0), "plate_6": (0.67, -0.35, 0.0),
    "platter_1": (0.36, 0.0, math.pi / 2), "platter_2": (0.50, 0.0, 0.0),
    "platter_3": (0.50, -0.11, 0.0), "platter_4": (0.50, 0.11, 0.0),
    "eraser_1": (0.61, 0.20, math.pi / 2), "eraser_2": (0.50, 0.22, 0.0)}


def test_the_finishing_polish_puts_a_plate_into_the_far_corner_it_stops_short_of():
    """REARRANGE aims 2 mm inside the table's edges (TARGET_INSET) and POLISH is to close
    the gap, but 2 mm short of a far corner a plate is already stranded, and the shortest
    push (2 mm) moves it further than the retreat limit lets it: tset12's plans left their
    plates there, 0.15 % of the bound's cost each."""
    scenario = resolve_scenario("tset12")
    models = ModelStore.load(default_models(scenario))
    goal = dataclasses.replace(scenario, objects=tuple(
        dataclasses.replace(o, pose=Pose2D(*TSET12_NEAR_OPTIMUM[o.id]))
        for o in scenario.objects))
    target = PlanningProblem(goal, models).start
    plate = scenario.objects.index(scenario.object("plate_6"))
    problem = PlanningProblem(dataclasses.replace(goal, objects=tuple(
        dataclasses.replace(o, pose=Pose2D(0.668, -0.348, 0.0)) if i == plate else o
        for i, o in enumerate(goal.objects))), models)
    assert problem.short_of_faces(problem.start)[plate]

    result = TASK_SPACE_RRT(problem, "tsrrt", 0, time_budget_s=None, max_nodes=1,
                            target=target)

    assert np.abs(result.states[-1][plate, :2] - target[plate, :2]).max() < 0.0005


def test_tset6_optimum_strands_nothing():
    """A plate (a disc, so heading 0) is pushed along the table's axes, and then the arm gets
    behind all four faces even in the corners near the base; turned 45 degrees it reaches
    three there. With the random headings discs had before, every variant of the optimum
    stranded one plate. The platters fit where they keep every face, so the rule lets no
    object lose one."""
    scenario = load_scenario("tset6")
    problem = PlanningProblem(scenario, ModelStore.load(default_models(scenario)))
    bound = lower_bound(problem, starts=4)
    strict = problem.with_face_allowance(equivalent_targets(problem, bound.state),
                                         interchangeable_groups(problem))
    allowance = {object_id: strict.face_allowance[strict.face_group[i]]
                 for i, object_id in enumerate(problem.objects.ids)}
    assert allowance == {"plate_1": 0, "plate_2": 0, "plate_3": 0, "plate_4": 0,
                         "platter_1": 0, "platter_2": 0}
    corners = np.array([[0.33, -0.21], [0.33, 0.21]])
    plate = np.zeros(2, int)
    assert (problem.reachable_faces(plate, np.column_stack([corners, [0.0, 0.0]])) == 4).all()
    turned = np.column_stack([corners, [np.pi / 4, np.pi / 4]])
    assert (problem.reachable_faces(plate, turned) == 3).all()


def test_improved_plans_on_clean_strand_nothing(clean):
    """The optimum of clean keeps every face (a row across the table's centre), so no plan
    may leave an object stranded that did not start so."""
    bound = lower_bound(clean, starts=4)
    everyone = np.arange(clean.n)
    at_start = clean.reachable_faces(everyone, clean.start)
    for seed in (0, 1):
        result = TASK_SPACE_RRT(clean, "tsrrt", seed, time_budget_s=None, max_nodes=300,
                                target=bound.state)
        for state in result.states:
            faces = clean.reachable_faces(everyone, np.asarray(state))
            assert ((faces == 4) | (at_start < 4)).all()
