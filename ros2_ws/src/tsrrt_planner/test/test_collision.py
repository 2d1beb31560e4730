"""Exact shape tests against dense point sampling of the footprints."""

from __future__ import annotations

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D
from tsrrt_common.scenario import ObjectSpec, load_scenario
from tsrrt_planner.collision import CollisionChecker, Shapes
from tsrrt_planner.kernels import segment_footprint_distance
from tsrrt_planner.objectives import ObjectSet

SPACING = 0.0005


def spec(object_id: str, shape: str, length: float, width: float, pose=(0.0, 0.0, 0.0),
         static: bool = False) -> ObjectSpec:
    return ObjectSpec(object_id, "thing", shape, length, width, 0.02, 2 if shape == "box" else 0,
                      0.2, 0.4, (0.5, 0.5, 0.5), Pose2D(*pose), static)


def boundary_points(shape: str, half: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points every SPACING along the footprint boundary, world frame (m, 2)."""
    if shape == "disc":
        count = int(2 * np.pi * half[0] / SPACING)
        angles = np.linspace(0, 2 * np.pi, count, endpoint=False)
        return pose[:2] + half[0] * np.column_stack([np.cos(angles), np.sin(angles)])
    hl, hw = half
    xs = np.arange(-hl, hl + SPACING, SPACING).clip(-hl, hl)
    ys = np.arange(-hw, hw + SPACING, SPACING).clip(-hw, hw)
    local = np.concatenate([np.column_stack([xs, np.full_like(xs, hw)]),
                            np.column_stack([xs, np.full_like(xs, -hw)]),
                            np.column_stack([np.full_like(ys, hl), ys]),
                            np.column_stack([np.full_like(ys, -hl), ys])])
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return local @ np.array([[c, s], [-s, c]]) + pose[:2]


def inside(points: np.ndarray, shape: str, half: np.ndarray, pose: np.ndarray) -> np.ndarray:
    relative = points - pose[:2]
    if shape == "disc":
        return np.linalg.norm(relative, axis=1) <= half[0]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    local = relative @ np.array([[c, -s], [s, c]])
    return np.all(np.abs(local) <= half, axis=1)


def sampled_signed_distance(shape_a, half_a, pose_a, shape_b, half_b, pose_b) -> float:
    """Overlap -> negative; else the smallest distance between sampled boundaries."""
    points_a = boundary_points(shape_a, half_a, pose_a)
    points_b = boundary_points(shape_b, half_b, pose_b)
    if inside(points_a, shape_b, half_b, pose_b).any() or inside(
            points_b, shape_a, half_a, pose_a).any():
        return -1.0
    gaps = np.linalg.norm(points_a[:, None] - points_b[None], axis=-1)
    return float(gaps.min())


def random_shape(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    if rng.random() < 0.4:
        return "disc", np.array([rng.uniform(0.02, 0.06)] * 2)
    length = rng.uniform(0.04, 0.18)
    return "box", np.array([length / 2, rng.uniform(0.02, length / 2)])


@pytest.mark.parametrize("seed", range(4))
def test_pair_signed_distance_matches_dense_sampling(seed):
    rng = np.random.default_rng(seed)
    mismatches = []
    for _ in range(40):
        (shape_a, half_a), (shape_b, half_b) = random_shape(rng), random_shape(rng)
        pose_a = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        pose_b = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(-np.pi, np.pi)])
        objects = ObjectSet(("a", "b"), ("x", "x"), np.array([half_a[0], half_b[0]]),
                            np.array([half_a[1], half_b[1]]),
                            np.array([shape_a == "disc", shape_b == "disc"]))
        shapes = Shapes(objects, [])
        exact = shapes.pair_signed_distance(np.array([0]), pose_a[None], np.array([1]),
                                            pose_b[None])[0]
        sampled = sampled_signed_distance(shape_a, half_a, pose_a, shape_b, half_b, pose_b)
        if abs(exact) < SPACING:  # touching: either answer is within resolution
            continue
        if (exact <= 0) != (sampled < 0) or (exact > 0 and abs(exact - sampled) > SPACING):
            mismatches.append((shape_a, shape_b, exact, sampled))
    assert not mismatches


@pytest.mark.parametrize("seed", range(3))
def test_segment_distance_matches_dense_sampling(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        shape, half = random_shape(rng)
        pose = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        start, end = rng.uniform(-0.15, 0.15, 2), rng.uniform(-0.15, 0.15, 2)
        exact = segment_footprint_distance(start, end, pose, half, shape == "disc")
        count = int(np.linalg.norm(end - start) / SPACING) + 2
        path = start + np.linspace(0, 1, count)[:, None] * (end - start)
        if inside(path, shape, half, pose).any():
            sampled = 0.0
        else:
            outline = boundary_points(shape, half, pose)
            sampled = float(np.linalg.norm(path[:, None] - outline[None], axis=-1).min())
        assert exact == pytest.approx(sampled, abs=SPACING)


def checker_for(specs, obstacles=(), margin=0.0) -> CollisionChecker:
    return CollisionChecker(ObjectSet.from_specs(specs), list(obstacles), (0.0, 0.0, 1.0, 1.0),
                            margin=margin)


def test_state_valid_checks_table_bounds_with_rotated_extent():
    checker = checker_for([spec("a", "box", 0.2, 0.05)])
    assert checker.state_valid(np.array([[0.101, 0.5, 0.0]]))
    assert not checker.state_valid(np.array([[0.101, 0.5, 0.3]]))  # rotated corner sticks out


def test_on_table_rows_agrees_with_the_full_check_of_a_lone_object():
    """The cheap table test (no neighbours) against state_valid, a tolerated overhang
    included: c starts 1 mm past the x_min edge and may stay there but go no further."""
    specs = [spec("a", "box", 0.2, 0.05), spec("b", "cylinder", 0.1, 0.1),
             spec("c", "box", 0.2, 0.05)]
    checker = checker_for(specs)
    checker.tolerate(np.array([[0.5, 0.5, 0.0], [0.5, 0.2, 0.0], [0.099, 0.8, 0.0]]))
    rng = np.random.default_rng(3)
    rows = rng.integers(0, 3, 400)
    poses = np.column_stack([rng.uniform(-0.05, 1.05, (400, 2)), rng.uniform(-3, 3, 400)])
    on_table = checker.on_table_rows(rows, poses)
    for row, pose, fast in zip(rows, poses, on_table, strict=True):
        alone = CollisionChecker(ObjectSet.from_specs([specs[row]]), [], (0.0, 0.0, 1.0, 1.0),
                                 margin=0.0)
        alone.table_allowance[0] = checker.table_allowance[row]
        assert fast == alone.state_valid(pose[None])
    assert 0 < on_table.sum() < 400
    np.testing.assert_array_equal(checker.on_table_rows(
        np.array([2, 2]), np.array([[0.099, 0.8, 0.0], [0.098, 0.8, 0.0]])), [True, False])


def test_margin_is_enforced_between_objects():
    specs = [spec("a", "cylinder", 0.1, 0.1), spec("b", "cylinder", 0.1, 0.1)]
    state = np.array([[0.4, 0.5, 0.0], [0.504, 0.5, 0.0]])
    assert checker_for(specs, margin=0.0).state_valid(state)
    assert not checker_for(specs, margin=0.005).state_valid(state)


def test_moved_objects_valid_agrees_with_full_check():
    scenario = load_scenario("tset6")
    checker = CollisionChecker(ObjectSet.from_specs(scenario.objects), scenario.obstacles,
                               scenario.table.bounds)
    parent = np.array([o.pose.as_array() for o in scenario.objects])
    rng = np.random.default_rng(0)
    moved = rng.integers(0, len(parent), 200)
    poses = parent[moved] + rng.normal(0, [0.05, 0.05, 0.5], (200, 3))
    fast = checker.moved_objects_valid(parent, moved, poses)
    for k in range(200):
        state = parent.copy()
        state[moved[k]] = poses[k]
        assert fast[k] == checker.state_valid(state)
    assert 0 < fast.sum() < 200


def test_obstacles_block_objects():
    obstacle = spec("wall", "box", 0.2, 0.05, (0.5, 0.5, 0.0), static=True)
    checker = checker_for([spec("a", "box", 0.1, 0.05)], [obstacle])
    assert not checker.state_valid(np.array([[0.5, 0.52, 0.0]]))
    assert checker.state_valid(np.array([[0.5, 0.6, 0.0]]))


def test_ball_path_ignores_pushed_object_but_not_others():
    specs = [spec("a", "box", 0.1, 0.05), spec("b", "cylinder", 0.1, 0.1)]
    checker = checker_for(specs)
    parent = np.array([[0.5, 0.5, 0.0], [0.5, 0.7, 0.0]])
    start, end = np.array([[0.5, 0.4]]), np.array([[0.5, 0.55]])
    assert checker.ball_paths_clear(parent, np.array([0]), start, end, 0.012)[0]
    assert not checker.ball_paths_clear(parent, np.array([0]), start, np.array([[0.5, 0.65]]),
                                        0.012)[0]


def test_constraint_jacobian_matches_finite_differences():
    scenario = load_scenario("tset6")
    checker = CollisionChecker(ObjectSet.from_specs(scenario.objects), scenario.obstacles,
                               scenario.table.bounds)
    state = np.array([o.pose.as_array() for o in scenario.objects])
    jacobian = checker.constraint_jacobian(state)
    step = 1e-6
    for column in range(state.size):
        plus, minus = state.copy().ravel(), state.copy().ravel()
        plus[column] += step
        minus[column] -= step
        expected = (checker.constraint_values(plus.reshape(state.shape))
                    - checker.constraint_values(minus.reshape(state.shape))) / (2 * step)
        np.testing.assert_allclose(jacobian[:, column], expected, atol=1e-4)


def test_tolerated_start_violations_may_shrink_but_never_deepen():
    specs = [spec("a", "cylinder", 0.1, 0.1), spec("b", "cylinder", 0.1, 0.1),
             spec("c", "box", 0.2, 0.05)]
    # a and b are 2 mm apart (margin 5 mm); c overhangs the table's x_min edge by 1 mm.
    start = np.array([[0.4, 0.5, 0.0], [0.502, 0.5, 0.0], [0.099, 0.2, 0.0]])
    checker = checker_for(specs, margin=0.005)
    assert not checker.state_valid(start)
    overlap, overhang = checker.tolerate(start)
    assert overlap == pytest.approx(0.003, abs=1e-9)
    assert overhang == pytest.approx(0.001, abs=1e-9)
    assert checker.state_valid(start)
    moves = np.array([[0.501, 0.5, 0.0],    # b closer to a: deeper, invalid
                      [0.503, 0.5, 0.0],    # b away from a: valid
                      [0.5015, 0.56, 0.0],  # b sliding past a, never closer: valid
                      [0.098, 0.2, 0.0],    # c further off the table: invalid
                      [0.105, 0.2, 0.0]])   # c back onto the table: valid
    moved = np.array([1, 1, 1, 2, 2])
    np.testing.assert_array_equal(checker.moved_objects_valid(start, moved, moves),
                                  [False, True, True, False, True])
    # Other constraints keep the full margin: c may not come within 5 mm of a.
    near_a = np.array([[0.4, 0.5 - 0.05 - 0.025 - 0.004, 0.0]])
    assert not checker.moved_objects_valid(start, np.array([2]), near_a)[0]
    # A valid state tolerates nothing.
    assert checker_for(specs, margin=0.005).tolerate(start + [[0, 0, 0], [0.1, 0, 0],
                                                              [0.05, 0, 0]]) == (0.0, 0.0)


def test_swept_valid_checks_the_way_not_only_the_end():
    # a pushes a 10-cm disc from x 0.2 to 0.6 through b at x 0.4; both ends are clear of b
    specs = [spec("a", "cylinder", 0.1, 0.1), spec("b", "cylinder", 0.1, 0.1)]
    checker = checker_for(specs, margin=0.005)
    parent = np.array([[0.2, 0.5, 0.0], [0.4, 0.5, 0.0]])
    start, change = np.array([[0.2, 0.5, 0.0]]), np.array([[0.4, 0.0, 0.0]])
    moved = np.array([0])
    assert checker.moved_objects_valid(parent, moved, start + change)[0]
    assert checker.swept_valid(parent, moved, start, change, np.array([1]))[0]
    assert not checker.swept_valid(parent, moved, start, change, np.array([40]))[0]
    # a way that moves away from b is clear at any resolution
    away = np.array([[0.4, 0.12, 0.0]])
    assert checker.swept_valid(parent, moved, start, away - start, np.array([40]))[0]
