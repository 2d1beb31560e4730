"""The six push primitives of the paper's Fig. 5 (Sec. III-D) as workspace geometry.

Each primitive is a workspace vector in the object frame (x along the long axis):

=========  ===============  =================================  ====================
primitive  push direction   contact point (object frame)       intended effect
=========  ===============  =================================  ====================
1          +x               (-length/2, 0)  -x face midpoint   +x translation
2          -x               (+length/2, 0)  +x face midpoint   -x translation
3          +y               (0, -width/2)   -y face midpoint   +y translation
4          -y               (0, +width/2)   +y face midpoint   -y translation
5          +y               (+0.45 length, -width/2)           +theta rotation
6          -y               (+0.45 length, +width/2)           -theta rotation
=========  ===============  =================================  ====================

Primitives 5-6 are the paper's "opposing vectors at 90 % of the box length along the long-axis box
faces": the contact sits 0.45 length from the centre, 90 % of the way from the centre to the end.
A disc (shape "cylinder") has no long axis, so pushing it off-centre only slides it: primitives 5-6
do not exist for discs and asking for them raises PrimitiveError (`primitives_for` lists the valid
ones). For discs, primitives 1-4 push at the rim along the disc's own x/y axes.

Near the object the ball end-effector follows a workspace path with the tool pointing down
(`workspace_segments`): from above the approach point at the safe height, descend vertically to
the approach point (ball surface `approach_clearance` short of the face), push along the vector
until the ball centre has moved `push_length` past the point of first contact, back off a few
millimetres along the vector, and retreat vertically to the safe height. Getting there from where
the arm waits and back are joint-space moves (primitive_plan), checked to keep the ball and hand
above the safe height.

Why the arm cannot sweep through other objects: the tool points straight down, so the ball is the
lowest point of the arm and the hand's lowest point is HAND_BOTTOM_ABOVE_BALL above its centre.
Moves across the table happen only at or above the safe height (ball bottom above the tallest
object plus a margin, `safe_transit_height`). At pushing height only the ball and the rod column
are below the hand, and the hand is above every object near the push (`hand_clears_objects`).
So the only low footprint is the ball's disc along descend-push-retreat, which
`ball_path_is_clear` checks against the other objects.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from tsrrt_common.geometry import Pose2D
from tsrrt_common.robot_model import BALL_RADIUS
from tsrrt_executor.errors import PrimitiveError

TRANSLATION_PRIMITIVES: tuple[int, ...] = (1, 2, 3, 4)
ROTATION_PRIMITIVES: tuple[int, ...] = (5, 6)
BOX_PRIMITIVES: tuple[int, ...] = TRANSLATION_PRIMITIVES + ROTATION_PRIMITIVES
DISC_PRIMITIVES: tuple[int, ...] = TRANSLATION_PRIMITIVES
SHAPES: tuple[str, ...] = ("box", "cylinder")

DEFAULT_PUSH_LENGTH = 0.05        # metres, as in the paper
MAX_PUSH_LENGTH = 0.15            # longer pushes leave the regime the forward models describe
ROTATION_CONTACT_FRACTION = 0.45  # contact x of primitives 5-6, as a fraction of the length
APPROACH_CLEARANCE = 0.01         # gap between ball surface and face at the approach point
BACK_OFF = 0.005                  # move back along the vector before lifting, to not drag the face
TABLE_CLEARANCE = 0.002           # gap between the ball's lowest point and the table top
MAX_PUSH_HEIGHT = 0.03            # ball centre above the table at most this (low pushes don't tip)
DEFAULT_SAFE_HEIGHT = 0.10        # ball centre above the table during moves across the table
SAFE_HEIGHT_MARGIN = 0.02         # ball bottom above the tallest object when crossing the table
# Lowest point of the Panda hand above the ball centre with the tool pointing down, from the
# hand's collision mesh in the pusher URDF (PyBullet AABB, 0.061 m) rounded down.
HAND_BOTTOM_ABOVE_BALL = 0.06
# Horizontal reach of the hand (half width 0.107 m), link 7 (0.14 m) and link 6 (0.19 m, but
# 0.14 m higher) around the ball, from the same AABBs at the ready posture, rounded up.
ARM_REACH_AROUND_BALL = 0.2
PHASE_APPROACH = "approach"
PHASE_PUSH = "push"
PHASE_RETREAT = "retreat"


def primitives_for(shape: str) -> tuple[int, ...]:
    """Primitives that exist for a shape: 1-6 for a box, 1-4 for a disc ("cylinder")."""
    if shape == "box":
        return BOX_PRIMITIVES
    if shape == "cylinder":
        return DISC_PRIMITIVES
    raise PrimitiveError(f"unknown shape {shape!r}; known shapes: {list(SHAPES)}")


def check_primitive(shape: str, primitive: int) -> None:
    """Raise PrimitiveError unless `primitive` exists for `shape` (5-6 do not exist on discs)."""
    valid = primitives_for(shape)
    if primitive not in valid:
        if shape == "cylinder" and primitive in ROTATION_PRIMITIVES:
            raise PrimitiveError(
                f"primitive {primitive} is a rotation primitive and does not exist for a disc "
                f"(a disc has no long axis); valid for a disc: {list(valid)}")
        raise PrimitiveError(f"primitive {primitive!r} is not one of {list(valid)} for a {shape}")


def check_push_length(push_length: float) -> None:
    """Raise PrimitiveError unless 0 < push_length <= MAX_PUSH_LENGTH."""
    if not (math.isfinite(push_length) and 0.0 < push_length <= MAX_PUSH_LENGTH):
        raise PrimitiveError(
            f"push length {push_length!r} m must be in (0, {MAX_PUSH_LENGTH}] m")


def primitive_vector_in_object_frame(shape: str, length: float, width: float,
                                     primitive: int) -> tuple[np.ndarray, np.ndarray]:
    """Contact point on the footprint boundary and unit push direction, both in the object frame.

    Args:
        shape: "box" or "cylinder" (length == width == diameter for a cylinder).
        length: footprint extent along the object x axis, metres.
        width: footprint extent along the object y axis, metres.
        primitive: 1..6 for a box, 1..4 for a disc.

    Returns:
        contact (2,) and direction (2,) in the object frame.
    """
    check_primitive(shape, primitive)
    if not (length > 0.0 and width > 0.0):
        raise PrimitiveError(f"object size must be positive, got length={length}, width={width}")
    hl, hw = length / 2.0, width / 2.0
    table = {
        1: ((-hl, 0.0), (1.0, 0.0)),
        2: ((hl, 0.0), (-1.0, 0.0)),
        3: ((0.0, -hw), (0.0, 1.0)),
        4: ((0.0, hw), (0.0, -1.0)),
        5: ((ROTATION_CONTACT_FRACTION * length, -hw), (0.0, 1.0)),
        6: ((ROTATION_CONTACT_FRACTION * length, hw), (0.0, -1.0)),
    }
    contact, direction = table[primitive]
    return np.array(contact), np.array(direction)


@dataclass(frozen=True)
class PushGeometry:
    """Where the ball goes for one primitive on one object; world frame, metres.

    The xy points are ball-centre positions except `contact_xy`, the point of the footprint the
    ball touches first. Heights are ball-centre heights (world z).
    """

    primitive: int
    push_length: float
    contact_xy: tuple[float, float]    # first contact point on the footprint boundary
    direction_xy: tuple[float, float]  # unit push direction
    approach_xy: tuple[float, float]   # ball centre before contact (ball surface clear of face)
    touch_xy: tuple[float, float]      # ball centre at first contact
    end_xy: tuple[float, float]        # ball centre at the end of the push
    push_z: float                      # ball centre height while pushing
    safe_z: float                      # ball centre height for moves across the table
    ball_radius: float

    @property
    def direction(self) -> np.ndarray:
        return np.array(self.direction_xy)

    @property
    def pre_approach_point(self) -> np.ndarray:
        """(3,) above the approach point at the safe height."""
        return np.array([*self.approach_xy, self.safe_z])

    @property
    def approach_point(self) -> np.ndarray:
        """(3,) ball centre where the push starts."""
        return np.array([*self.approach_xy, self.push_z])

    @property
    def end_point(self) -> np.ndarray:
        """(3,) ball centre where the push ends."""
        return np.array([*self.end_xy, self.push_z])

    @property
    def retreat_point(self) -> np.ndarray:
        """(3,) ball centre after backing off BACK_OFF from the pushed face."""
        xy = np.array(self.end_xy) - BACK_OFF * self.direction
        return np.array([xy[0], xy[1], self.push_z])

    @property
    def post_retreat_point(self) -> np.ndarray:
        """(3,) above the retreat point at the safe height."""
        return np.array([*self.retreat_point[:2], self.safe_z])

    @property
    def push_travel(self) -> float:
        """Distance the ball travels from the approach point to the end point."""
        return float(np.linalg.norm(np.array(self.end_xy) - np.array(self.approach_xy)))


def push_height(object_height: float, ball_radius: float = BALL_RADIUS) -> float:
    """Ball-centre height above the table for pushing an object of this height.

    Half the object height (the contact is then at the face's middle), but never so low that the
    ball touches the table (ball radius + TABLE_CLEARANCE) and never above MAX_PUSH_HEIGHT, since a
    high contact on a tall object tips it instead of sliding it.
    """
    if not object_height > 0.0:
        raise PrimitiveError(f"object height must be positive, got {object_height}")
    return float(np.clip(object_height / 2.0, ball_radius + TABLE_CLEARANCE,
                         max(MAX_PUSH_HEIGHT, ball_radius + TABLE_CLEARANCE)))


def safe_transit_height(object_heights: Iterable[float], ball_radius: float = BALL_RADIUS,
                        minimum: float = DEFAULT_SAFE_HEIGHT) -> float:
    """Ball-centre height above the table at which moves across the table clear every object.

    The ball is the arm's lowest point with the tool pointing down, so its bottom must clear the
    tallest object by SAFE_HEIGHT_MARGIN.
    """
    tallest = max(object_heights, default=0.0)
    return max(minimum, tallest + ball_radius + SAFE_HEIGHT_MARGIN)


def push_geometry(shape: str, length: float, width: float, height: float, pose: Pose2D,
                  primitive: int, push_length: float = DEFAULT_PUSH_LENGTH, *,
                  table_height: float = 0.0, safe_height: float = DEFAULT_SAFE_HEIGHT,
                  ball_radius: float = BALL_RADIUS,
                  approach_clearance: float = APPROACH_CLEARANCE) -> PushGeometry:
    """Workspace geometry of `primitive` on an object (Fig. 5).

    Args:
        shape: "box" or "cylinder".
        length, width, height: object size in metres (diameter twice for a cylinder).
        pose: object pose on the table (world frame).
        primitive: 1..6 for a box, 1..4 for a disc.
        push_length: how far the ball moves past first contact, metres, in (0, MAX_PUSH_LENGTH].
        table_height: world z of the table top.
        safe_height: ball-centre height above the table for moves across the table (see
            `safe_transit_height`); must be above the pushing height.
        ball_radius: radius of the ball end-effector.
        approach_clearance: gap between ball surface and face at the approach point.

    Raises:
        PrimitiveError: unknown shape, primitive not defined for the shape (5-6 on a disc),
            non-positive size, or push length out of range.
    """
    check_push_length(push_length)
    contact_object, direction_object = primitive_vector_in_object_frame(
        shape, length, width, primitive)
    z_push = push_height(height, ball_radius)
    if not safe_height > z_push:
        raise PrimitiveError(
            f"safe height {safe_height} m must be above the pushing height {z_push:.3f} m")
    contact = pose.transform_point_to_world(contact_object)
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    direction = np.array([c * direction_object[0] - s * direction_object[1],
                          s * direction_object[0] + c * direction_object[1]])
    touch = contact - ball_radius * direction
    approach = touch - approach_clearance * direction
    end = touch + push_length * direction

    def pair(v: np.ndarray) -> tuple[float, float]:
        return (float(v[0]), float(v[1]))

    return PushGeometry(
        primitive=primitive, push_length=float(push_length), contact_xy=pair(contact),
        direction_xy=pair(direction), approach_xy=pair(approach), touch_xy=pair(touch),
        end_xy=pair(end), push_z=table_height + z_push, safe_z=table_height + safe_height,
        ball_radius=ball_radius)


@dataclass(frozen=True)
class WorkspaceSegment:
    """One straight move of the ball centre; `pushing` marks the constant-speed contact move."""

    name: str         # lift, descend, push, back_off, retreat
    phase: str        # PHASE_APPROACH, PHASE_PUSH or PHASE_RETREAT (action feedback)
    start: np.ndarray  # (3,)
    end: np.ndarray    # (3,)
    pushing: bool

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))


def workspace_segments(geometry: PushGeometry) -> list[WorkspaceSegment]:
    """The ball's tool-down path for a primitive, from and back to the safe height.

    descend (vertical, from above the approach point) -> push (along the vector) -> back_off ->
    retreat (vertical). Zero-length segments are left out.
    """
    candidates = [
        WorkspaceSegment("descend", PHASE_APPROACH, geometry.pre_approach_point,
                         geometry.approach_point, False),
        WorkspaceSegment("push", PHASE_PUSH, geometry.approach_point, geometry.end_point, True),
        WorkspaceSegment("back_off", PHASE_RETREAT, geometry.end_point, geometry.retreat_point,
                         False),
        WorkspaceSegment("retreat", PHASE_RETREAT, geometry.retreat_point,
                         geometry.post_retreat_point, False),
    ]
    return [segment for segment in candidates if segment.length > 1e-9]


def ball_path_points(geometry: PushGeometry, spacing: float = 0.005) -> np.ndarray:
    """Ball-centre xy points (N, 2) from the approach point to the end of the push.

    Together with the ball radius these are the discs on the table plane that the low part of the
    path (descend, push, back-off, retreat all lie on this segment) occupies.
    """
    if not spacing > 0.0:
        raise PrimitiveError(f"spacing must be positive, got {spacing}")
    count = max(2, int(math.ceil(geometry.push_travel / spacing)) + 1)
    fractions = np.linspace(0.0, 1.0, count)[:, None]
    return (1.0 - fractions) * np.array(geometry.approach_xy) + fractions * np.array(
        geometry.end_xy)


def points_to_polygon_distance(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance (N,) from points (N, 2) to a convex counter-clockwise polygon (M, 2); 0 inside."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    polygon = np.asarray(polygon, dtype=float)
    starts = polygon
    edges = np.roll(polygon, -1, axis=0) - polygon                          # (M, 2)
    relative = points[:, None, :] - starts[None, :, :]                      # (N, M, 2)
    cross = edges[None, :, 0] * relative[..., 1] - edges[None, :, 1] * relative[..., 0]
    inside = np.all(cross >= 0.0, axis=1)
    t = np.clip(np.einsum("nmk,mk->nm", relative, edges) / np.einsum("mk,mk->m", edges, edges),
                0.0, 1.0)
    nearest = starts[None] + t[..., None] * edges[None]
    distance = np.linalg.norm(points[:, None, :] - nearest, axis=2).min(axis=1)
    return np.where(inside, 0.0, distance)


def ball_path_is_clear(geometry: PushGeometry, other_footprints: Sequence[np.ndarray],
                       margin: float = 0.003) -> bool:
    """True when the ball's low path keeps `margin` from every other object's footprint.

    Args:
        geometry: the push.
        other_footprints: convex counter-clockwise world footprints (M_i, 2) of every object except
            the pushed one (e.g. tsrrt_common.geometry.footprint_polygon; discs become
            circumscribed polygons, so the test is conservative).
        margin: extra clearance beyond the ball radius, metres.
    """
    points = ball_path_points(geometry)
    needed = geometry.ball_radius + margin
    return all(points_to_polygon_distance(points, footprint).min() > needed
               for footprint in other_footprints)


def hand_clears_objects(geometry: PushGeometry, footprints: Sequence[np.ndarray],
                        heights: Sequence[float], table_height: float = 0.0,
                        margin: float = 0.005) -> bool:
    """True when, at pushing height, the arm above the ball passes over every nearby object.

    Objects whose footprint comes within ARM_REACH_AROUND_BALL of the ball's low path must be
    `margin` lower than the hand's bottom; farther objects are out of the arm's way whatever
    their height. Below the hand only the ball and the thin rod (inside the ball's footprint)
    reach down, so this plus `ball_path_is_clear` means nothing but the ball touches objects.

    Args:
        geometry: the push.
        footprints: world footprints (M_i, 2) of the objects, the pushed one included.
        heights: their heights, metres.
    """
    hand_bottom = geometry.push_z + HAND_BOTTOM_ABOVE_BALL - table_height
    points = ball_path_points(geometry)
    for footprint, height in zip(footprints, heights, strict=True):
        near = points_to_polygon_distance(points, footprint).min() < ARM_REACH_AROUND_BALL
        if near and height > hand_bottom - margin:
            return False
    return True
