"""From "push object X with primitive k" to a checked joint trajectory (the node's ROS-free core).

plan_primitive validates the goal, computes the Fig. 5 geometry, checks that the arm can reach
every ball position of the push and of the transit to it, that the ball's low path keeps clear
of the other objects and the hand clears them all, and then runs IK + time parameterisation.
Each failure raises the error the action result maps to a code:
PrimitiveError -> INVALID_GOAL, UnreachableError -> UNREACHABLE, IKError -> IK_FAILED.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tsrrt_common.geometry import Pose2D, footprint_polygon
from tsrrt_executor.errors import UnreachableError
from tsrrt_executor.inverse_kinematics import PusherIK
from tsrrt_executor.push_primitives import (
    DEFAULT_PUSH_LENGTH,
    DEFAULT_SAFE_HEIGHT,
    PHASE_RETREAT,
    PushGeometry,
    WorkspaceSegment,
    ball_path_is_clear,
    check_push_length,
    hand_clears_objects,
    push_geometry,
    safe_transit_height,
    workspace_segments,
)
from tsrrt_executor.reachability import push_is_reachable, segment_is_reachable
from tsrrt_executor.trajectory import TimedJointTrajectory, TimingSettings, time_parameterise


@dataclass(frozen=True)
class TableObject:
    """What the executor needs to know of an object on the table (from perception)."""

    id: str
    shape: str          # "box" | "cylinder"
    length: float
    width: float
    height: float
    pose: Pose2D

    def footprint(self) -> np.ndarray:
        return footprint_polygon(self.shape, self.length, self.width, self.pose)


@dataclass(frozen=True)
class ExecutorSettings:
    """Parameters of primitive execution (the node's ROS parameters)."""

    default_push_length: float = DEFAULT_PUSH_LENGTH
    safe_height: float = DEFAULT_SAFE_HEIGHT   # minimum ball-centre height for transits
    path_clearance: float = 0.003              # ball to other objects along the low path
    table_height: float = 0.0
    timing: TimingSettings = field(default_factory=TimingSettings)


@dataclass(frozen=True, eq=False)
class PrimitivePlan:
    """A checked push: its geometry, its joint trajectory, and what computing them cost."""

    geometry: PushGeometry
    trajectory: TimedJointTrajectory
    planning_ms: float   # IK + time parameterisation (+ the cheap checks), wall milliseconds


def plan_primitive(ik: PusherIK, target: TableObject, others: Sequence[TableObject],
                   primitive: int, push_length: float, q_current: np.ndarray,
                   settings: ExecutorSettings | None = None) -> PrimitivePlan:
    """Plan one primitive on `target` from the arm configuration `q_current` (7,).

    Args:
        ik: the solver (holds the robot model).
        target: the object to push.
        others: every other object on the table (obstacles included).
        primitive: 1..6 (1..4 for a disc).
        push_length: metres; 0 means settings.default_push_length.
        q_current: measured joint positions.
        settings: executor parameters.

    Raises:
        PrimitiveError: the primitive does not exist for the object or the length is invalid.
        UnreachableError: part of the path is outside the reachable workspace, or blocked.
        IKError: a waypoint has no tool-down IK solution.
    """
    start = time.perf_counter()
    settings = settings or ExecutorSettings()
    length = settings.default_push_length if push_length == 0.0 else push_length
    check_push_length(length)
    heights = [target.height, *(other.height for other in others)]
    safe_z = safe_transit_height(heights, minimum=settings.safe_height)
    geometry = push_geometry(target.shape, target.length, target.width, target.height,
                             target.pose, primitive, length,
                             table_height=settings.table_height, safe_height=safe_z)
    q_current = np.asarray(q_current, dtype=float)
    tool_start = ik.tool_position(q_current)
    check_push_feasible(geometry, target, others, tool_start, settings)
    segments = workspace_segments(geometry, tool_start)
    trajectory = time_parameterise(ik, segments, q_current, settings.timing)
    return PrimitivePlan(geometry, trajectory, (time.perf_counter() - start) * 1000.0)


def check_push_feasible(geometry: PushGeometry, target: TableObject,
                        others: Sequence[TableObject], tool_start: np.ndarray,
                        settings: ExecutorSettings) -> None:
    """Raise UnreachableError unless the push and the transit to it are reachable and clear."""
    if not push_is_reachable(geometry, settings.table_height):
        raise UnreachableError(
            f"primitive {geometry.primitive} on {target.id!r} at ({target.pose.x:.3f}, "
            f"{target.pose.y:.3f}): the ball path from ({geometry.approach_xy[0]:.3f}, "
            f"{geometry.approach_xy[1]:.3f}) to ({geometry.end_xy[0]:.3f}, "
            f"{geometry.end_xy[1]:.3f}) leaves the reachable workspace")
    if not segment_is_reachable(tool_start[:2], geometry.approach_xy):
        raise UnreachableError(
            f"the transit from the tool at ({tool_start[0]:.3f}, {tool_start[1]:.3f}) to above "
            f"the approach point leaves the reachable workspace")
    for other in others:
        if not ball_path_is_clear(geometry, [other.footprint()], settings.path_clearance):
            raise UnreachableError(
                f"primitive {geometry.primitive} on {target.id!r}: the approach or push path "
                f"of the ball is blocked by {other.id!r}")
    for item in (target, *others):
        if not hand_clears_objects(geometry, [item.footprint()], [item.height],
                                   settings.table_height):
            raise UnreachableError(
                f"primitive {geometry.primitive} on {target.id!r}: the hand would hit "
                f"{item.id!r} (height {item.height:.3f} m) while pushing")


def retreat_trajectory(ik: PusherIK, q_current: np.ndarray, safe_z: float,
                       settings: ExecutorSettings | None = None) -> TimedJointTrajectory | None:
    """Lift the ball vertically from where it is to `safe_z` (e.g. after a cancel).

    Returns None when the ball is already at or above `safe_z`.
    """
    settings = settings or ExecutorSettings()
    tool = ik.tool_position(np.asarray(q_current, dtype=float))
    if tool[2] >= safe_z - 1e-6:
        return None
    lift = WorkspaceSegment("retreat", PHASE_RETREAT, tool, np.array([tool[0], tool[1], safe_z]),
                            False)
    return time_parameterise(ik, [lift], q_current, settings.timing)
