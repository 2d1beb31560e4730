"""Time-parameterised joint trajectories for a push primitive, within joint velocity/accel limits.

Each straight workspace segment of the ball path (push_primitives.workspace_segments) gets a
trapezoidal (or triangular) tool-speed profile that starts and ends at rest: the pushing segment
at the push speed, so the ball moves at constant speed while in contact (its ramp fits into the
approach clearance), the others at the transit speed. The profile is sampled at a fixed period,
each sample goes through warm-started IK, and joint velocities and accelerations follow by the
chain rule from the geometric derivative dq/ds (s = arc length) and the profile:

    q_dot = q' s_dot,   q_ddot = q'' s_dot^2 + q' s_ddot.

If a segment would exceed a joint's (scaled) velocity or acceleration limit, it is slowed down
uniformly (time scaled by k: velocities / k, accelerations / k^2), keeping its geometry, and
resampled. Moves in joint space (`JointMove`: a straight line in q with a synchronised
trapezoid, every joint at rest at both ends) take the arm between postures that are not on one
tool-down straight line: from where it waits out of the camera's view to above the object, and
back; primitive_plan checks that they keep the arm above the objects.

The result is a plain structure (times, positions, velocities, accelerations) that the node turns
into a trajectory_msgs/JointTrajectory.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tsrrt_common.robot_model import ARM_JOINT_NAMES
from tsrrt_executor.errors import TrajectoryError
from tsrrt_executor.inverse_kinematics import TOOL_AXIS_DOWN, PusherIK
from tsrrt_executor.push_primitives import WorkspaceSegment

JOINT_MOVE_TOLERANCE = 1e-4  # rad; a joint move to where the arm already is is left out
# A workspace segment must start where the arm's ball is (and the tool must point down).
SEGMENT_START_TOLERANCE = 1e-3     # metres
TOOL_AXIS_TOLERANCE = 0.02         # |z_tool - down|, about radians of tilt


@dataclass(frozen=True)
class TimingSettings:
    """Speeds of the ball and scaling of the robot's joint limits."""

    push_speed: float = 0.05          # m/s, constant while in contact
    transit_speed: float = 0.3        # m/s, lift / transit / descend / retreat
    tool_acceleration: float = 1.0    # m/s^2, ramps of every workspace segment
    # The two joint moves out of and back into the observe posture were 3.5 s of a push's 6 s
    # at half the limits; at 0.9 they take 2.1 s (a clean push 4.5 s simulated instead of
    # 5.8), and the 10 % left is the margin a real arm's limit reflexes want.
    velocity_scale: float = 0.9       # fraction of the URDF joint velocity limits used
    acceleration_scale: float = 0.9   # fraction of the datasheet joint acceleration limits used
    sample_period: float = 0.04       # s between points (the controller splines between)

    def validate(self) -> None:
        for name in ("push_speed", "transit_speed", "tool_acceleration", "sample_period"):
            if not getattr(self, name) > 0.0:
                raise TrajectoryError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("velocity_scale", "acceleration_scale"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise TrajectoryError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        ramp = self.push_speed ** 2 / (2.0 * self.tool_acceleration)
        if ramp > 0.01:
            raise TrajectoryError(
                f"push speed {self.push_speed} m/s needs a {ramp * 1000:.1f} mm ramp at "
                f"{self.tool_acceleration} m/s^2, longer than the approach clearance")


@dataclass(frozen=True, eq=False)
class JointMove:
    """A straight line in joint space to `target` (7,), starting and ending at rest."""

    name: str           # e.g. transit, return
    phase: str          # PHASE_APPROACH or PHASE_RETREAT (action feedback)
    target: np.ndarray  # (7,) rad


@dataclass(frozen=True, eq=False)
class TimedJointTrajectory:
    """Joint trajectory sampled at `times` (N,), with the ball's nominal path and phases."""

    joint_names: tuple[str, ...]
    times: np.ndarray          # (N,) seconds from the start, strictly increasing, times[0] = 0
    positions: np.ndarray      # (N, 7) rad
    velocities: np.ndarray     # (N, 7) rad/s
    accelerations: np.ndarray  # (N, 7) rad/s^2
    tool_targets: np.ndarray   # (N, 3) nominal ball centre
    phases: tuple[str, ...]    # (N,) phase each point belongs to
    segment_names: tuple[str, ...]  # (N,) name of the segment or joint move it belongs to
    in_joint_space: np.ndarray  # (N,) bool, the point belongs to a JointMove

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def phase_start_times(self) -> dict[str, float]:
        """Time at which each phase begins (first point of that phase)."""
        starts: dict[str, float] = {}
        for t, phase in zip(self.times, self.phases, strict=True):
            starts.setdefault(phase, float(t))
        return starts

    def phase_at(self, t: float) -> tuple[str, float]:
        """Phase at time t from the start and the progress (0..1) within it, for feedback."""
        index = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0,
                            len(self.times) - 1))
        return self.phases[index], self._progress(self.phases[index], t)

    def phase_at_index(self, index: int) -> tuple[str, float]:
        """Phase of point `index` and the progress (0..1) within that phase."""
        return self.phases[index], self._progress(self.phases[index], float(self.times[index]))

    def _progress(self, phase: str, t: float) -> float:
        members = np.flatnonzero(np.array(self.phases) == phase)
        start, end = float(self.times[members[0]]), float(self.times[members[-1]])
        return 1.0 if end <= start else float(np.clip((t - start) / (end - start), 0.0, 1.0))

    def nearest_index(self, q: np.ndarray, from_index: int = 0) -> int:
        """Index of the point nearest to joint positions q (7,), searching from `from_index` on.

        For feedback from a controller's desired state, which only moves forward: this needs no
        clock shared with the controller.
        """
        distances = np.abs(self.positions[from_index:] - np.asarray(q, dtype=float)).max(axis=1)
        return from_index + int(np.argmin(distances))


def trapezoid_profile(length: float, max_speed: float, max_acceleration: float,
                      sample_period: float) -> tuple[np.ndarray, ...]:
    """Rest-to-rest profile along a path of `length`: times, s, s_dot, s_ddot, each (n,).

    Triangular when the path is too short to reach `max_speed`.
    """
    if not (length > 0.0 and max_speed > 0.0 and max_acceleration > 0.0):
        raise TrajectoryError(f"profile needs positive length, speed and acceleration, got "
                              f"{length}, {max_speed}, {max_acceleration}")
    ramp_time = max_speed / max_acceleration
    if max_acceleration * ramp_time ** 2 >= length:  # never reaches max_speed
        ramp_time = math.sqrt(length / max_acceleration)
        peak = max_acceleration * ramp_time
        cruise_time = 0.0
    else:
        peak = max_speed
        cruise_time = (length - max_acceleration * ramp_time ** 2) / max_speed
    duration = 2.0 * ramp_time + cruise_time
    count = max(2, int(math.ceil(duration / sample_period)) + 1)
    t = np.linspace(0.0, duration, count)
    decel_start = ramp_time + cruise_time
    tail = duration - t
    s = np.where(t < ramp_time, 0.5 * max_acceleration * t ** 2,
                 np.where(t <= decel_start, 0.5 * max_acceleration * ramp_time ** 2
                          + peak * (t - ramp_time),
                          length - 0.5 * max_acceleration * tail ** 2))
    s_dot = np.where(t < ramp_time, max_acceleration * t,
                     np.where(t <= decel_start, peak, max_acceleration * tail))
    s_ddot = np.where(t < ramp_time, max_acceleration,
                      np.where(t <= decel_start, 0.0, -max_acceleration))
    s[-1], s_dot[-1], s_dot[0] = length, 0.0, 0.0
    return t, s, s_dot, s_ddot


@dataclass
class _Piece:
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    tool_targets: np.ndarray
    phase: str
    name: str
    joint_space: bool = False


def _stretch_needed(piece: _Piece, velocity_limits: np.ndarray,
                    acceleration_limits: np.ndarray) -> float:
    """Time scale factor (>= 1) that brings every joint within its limits."""
    velocity_ratio = float((np.abs(piece.velocities) / velocity_limits).max())
    acceleration_ratio = float((np.abs(piece.accelerations) / acceleration_limits).max())
    return max(1.0, velocity_ratio, math.sqrt(acceleration_ratio))


def _stretch(piece: _Piece, factor: float) -> None:
    piece.times = piece.times * factor
    piece.velocities = piece.velocities / factor
    piece.accelerations = piece.accelerations / factor ** 2


def _workspace_piece(ik: PusherIK, segment: WorkspaceSegment, q_start: np.ndarray,
                     speed: float, acceleration: float, sample_period: float) -> _Piece:
    t, s, s_dot, s_ddot = trapezoid_profile(segment.length, speed, acceleration, sample_period)
    unit = (segment.end - segment.start) / segment.length
    targets = segment.start + s[:, None] * unit                       # (n, 3)
    positions, _ = ik.solve_path(targets, q_start)                   # (n, 7)
    dq_ds = np.gradient(positions, s, axis=0, edge_order=1)          # (n, 7)
    d2q_ds2 = np.gradient(dq_ds, s, axis=0, edge_order=1)
    velocities = dq_ds * s_dot[:, None]
    accelerations = d2q_ds2 * s_dot[:, None] ** 2 + dq_ds * s_ddot[:, None]
    return _Piece(t, positions, velocities, accelerations, targets, segment.phase, segment.name)


def _joint_move_piece(ik: PusherIK, q_from: np.ndarray, move: JointMove,
                      velocity_limits: np.ndarray, acceleration_limits: np.ndarray,
                      sample_period: float) -> _Piece:
    delta = np.asarray(move.target, dtype=float) - q_from
    moving = np.abs(delta) > 1e-12
    speed = float((velocity_limits[moving] / np.abs(delta[moving])).min())
    acceleration = float((acceleration_limits[moving] / np.abs(delta[moving])).min())
    t, s, s_dot, s_ddot = trapezoid_profile(1.0, speed, acceleration, sample_period)
    positions = q_from + s[:, None] * delta
    return _Piece(t, positions, s_dot[:, None] * delta, s_ddot[:, None] * delta,
                  ik.tool_positions(positions), move.phase, move.name, joint_space=True)


def _check_segment_start(ik: PusherIK, segment: WorkspaceSegment, q: np.ndarray) -> None:
    """A tool-down segment must begin where the ball is, with the tool pointing down."""
    position, axis = ik.tool_pose(q)
    gap = float(np.linalg.norm(position - segment.start))
    tilt = float(np.linalg.norm(axis - TOOL_AXIS_DOWN))
    if gap > SEGMENT_START_TOLERANCE or tilt > TOOL_AXIS_TOLERANCE:
        raise TrajectoryError(
            f"segment {segment.name!r} starts at {np.round(segment.start, 4).tolist()} but the "
            f"ball is at {np.round(position, 4).tolist()} (tool tilted {tilt:.3f}); a joint move "
            "must bring the arm there first")


def time_parameterise(ik: PusherIK, motions: Sequence[WorkspaceSegment | JointMove],
                      q_current: np.ndarray, settings: TimingSettings | None = None
                      ) -> TimedJointTrajectory:
    """Joint trajectory from the arm's configuration `q_current` (7,) through the motions.

    Workspace segments are straight ball paths with the tool down (IK at every sample, warm-
    started along the path); each must start where the previous motion left the ball. Joint moves
    are straight lines in joint space; one to where the arm already is is left out.

    Raises:
        IKError: a waypoint has no tool-down IK solution.
        TrajectoryError: bad settings, nothing to do, or a segment that does not start at the ball.
    """
    settings = settings or TimingSettings()
    settings.validate()
    velocity_limits = ik.velocity_limits * settings.velocity_scale
    acceleration_limits = ik.acceleration_limits * settings.acceleration_scale
    q = np.asarray(q_current, dtype=float).reshape(-1)
    pieces: list[_Piece] = []
    for motion in motions:
        if isinstance(motion, JointMove):
            if np.abs(np.asarray(motion.target, dtype=float) - q).max() <= JOINT_MOVE_TOLERANCE:
                continue
            piece = _joint_move_piece(ik, q, motion, velocity_limits, acceleration_limits,
                                      settings.sample_period)
        else:
            _check_segment_start(ik, motion, q)
            piece = _timed_workspace_piece(ik, motion, q, settings, velocity_limits,
                                           acceleration_limits)
        pieces.append(piece)
        q = piece.positions[-1]
    if not pieces:
        raise TrajectoryError("no motion to time-parameterise: the arm is already there")
    return _concatenate(pieces)


def _timed_workspace_piece(ik: PusherIK, segment: WorkspaceSegment, q: np.ndarray,
                           settings: TimingSettings, velocity_limits: np.ndarray,
                           acceleration_limits: np.ndarray) -> _Piece:
    speed = settings.push_speed if segment.pushing else settings.transit_speed
    acceleration = settings.tool_acceleration
    piece = _workspace_piece(ik, segment, q, speed, acceleration, settings.sample_period)
    stretch = _stretch_needed(piece, velocity_limits, acceleration_limits)
    if stretch > 1.0:
        # Resample the slower profile (speed / k, acceleration / k^2 is the same profile
        # stretched k times) so that points stay sample_period apart; then correct the
        # small differences sampling makes with a final uniform stretch.
        piece = _workspace_piece(ik, segment, q, speed / stretch,
                                 acceleration / stretch ** 2, settings.sample_period)
        _stretch(piece, _stretch_needed(piece, velocity_limits, acceleration_limits))
    return piece


def _concatenate(pieces: list[_Piece]) -> TimedJointTrajectory:
    """Join pieces end to start; each piece's first point duplicates the previous one's last."""
    times, positions, velocities, accelerations, targets = [], [], [], [], []
    phases: list[str] = []
    names: list[str] = []
    joint_space: list[bool] = []
    offset = 0.0
    for index, piece in enumerate(pieces):
        keep = slice(0 if index == 0 else 1, None)
        times.append(piece.times[keep] + offset)
        positions.append(piece.positions[keep])
        velocities.append(piece.velocities[keep])
        accelerations.append(piece.accelerations[keep])
        targets.append(piece.tool_targets[keep])
        count = len(piece.times[keep])
        phases += [piece.phase] * count
        names += [piece.name] * count
        joint_space += [piece.joint_space] * count
        offset += float(piece.times[-1])
    return TimedJointTrajectory(
        joint_names=ARM_JOINT_NAMES, times=np.concatenate(times),
        positions=np.vstack(positions), velocities=np.vstack(velocities),
        accelerations=np.vstack(accelerations), tool_targets=np.vstack(targets),
        phases=tuple(phases), segment_names=tuple(names),
        in_joint_space=np.array(joint_space, dtype=bool))


class PhaseProgress:
    """Turns a controller's desired joint positions into feedback: (phase, progress) in order.

    A controller reports at its own rate, which may be slower than a short phase (the push takes
    about a second of simulated time, a tenth of a second of wall time at full simulation
    speed); phases passed between two reports are returned completed (progress 1.0), so that a
    client sees every phase, in order.
    """

    def __init__(self, trajectory: TimedJointTrajectory) -> None:
        self.trajectory = trajectory
        self.order = tuple(dict.fromkeys(trajectory.phases))
        self.index = 0
        self.phase_rank = -1
        self.finished = False

    def update(self, q_desired: np.ndarray) -> list[tuple[str, float]]:
        """Phases finished since the last update (progress 1.0), then the current one; nothing
        once finished (a late report must not follow the end)."""
        if self.finished:
            return []
        self.index = self.trajectory.nearest_index(q_desired, self.index)
        return self._report(self.index)

    def finish(self) -> list[tuple[str, float]]:
        """Updates up to the end of the trajectory (call when the controller succeeded)."""
        self.finished = True
        self.index = len(self.trajectory.times) - 1
        return self._report(self.index)

    def _report(self, index: int) -> list[tuple[str, float]]:
        phase, progress = self.trajectory.phase_at_index(index)
        rank = self.order.index(phase)
        # The last phase reported and any between it and this one are over.
        skipped = [(self.order[r], 1.0) for r in range(max(self.phase_rank, 0), rank)]
        self.phase_rank = rank
        return [*skipped, (phase, progress)]
