"""Primitive geometry (Fig. 5) against hand-computed points, and the free-path checks."""

import math

import numpy as np
import pytest

from tsrrt_common.geometry import Pose2D, footprint_polygon
from tsrrt_executor.errors import PrimitiveError
from tsrrt_executor.push_primitives import (
    APPROACH_CLEARANCE,
    BACK_OFF,
    BOX_PRIMITIVES,
    DISC_PRIMITIVES,
    ball_path_is_clear,
    check_primitive,
    hand_clears_objects,
    points_to_polygon_distance,
    primitives_for,
    push_geometry,
    push_height,
    safe_transit_height,
    workspace_segments,
)

R = 0.012  # ball radius
ERASER = ("box", 0.12, 0.05, 0.03)


def eraser_push(primitive, pose=None, push_length=0.05):
    pose = pose or Pose2D(0.45, 0.1, 0.0)
    return push_geometry(*ERASER, pose, primitive, push_length, ball_radius=R)


@pytest.mark.parametrize("primitive, contact, direction", [
    (1, (0.39, 0.10), (1.0, 0.0)),
    (2, (0.51, 0.10), (-1.0, 0.0)),
    (3, (0.45, 0.075), (0.0, 1.0)),
    (4, (0.45, 0.125), (0.0, -1.0)),
    (5, (0.45 + 0.054, 0.075), (0.0, 1.0)),
    (6, (0.45 + 0.054, 0.125), (0.0, -1.0)),
])
def test_box_contact_points_axis_aligned(primitive, contact, direction):
    geometry = eraser_push(primitive)
    np.testing.assert_allclose(geometry.contact_xy, contact, atol=1e-12)
    np.testing.assert_allclose(geometry.direction_xy, direction, atol=1e-12)


def test_box_contact_points_rotated_quarter_turn():
    # Object x axis along world +y: object (a, b) maps to world (0.45 - b, 0.1 + a).
    pose = Pose2D(0.45, 0.1, math.pi / 2)
    one = eraser_push(1, pose)
    np.testing.assert_allclose(one.contact_xy, (0.45, 0.04), atol=1e-12)
    np.testing.assert_allclose(one.direction_xy, (0.0, 1.0), atol=1e-12)
    five = eraser_push(5, pose)
    np.testing.assert_allclose(five.contact_xy, (0.475, 0.154), atol=1e-12)
    np.testing.assert_allclose(five.direction_xy, (-1.0, 0.0), atol=1e-12)


@pytest.mark.parametrize("theta", [0.0, 0.7, -2.5])
def test_rotation_primitives_turn_the_intended_way(theta):
    pose = Pose2D(0.4, -0.05, theta)
    for primitive, sign in ((5, 1.0), (6, -1.0)):
        geometry = eraser_push(primitive, pose)
        lever = np.array(geometry.contact_xy) - [pose.x, pose.y]
        torque = lever[0] * geometry.direction_xy[1] - lever[1] * geometry.direction_xy[0]
        assert sign * torque > 0.0


def test_ball_points_along_the_push():
    geometry = eraser_push(3, push_length=0.04)
    contact = np.array(geometry.contact_xy)
    direction = geometry.direction
    np.testing.assert_allclose(geometry.touch_xy, contact - R * direction, atol=1e-12)
    np.testing.assert_allclose(geometry.approach_xy,
                               contact - (R + APPROACH_CLEARANCE) * direction, atol=1e-12)
    np.testing.assert_allclose(geometry.end_xy, contact + (0.04 - R) * direction, atol=1e-12)
    np.testing.assert_allclose(geometry.retreat_point[:2], np.array(geometry.end_xy)
                               - BACK_OFF * direction, atol=1e-12)
    assert geometry.push_travel == pytest.approx(0.04 + APPROACH_CLEARANCE)
    assert geometry.pre_approach_point[2] == pytest.approx(0.10)


def test_disc_primitives_push_at_the_rim():
    geometry = push_geometry("cylinder", 0.10, 0.10, 0.015, Pose2D(0.5, 0.0, 0.3), 2)
    expected_contact = (0.5 + 0.05 * math.cos(0.3), 0.05 * math.sin(0.3))
    np.testing.assert_allclose(geometry.contact_xy, expected_contact, atol=1e-12)
    assert primitives_for("cylinder") == DISC_PRIMITIVES == (1, 2, 3, 4)
    assert primitives_for("box") == BOX_PRIMITIVES == (1, 2, 3, 4, 5, 6)


@pytest.mark.parametrize("primitive", [5, 6])
def test_rotation_primitives_do_not_exist_for_discs(primitive):
    with pytest.raises(PrimitiveError, match="does not exist for a disc"):
        push_geometry("cylinder", 0.10, 0.10, 0.015, Pose2D(0.5, 0.0, 0.0), primitive)


@pytest.mark.parametrize("shape, primitive", [("box", 0), ("box", 7), ("cylinder", 7)])
def test_out_of_range_primitives_rejected(shape, primitive):
    with pytest.raises(PrimitiveError, match="not one of"):
        check_primitive(shape, primitive)


def test_unknown_shape_rejected():
    with pytest.raises(PrimitiveError, match="unknown shape 'sphere'"):
        primitives_for("sphere")


@pytest.mark.parametrize("push_length", [0.0, -0.01, 0.16, float("nan")])
def test_bad_push_lengths_rejected(push_length):
    with pytest.raises(PrimitiveError, match="push length"):
        eraser_push(1, push_length=push_length)


def test_safe_height_must_be_above_push_height():
    with pytest.raises(PrimitiveError, match="safe height"):
        push_geometry(*ERASER, Pose2D(0.45, 0.0, 0.0), 1, safe_height=0.01)


@pytest.mark.parametrize("height, expected", [
    (0.015, 0.014),   # plate: ball kept 2 mm above the table
    (0.03, 0.015),    # eraser: half height
    (0.06, 0.03),     # hole punch: capped so it slides instead of tipping
])
def test_push_height(height, expected):
    assert push_height(height, R) == pytest.approx(expected)


def test_safe_transit_height_clears_tallest_object():
    assert safe_transit_height([0.02, 0.03]) == pytest.approx(0.10)
    assert safe_transit_height([0.02, 0.09]) == pytest.approx(0.09 + R + 0.02)


def test_workspace_segments_descend_push_back_off_retreat():
    geometry = eraser_push(1)
    segments = workspace_segments(geometry)
    assert [s.name for s in segments] == ["descend", "push", "back_off", "retreat"]
    descend, push, back_off, retreat = segments
    np.testing.assert_allclose(descend.start, geometry.pre_approach_point)
    assert descend.start[2] == pytest.approx(geometry.safe_z)
    np.testing.assert_allclose(descend.start[:2], descend.end[:2])
    np.testing.assert_allclose(retreat.start[:2], retreat.end[:2])
    np.testing.assert_allclose(retreat.end, geometry.post_retreat_point)
    assert push.pushing and not back_off.pushing
    np.testing.assert_allclose(push.start, geometry.approach_point)
    np.testing.assert_allclose(push.end, geometry.end_point)
    for before, after in zip(segments, segments[1:], strict=False):
        np.testing.assert_allclose(before.end, after.start)    # one continuous path


def test_points_to_polygon_distance_hand_computed():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    points = np.array([[2.0, 0.5], [0.5, 0.5], [2.0, 2.0], [0.5, -0.25]])
    np.testing.assert_allclose(points_to_polygon_distance(points, square),
                               [1.0, 0.0, math.sqrt(2.0), 0.25])


def test_ball_path_clear_of_far_objects_but_not_of_one_at_the_approach():
    geometry = eraser_push(1)  # approach at x = 0.368, y = 0.1
    far = footprint_polygon("box", 0.1, 0.05, Pose2D(0.45, -0.15, 0.0))
    assert ball_path_is_clear(geometry, [far])
    # Ball surface at the approach reaches back to x = 0.356; a disc rim at 0.35 leaves 6 mm,
    # one at 0.36 overlaps it.
    near = footprint_polygon("cylinder", 0.1, 0.1, Pose2D(0.30, 0.1, 0.0))
    assert ball_path_is_clear(geometry, [far, near])
    behind = footprint_polygon("cylinder", 0.1, 0.1, Pose2D(0.31, 0.1, 0.0))
    assert not ball_path_is_clear(geometry, [far, behind])


def test_hand_clears_every_class_but_not_a_tall_object_nearby():
    geometry = eraser_push(1)  # ball path from x = 0.368 to 0.428 at y = 0.1
    eraser = footprint_polygon("box", 0.12, 0.05, Pose2D(0.45, 0.1, 0.0))
    assert hand_clears_objects(geometry, [eraser], [0.03])
    assert hand_clears_objects(geometry, [eraser, eraser], [0.06, 0.06])   # a hole punch
    tall_near = footprint_polygon("box", 0.05, 0.05, Pose2D(0.45, 0.25, 0.0))
    tall_far = footprint_polygon("box", 0.05, 0.05, Pose2D(0.45, -0.25, 0.0))
    assert not hand_clears_objects(geometry, [eraser, tall_near], [0.03, 0.10])
    assert hand_clears_objects(geometry, [eraser, tall_far], [0.03, 0.10])
