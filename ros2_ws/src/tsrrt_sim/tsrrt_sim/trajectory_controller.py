"""Joint-trajectory tracking with computed-torque control, run inside the physics loop.

It behaves like ros2_controllers' JointTrajectoryController (JTC) so that the executor can later
drive a real controller the same way:
- waypoints are interpolated linearly (positions only), with cubic splines (positions and
  velocities) or quintic splines (positions, velocities and accelerations);
- before the first waypoint the controller interpolates from the state it had when the goal
  arrived (a first waypoint at or before that time is jumped to, as in JTC);
- a new goal preempts the active one and starts from the current *desired* state, so the
  reference stays continuous;
- path tolerances are checked while the trajectory runs, goal tolerances after its last point
  within the goal time tolerance; a violation aborts the goal and holds the measured position;
- with no goal, the controller holds the last commanded position.

Torque law (computed torque): tau = ID(q, qd, qdd_d + Kp (q_d - q) + Kd (qd_d - qd)), clipped to
the URDF effort limits. ID is the robot's inverse dynamics, so the closed loop is a decoupled
critically-damped second-order system per joint (Kp 2500, Kd 100: 50 rad/s, damping ratio 1).
Plain PD plus gravity compensation with Franka-like gains was measured to track the tool by
centimetres on this model; computed torque tracks it to well under a millimetre.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from tsrrt_common.errors import TsrrtError
from tsrrt_common.robot_model import ARM_JOINT_NAMES
from tsrrt_sim.kinematics import JointLimits

NUM_JOINTS = len(ARM_JOINT_NAMES)
# A waypoint exactly on a joint limit is fine; rounding in a planner's output may put it a hair
# beyond. Anything further out is refused.
LIMIT_SLACK = 1e-6


class TrajectoryErrorCode(enum.IntEnum):
    """Result codes, numerically equal to tsrrt_interfaces/action/FollowJointTrajectory's."""

    SUCCESSFUL = 0
    INVALID_GOAL = -1
    INVALID_JOINTS = -2
    OLD_HEADER_TIMESTAMP = -3
    PATH_TOLERANCE_VIOLATED = -4
    GOAL_TOLERANCE_VIOLATED = -5
    CANCELED = -6
    PREEMPTED = -7


class TrajectoryError(TsrrtError):
    """A trajectory goal is unacceptable; `code` says which kind of problem it is."""

    def __init__(self, code: TrajectoryErrorCode, message: str) -> None:
        self.code = code
        super().__init__(message)


@dataclass(frozen=True)
class JointTrajectory:
    """A validated trajectory in ARM_JOINT_NAMES order.

    Attributes:
        times: (N,) seconds from the trajectory start, strictly increasing, >= 0.
        positions: (N, 7) rad.
        velocities: (N, 7) rad/s, or None when the waypoints gave none (linear interpolation).
        accelerations: (N, 7) rad/s^2, or None (cubic or linear interpolation).
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray | None
    accelerations: np.ndarray | None

    @property
    def duration(self) -> float:
        return float(self.times[-1])


@dataclass(frozen=True)
class SetPoint:
    """Desired (or measured) joint state, each (7,)."""

    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray

    @staticmethod
    def at_rest(positions: np.ndarray) -> SetPoint:
        positions = np.array(positions, dtype=float)
        return SetPoint(positions, np.zeros(NUM_JOINTS), np.zeros(NUM_JOINTS))


@dataclass(frozen=True)
class Tolerances:
    """Per-joint tolerances (7,) each; math.inf means unchecked.

    goal_velocity is the speed below which a joint counts as stopped at the goal; goal_time is
    how long after the last waypoint's time the goal tolerance may take to be met.
    """

    path_position: np.ndarray
    path_velocity: np.ndarray
    goal_position: np.ndarray
    goal_velocity: np.ndarray
    goal_time: float

    @staticmethod
    def uniform(path_position: float, path_velocity: float, goal_position: float,
                goal_velocity: float, goal_time: float) -> Tolerances:
        """The same tolerance on every joint; a value <= 0 means unchecked."""
        def vector(value: float) -> np.ndarray:
            return np.full(NUM_JOINTS, value if value > 0 else math.inf)
        return Tolerances(vector(path_position), vector(path_velocity), vector(goal_position),
                          vector(goal_velocity), goal_time if goal_time > 0 else math.inf)


@dataclass(frozen=True)
class JointToleranceOverride:
    """One entry of a goal's path_tolerance or goal_tolerance (control_msgs' JointTolerance):
    0 keeps the default, a negative value removes the check, a positive value replaces it."""

    name: str
    position: float
    velocity: float


def resolve_tolerances(defaults: Tolerances, path: Sequence[JointToleranceOverride],
                       goal: Sequence[JointToleranceOverride], goal_time: float) -> Tolerances:
    """Apply a goal's tolerance overrides to the controller defaults (JointTolerance rules)."""
    def apply(base: np.ndarray, name: str, value: float) -> None:
        if not math.isfinite(value):
            raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL,
                                  f"tolerance for {name} is not finite ({value})")
        if value != 0.0:
            base[ARM_JOINT_NAMES.index(name)] = value if value > 0 else math.inf

    arrays = {key: getattr(defaults, key).copy() for key in
              ("path_position", "path_velocity", "goal_position", "goal_velocity")}
    for kind, overrides in (("path", path), ("goal", goal)):
        for override in overrides:
            if override.name not in ARM_JOINT_NAMES:
                raise TrajectoryError(TrajectoryErrorCode.INVALID_JOINTS,
                                      f"{kind}_tolerance names unknown joint {override.name!r}; "
                                      f"known: {list(ARM_JOINT_NAMES)}")
            apply(arrays[f"{kind}_position"], override.name, override.position)
            apply(arrays[f"{kind}_velocity"], override.name, override.velocity)
    if not math.isfinite(goal_time) or goal_time < 0:
        raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL,
                              f"goal_time_tolerance must be finite and >= 0, got {goal_time}")
    return Tolerances(**arrays, goal_time=goal_time if goal_time > 0 else defaults.goal_time)


def _check_joint_names(joint_names: Sequence[str]) -> list[int]:
    """Index of each goal joint in ARM_JOINT_NAMES; every arm joint must appear exactly once."""
    unknown = [name for name in joint_names if name not in ARM_JOINT_NAMES]
    if unknown:
        raise TrajectoryError(TrajectoryErrorCode.INVALID_JOINTS,
                              f"unknown joints {unknown}; this arm has {list(ARM_JOINT_NAMES)}")
    duplicates = sorted({name for name in joint_names if list(joint_names).count(name) > 1})
    if duplicates:
        raise TrajectoryError(TrajectoryErrorCode.INVALID_JOINTS,
                              f"joints named more than once: {duplicates}")
    missing = [name for name in ARM_JOINT_NAMES if name not in joint_names]
    if missing:
        raise TrajectoryError(TrajectoryErrorCode.INVALID_JOINTS,
                              f"joints missing from the goal: {missing} (partial goals are not "
                              "supported; give all seven)")
    return [ARM_JOINT_NAMES.index(name) for name in joint_names]


def _stack_field(rows: Sequence[Sequence[float]], name: str, num_joints: int
                 ) -> np.ndarray | None:
    """(N, num_joints) array of a waypoint field that all points give, or None if none give it."""
    lengths = {len(row) for row in rows}
    if lengths == {0}:
        return None
    if lengths != {num_joints}:
        raise TrajectoryError(
            TrajectoryErrorCode.INVALID_GOAL,
            f"every point must give {num_joints} {name} (one per joint) or, except for positions, "
            f"none; got lengths {sorted(lengths)}")
    array = np.array(rows, dtype=float)
    if not np.all(np.isfinite(array)):
        point = int(np.argwhere(~np.isfinite(array))[0][0])
        raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL,
                              f"point {point} has a non-finite value in {name}")
    return array


def validate_trajectory(joint_names: Sequence[str], times: Sequence[float],
                        positions: Sequence[Sequence[float]],
                        velocities: Sequence[Sequence[float]],
                        accelerations: Sequence[Sequence[float]],
                        limits: JointLimits) -> JointTrajectory:
    """Check a trajectory message's content and reorder it to ARM_JOINT_NAMES.

    Args:
        joint_names: names of the columns, a permutation of ARM_JOINT_NAMES.
        times: (N,) time_from_start of each point, seconds.
        positions: N rows of len(joint_names) values.
        velocities, accelerations: N rows each, all empty or all full.
        limits: the arm's joint limits.

    Raises:
        TrajectoryError: INVALID_JOINTS for unknown, duplicate or missing joints; INVALID_GOAL
            for no points, ragged or non-finite values, times not strictly increasing, positions
            beyond the joint limits, or speeds beyond the velocity limits.
    """
    order = _check_joint_names(joint_names)
    if len(times) == 0:
        raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL, "the trajectory has no points")
    if not (len(positions) == len(velocities) == len(accelerations) == len(times)):
        raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL,
                              "points, times and per-point fields differ in count")
    times_array = np.array(times, dtype=float)
    if not np.all(np.isfinite(times_array)) or times_array[0] < 0:
        raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL,
                              "time_from_start must be finite and >= 0, got "
                              f"{times_array.tolist()}")
    steps = np.diff(times_array)
    if np.any(steps <= 0):
        point = int(np.argmax(steps <= 0)) + 1
        raise TrajectoryError(
            TrajectoryErrorCode.INVALID_GOAL,
            f"time_from_start must strictly increase; point {point} at {times_array[point]} s "
            f"does not come after point {point - 1} at {times_array[point - 1]} s")
    if any(len(row) != len(joint_names) for row in positions):
        raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL,
                              f"every point must give {len(joint_names)} positions")
    inverse = np.argsort(order)   # column j of the result is goal column inverse[j]
    position_array = _stack_field(positions, "positions", len(joint_names))[:, inverse]
    velocity_array = _stack_field(velocities, "velocities", len(joint_names))
    acceleration_array = _stack_field(accelerations, "accelerations", len(joint_names))
    if acceleration_array is not None and velocity_array is None:
        raise TrajectoryError(TrajectoryErrorCode.INVALID_GOAL,
                              "accelerations given without velocities")
    if velocity_array is not None:
        velocity_array = velocity_array[:, inverse]
    if acceleration_array is not None:
        acceleration_array = acceleration_array[:, inverse]

    outside = (position_array < limits.lower - LIMIT_SLACK) | (
        position_array > limits.upper + LIMIT_SLACK)
    if np.any(outside):
        point, joint = (int(i) for i in np.argwhere(outside)[0])
        raise TrajectoryError(
            TrajectoryErrorCode.INVALID_GOAL,
            f"point {point}: {ARM_JOINT_NAMES[joint]} = {position_array[point, joint]:.4f} rad "
            f"is beyond its limits [{limits.lower[joint]:.4f}, {limits.upper[joint]:.4f}]")
    if velocity_array is not None:
        too_fast = np.abs(velocity_array) > limits.velocity + LIMIT_SLACK
        if np.any(too_fast):
            point, joint = (int(i) for i in np.argwhere(too_fast)[0])
            raise TrajectoryError(
                TrajectoryErrorCode.INVALID_GOAL,
                f"point {point}: {ARM_JOINT_NAMES[joint]} velocity "
                f"{velocity_array[point, joint]:.3f} rad/s exceeds its limit "
                f"{limits.velocity[joint]:.3f}")
    if len(times_array) > 1:
        mean_speeds = np.abs(np.diff(position_array, axis=0)) / steps[:, None]
        too_fast = mean_speeds > limits.velocity + LIMIT_SLACK
        if np.any(too_fast):
            segment, joint = (int(i) for i in np.argwhere(too_fast)[0])
            raise TrajectoryError(
                TrajectoryErrorCode.INVALID_GOAL,
                f"points {segment}->{segment + 1}: {ARM_JOINT_NAMES[joint]} must move at "
                f"{mean_speeds[segment, joint]:.3f} rad/s on average, beyond its limit "
                f"{limits.velocity[joint]:.3f}")
    return JointTrajectory(times_array, position_array, velocity_array, acceleration_array)


def segment_coefficients(start: SetPoint, end: SetPoint, duration: float,
                         degree: int) -> np.ndarray:
    """Polynomial coefficients (6, 7) of the reference between two waypoints `duration` apart.

    Row k multiplies s**k, s being the time since the first waypoint. degree 1 (positions only)
    interpolates linearly; 3 matches positions and velocities at both ends (cubic Hermite); 5
    matches accelerations too (quintic), as JTC's spline interpolation does.
    """
    p0, p1, T = start.positions, end.positions, duration
    coefficients = np.zeros((6, NUM_JOINTS))
    coefficients[0] = p0
    if degree == 1:
        coefficients[1] = (p1 - p0) / T
        return coefficients
    v0, v1 = start.velocities, end.velocities
    coefficients[1] = v0
    if degree == 3:
        coefficients[2] = (3.0 * (p1 - p0) - (2.0 * v0 + v1) * T) / T**2
        coefficients[3] = (2.0 * (p0 - p1) + (v0 + v1) * T) / T**3
        return coefficients
    a0, a1 = start.accelerations, end.accelerations
    coefficients[2] = a0 / 2.0
    coefficients[3] = (20.0 * (p1 - p0) - (8.0 * v1 + 12.0 * v0) * T
                       - (3.0 * a0 - a1) * T**2) / (2.0 * T**3)
    coefficients[4] = (30.0 * (p0 - p1) + (14.0 * v1 + 16.0 * v0) * T
                       + (3.0 * a0 - 2.0 * a1) * T**2) / (2.0 * T**4)
    coefficients[5] = (12.0 * (p1 - p0) - 6.0 * (v1 + v0) * T - (a0 - a1) * T**2) / (
        2.0 * T**5)
    return coefficients


def evaluate_segment(coefficients: np.ndarray, s: float) -> SetPoint:
    """Position, velocity and acceleration (7,) each of a segment (6, 7) at time s into it."""
    s2, s3 = s * s, s * s * s
    basis = np.array([[1.0, s, s2, s3, s3 * s, s3 * s2],
                      [0.0, 1.0, 2.0 * s, 3.0 * s2, 4.0 * s3, 5.0 * s3 * s],
                      [0.0, 0.0, 2.0, 6.0 * s, 12.0 * s2, 20.0 * s3]])
    values = basis @ coefficients
    return SetPoint(values[0], values[1], values[2])


class ExecutionStatus(enum.Enum):
    ACTIVE = "active"
    SUCCEEDED = "succeeded"
    ABORTED = "aborted"
    PREEMPTED = "preempted"
    CANCELED = "canceled"


@dataclass
class TrajectoryExecution:
    """One goal being (or having been) tracked; updated by the physics loop, read by the node.

    Times are simulation seconds. The tool error compares the tool position of the desired and
    the measured joint positions, the error that matters for pushing.
    """

    trajectory: JointTrajectory
    tolerances: Tolerances
    start_time: float
    state_before: SetPoint
    time_before: float
    status: ExecutionStatus = ExecutionStatus.ACTIVE
    error_code: TrajectoryErrorCode = TrajectoryErrorCode.SUCCESSFUL
    error_string: str = ""
    desired: SetPoint | None = None
    actual_positions: np.ndarray | None = None
    actual_velocities: np.ndarray | None = None
    time: float = 0.0
    tool_error_sum_sq: float = 0.0
    tool_error_max: float = 0.0
    tool_error_samples: int = 0
    _segment_starts: np.ndarray = field(init=False, repr=False)
    _segment_durations: list[float] = field(init=False, repr=False)
    _segments: list[np.ndarray] = field(init=False, repr=False)
    _final: SetPoint = field(init=False, repr=False)

    def __post_init__(self) -> None:
        """Precompute every segment's polynomial; sampling then costs one small product."""
        traj = self.trajectory
        if traj.accelerations is not None:
            degree = 5
        elif traj.velocities is not None:
            degree = 3
        else:
            degree = 1
        times = traj.times + self.start_time
        starts, durations, segments = [], [], []
        # Before the first waypoint: from the state when the goal arrived, unless the first
        # waypoint's time has already passed (then the reference jumps to it, as in JTC).
        if times[0] > self.time_before:
            starts.append(self.time_before)
            durations.append(times[0] - self.time_before)
            segments.append(segment_coefficients(self.state_before, self.waypoint(0),
                                                 durations[-1], degree))
        else:
            starts.append(times[0])
            durations.append(0.0)
            segments.append(segment_coefficients(self.waypoint(0), self.waypoint(0), 1.0, 1))
        for index in range(len(times) - 1):
            starts.append(times[index])
            durations.append(times[index + 1] - times[index])
            segments.append(segment_coefficients(self.waypoint(index),
                                                 self.waypoint(index + 1), durations[-1],
                                                 degree))
        self._segment_starts = np.array(starts)
        self._segment_durations = durations
        self._segments = segments
        self._final = SetPoint.at_rest(traj.positions[-1])

    @property
    def end_time(self) -> float:
        return self.start_time + self.trajectory.duration

    @property
    def done(self) -> bool:
        return self.status is not ExecutionStatus.ACTIVE

    @property
    def tool_rms_error(self) -> float:
        """RMS tool error in metres over the steps tracked so far (0 before the first)."""
        if self.tool_error_samples == 0:
            return 0.0
        return math.sqrt(self.tool_error_sum_sq / self.tool_error_samples)

    def waypoint(self, index: int) -> SetPoint:
        traj = self.trajectory
        zeros = np.zeros(NUM_JOINTS)
        return SetPoint(
            traj.positions[index],
            traj.velocities[index] if traj.velocities is not None else zeros,
            traj.accelerations[index] if traj.accelerations is not None else zeros)

    def sample(self, time: float) -> SetPoint:
        """Desired state at simulation time `time` (the last waypoint, at rest, after the end)."""
        if time >= self.end_time:
            return self._final
        index = max(0, int(np.searchsorted(self._segment_starts, time, side="right")) - 1)
        elapsed = min(max(time - self._segment_starts[index], 0.0),
                      self._segment_durations[index])
        return evaluate_segment(self._segments[index], elapsed)

    def finish(self, status: ExecutionStatus, code: TrajectoryErrorCode, message: str) -> None:
        self.status, self.error_code, self.error_string = status, code, message


@dataclass(frozen=True)
class ControllerGains:
    kp: float = 2500.0   # 1/s^2
    kd: float = 100.0    # 1/s


class TrajectoryController:
    """Computed-torque tracking of one trajectory at a time, holding position in between.

    Args:
        limits: joint limits; effort limits clip the torques.
        inverse_dynamics: (q, qd, qdd) -> tau, each (7,), of the simulated robot.
        tool_position: q (7,) -> ball centre (3,), for the tool tracking error.
        default_tolerances: used where a goal leaves a tolerance at 0.
        gains: computed-torque gains.
        initial_positions: (7,) the position to hold before the first goal.
    """

    def __init__(self, limits: JointLimits,
                 inverse_dynamics: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
                 tool_position: Callable[[np.ndarray], np.ndarray],
                 default_tolerances: Tolerances, initial_positions: np.ndarray,
                 gains: ControllerGains = ControllerGains()) -> None:
        self.limits = limits
        self.default_tolerances = default_tolerances
        self.gains = gains
        self._inverse_dynamics = inverse_dynamics
        self._tool_position = tool_position
        self._hold = SetPoint.at_rest(initial_positions)
        self._desired = self._hold
        self.active: TrajectoryExecution | None = None

    @property
    def desired(self) -> SetPoint:
        """The most recent commanded state."""
        return self._desired

    def reset(self, positions: np.ndarray) -> None:
        """Forget any goal (it is aborted) and hold `positions`, e.g. after a world reset."""
        if self.active is not None:
            self.active.finish(ExecutionStatus.PREEMPTED, TrajectoryErrorCode.PREEMPTED,
                               "preempted by a reset of the simulated world")
            self.active = None
        self._hold = SetPoint.at_rest(positions)
        self._desired = self._hold

    def start(self, trajectory: JointTrajectory, tolerances: Tolerances, start_time: float,
              now: float) -> TrajectoryExecution:
        """Begin tracking `trajectory` whose time 0 is `start_time`; preempts the active goal.

        The new reference starts from the current desired state at `now`, so preemption does not
        make the reference jump.
        """
        if start_time + trajectory.duration < now:
            raise TrajectoryError(
                TrajectoryErrorCode.OLD_HEADER_TIMESTAMP,
                f"the trajectory ended at t = {start_time + trajectory.duration:.3f} s, before "
                f"now ({now:.3f} s)")
        if self.active is not None:
            self.active.finish(ExecutionStatus.PREEMPTED, TrajectoryErrorCode.PREEMPTED,
                               "preempted by a new goal")
        self.active = TrajectoryExecution(trajectory, tolerances, start_time, self._desired, now,
                                          time=now)
        return self.active

    def cancel(self, execution: TrajectoryExecution) -> None:
        """Stop `execution` if it is still the active goal, holding the desired position."""
        if execution is self.active:
            execution.finish(ExecutionStatus.CANCELED, TrajectoryErrorCode.CANCELED,
                             "canceled by the client")
            self._hold = SetPoint.at_rest(self._desired.positions)
            self.active = None

    def _abort(self, code: TrajectoryErrorCode, message: str, positions: np.ndarray) -> None:
        self.active.finish(ExecutionStatus.ABORTED, code, message)
        self.active = None
        self._hold = SetPoint.at_rest(positions)

    def update(self, now: float, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """Torques (7,) for the measured state (7,), (7,) at simulation time `now`."""
        execution = self.active
        if execution is None:
            desired = self._hold
        else:
            desired = execution.sample(now)
            self._track(execution, now, desired, positions, velocities)
            if execution.done:
                desired = self._hold
        self._desired = desired
        acceleration = (desired.accelerations
                        + self.gains.kp * (desired.positions - positions)
                        + self.gains.kd * (desired.velocities - velocities))
        torques = self._inverse_dynamics(positions, velocities, acceleration)
        return np.clip(torques, -self.limits.effort, self.limits.effort)

    def _track(self, execution: TrajectoryExecution, now: float, desired: SetPoint,
               positions: np.ndarray, velocities: np.ndarray) -> None:
        """Record errors and apply the tolerance rules; may finish the execution."""
        execution.time = now
        execution.desired = desired
        execution.actual_positions = positions
        execution.actual_velocities = velocities
        tool_error = math.dist(self._tool_position(desired.positions),
                               self._tool_position(positions))
        execution.tool_error_sum_sq += tool_error * tool_error
        execution.tool_error_max = max(execution.tool_error_max, tool_error)
        execution.tool_error_samples += 1
        tolerances = execution.tolerances
        position_error = np.abs(desired.positions - positions)
        if now < execution.end_time:
            velocity_error = np.abs(desired.velocities - velocities)
            violated = (position_error > tolerances.path_position) | (
                velocity_error > tolerances.path_velocity)
            if np.any(violated):
                joint = int(np.argmax(violated))
                self._abort(
                    TrajectoryErrorCode.PATH_TOLERANCE_VIOLATED,
                    f"{ARM_JOINT_NAMES[joint]} left the path tolerance at t = "
                    f"{now - execution.start_time:.3f} s: position error "
                    f"{position_error[joint]:.4f} rad (tolerance "
                    f"{tolerances.path_position[joint]}), velocity error "
                    f"{velocity_error[joint]:.4f} rad/s (tolerance "
                    f"{tolerances.path_velocity[joint]})", positions)
            return
        reached = np.all(position_error <= tolerances.goal_position) and np.all(
            np.abs(velocities) <= tolerances.goal_velocity)
        if reached:
            execution.finish(ExecutionStatus.SUCCEEDED, TrajectoryErrorCode.SUCCESSFUL, "")
            self._hold = SetPoint.at_rest(desired.positions)
            self.active = None
        elif now > execution.end_time + tolerances.goal_time:
            joint = int(np.argmax(position_error - tolerances.goal_position))
            self._abort(
                TrajectoryErrorCode.GOAL_TOLERANCE_VIOLATED,
                f"goal not reached {tolerances.goal_time} s after the trajectory's end: "
                f"{ARM_JOINT_NAMES[joint]} is {position_error[joint]:.4f} rad off (tolerance "
                f"{tolerances.goal_position[joint]}), max speed "
                f"{np.abs(velocities).max():.4f} rad/s", positions)
