"""From "push object X with primitive k" to a checked joint trajectory (the node's ROS-free core).

The arm waits in OBSERVE_POSTURE, out of the overhead camera's view, so that perception sees
every object before and after a push. A primitive's trajectory therefore runs:

    [lift]  vertical, to the safe height, only if the ball starts lower (e.g. after a cancel)
    transit joint-space move to the tool-down posture above the approach point
    descend, push, back_off, retreat   tool-down workspace path of Fig. 5 (push_primitives)
    return  joint-space move back to OBSERVE_POSTURE

plan_primitive validates the goal, computes the Fig. 5 geometry, checks that the arm can reach
every ball position of the push, that the ball's low path keeps clear of the other objects and
the hand clears them all, runs IK + time parameterisation, and checks that the joint-space moves
keep the ball and the hand above the safe height (`check_joint_moves_clear`; straight lines in
joint space are not straight for the ball, so this is checked, not assumed).
Each failure raises the error the action result maps to a code:
PrimitiveError -> INVALID_GOAL, UnreachableError -> UNREACHABLE, IKError -> IK_FAILED.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from tsrrt_common.geometry import Pose2D, footprint_polygon
from tsrrt_common.robot_model import BALL_RADIUS, OBSERVE_POSTURE
from tsrrt_executor.errors import UnreachableError
from tsrrt_executor.inverse_kinematics import TOOL_AXIS_DOWN, PusherIK
from tsrrt_executor.push_primitives import (
    DEFAULT_PUSH_LENGTH,
    DEFAULT_SAFE_HEIGHT,
    PHASE_APPROACH,
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
from tsrrt_executor.reachability import push_is_executable
from tsrrt_executor.trajectory import (
    JOINT_MOVE_TOLERANCE,
    TOOL_AXIS_TOLERANCE,
    JointMove,
    TimedJointTrajectory,
    TimingSettings,
    time_parameterise,
)

HAND_FRAME = "panda_hand"
# Corners of the hand's collision mesh (example-robot-data hand.stl) in the hand frame, rounded
# outwards; with the ball these are the lowest parts of the arm in every posture it moves through.
HAND_BOX_CORNERS = np.array(list(itertools.product((-0.032, 0.032), (-0.105, 0.101),
                                                   (-0.026, 0.066))))          # (8, 3)
CLEARANCE_TOLERANCE = 1e-3   # metres a joint move may dip below the safe height (sampling)


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
    observe_posture: tuple[float, ...] = OBSERVE_POSTURE   # (7,) where the arm waits


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

    The trajectory starts at `q_current` and ends in settings.observe_posture.

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
        UnreachableError: part of the path is outside the reachable workspace, blocked, or a
            joint-space move would come down below the safe height.
        IKError: a waypoint has no tool-down IK solution.
    """
    start = time.perf_counter()
    settings = settings or ExecutorSettings()
    length = settings.default_push_length if push_length == 0.0 else push_length
    check_push_length(length)
    heights = [target.height, *(other.height for other in others)]
    safe_height = safe_transit_height(heights, minimum=settings.safe_height)
    geometry = push_geometry(target.shape, target.length, target.width, target.height,
                             target.pose, primitive, length,
                             table_height=settings.table_height, safe_height=safe_height)
    check_push_feasible(geometry, target, others, settings)
    q_current = np.asarray(q_current, dtype=float)
    # Solved from the rest posture, not from q_current: the push posture does not depend on
    # where the arm happens to be.
    q_above_approach, _ = ik.solve(geometry.pre_approach_point)
    motions = [*lift_to_safe_height(ik, q_current, geometry.safe_z, PHASE_APPROACH),
               JointMove("transit", PHASE_APPROACH, q_above_approach),
               *workspace_segments(geometry),
               JointMove("return", PHASE_RETREAT, np.array(settings.observe_posture))]
    trajectory = time_parameterise(ik, motions, q_current, settings.timing)
    check_joint_moves_clear(ik, trajectory, geometry.safe_z)
    return PrimitivePlan(geometry, trajectory, (time.perf_counter() - start) * 1000.0)


def check_push_feasible(geometry: PushGeometry, target: TableObject,
                        others: Sequence[TableObject], settings: ExecutorSettings) -> None:
    """Raise UnreachableError unless the push is reachable and its low path clear."""
    if not push_is_executable(geometry, settings.table_height):
        raise UnreachableError(
            f"primitive {geometry.primitive} on {target.id!r} at ({target.pose.x:.3f}, "
            f"{target.pose.y:.3f}): the ball path from ({geometry.approach_xy[0]:.3f}, "
            f"{geometry.approach_xy[1]:.3f}) to ({geometry.end_xy[0]:.3f}, "
            f"{geometry.end_xy[1]:.3f}) leaves the reachable workspace")
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


def lowest_arm_point(ik: PusherIK, q: np.ndarray) -> float:
    """Height (world z) of the lowest point of the ball and the hand at configuration q (7,).

    The rest of the arm (wrist, elbow) stays well above these in the postures the executor uses.
    """
    pin.framesForwardKinematics(ik.model, ik.data, np.asarray(q, dtype=float))
    hand = ik.data.oMf[ik.model.getFrameId(HAND_FRAME)]
    ball_centre = ik.data.oMf[ik.tool_frame_id].translation
    corners_z = hand.rotation[2] @ HAND_BOX_CORNERS.T + hand.translation[2]      # (8,)
    return float(min(ball_centre[2] - BALL_RADIUS, corners_z.min()))


def check_joint_moves_clear(ik: PusherIK, trajectory: TimedJointTrajectory,
                            safe_z: float) -> None:
    """Raise UnreachableError if a joint-space move takes the ball or hand below the safe height.

    The safe height is for the ball centre; the ball's bottom is then BALL_RADIUS lower, so that
    is the lowest any part of the arm may come during a joint-space move.
    """
    floor = safe_z - BALL_RADIUS - CLEARANCE_TOLERANCE
    for index in np.flatnonzero(trajectory.in_joint_space):
        lowest = lowest_arm_point(ik, trajectory.positions[index])
        if lowest < floor:
            raise UnreachableError(
                f"the joint-space move {trajectory.segment_names[index]!r} would bring the arm "
                f"down to z = {lowest:.3f} m, below the safe height (lowest allowed "
                f"{floor + CLEARANCE_TOLERANCE:.3f} m)")


def lift_to_safe_height(ik: PusherIK, q_current: np.ndarray, safe_z: float,
                        phase: str = PHASE_RETREAT) -> list[WorkspaceSegment]:
    """A vertical lift of the ball to `safe_z` if it is lower; [] if it is not.

    Raises:
        UnreachableError: the ball is low with the tool not pointing down (it cannot be lifted
            straight up; this does not happen in the executor's own motions).
    """
    position, axis = ik.tool_pose(np.asarray(q_current, dtype=float))
    if position[2] >= safe_z - CLEARANCE_TOLERANCE:
        return []
    tilt = float(np.linalg.norm(axis - TOOL_AXIS_DOWN))
    if tilt > TOOL_AXIS_TOLERANCE:
        raise UnreachableError(
            f"the ball is {position[2]:.3f} m high, below the safe height {safe_z:.3f} m, with "
            f"the tool tilted ({tilt:.2f}); it cannot be lifted straight up")
    return [WorkspaceSegment("lift", phase, position,
                             np.array([position[0], position[1], safe_z]), False)]


def at_posture(q: np.ndarray, posture: Sequence[float], tolerance: float = 0.01) -> bool:
    """Whether every joint of q (7,) is within `tolerance` rad of `posture`."""
    return bool(np.abs(np.asarray(q, dtype=float) - np.asarray(posture)).max() <= tolerance)


def return_to_observe(ik: PusherIK, q_current: np.ndarray, safe_z: float,
                      settings: ExecutorSettings | None = None) -> TimedJointTrajectory | None:
    """Lift the ball to `safe_z` if it is lower, then move to the observe posture.

    For parking the arm before the "before" observation and for retreating after a cancel.
    Returns None when the arm is already there.

    Raises:
        UnreachableError: the ball is low with the tool tilted, or the move back would come
            down below the safe height.
        IKError: no tool-down IK solution along the lift.
    """
    settings = settings or ExecutorSettings()
    q_current = np.asarray(q_current, dtype=float)
    if at_posture(q_current, settings.observe_posture, JOINT_MOVE_TOLERANCE):
        return None
    motions = [*lift_to_safe_height(ik, q_current, safe_z),
               JointMove("return", PHASE_RETREAT, np.array(settings.observe_posture))]
    trajectory = time_parameterise(ik, motions, q_current, settings.timing)
    check_joint_moves_clear(ik, trajectory, safe_z)
    return trajectory


def lift_trajectory(ik: PusherIK, q_current: np.ndarray, safe_z: float,
                    settings: ExecutorSettings | None = None) -> TimedJointTrajectory | None:
    """Only the vertical lift to `safe_z` (None if the ball is not lower): the fallback after a
    cancel when the way back to the observe posture is not clear."""
    settings = settings or ExecutorSettings()
    lift = lift_to_safe_height(ik, np.asarray(q_current, dtype=float), safe_z)
    return time_parameterise(ik, lift, q_current, settings.timing) if lift else None
