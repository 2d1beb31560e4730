"""Inverse kinematics of the Panda pusher: ball centre at a point with the tool pointing down.

The paper used analytical IK for its arm; the Panda is redundant (7 joints for a 5-D task:
3 position + 2 for the tool axis, yaw free since the ball is round), so this solves the task with
damped least squares on Pinocchio's analytic frame Jacobian, on the same URDF the simulator loads:

    task residual  r(q) = [p_tool(q) - p_target ; z_tool(q) - (0, 0, -1)]           (6,)
    task Jacobian  J(q) = [J_v ; -[z_tool]x J_w]   (LOCAL_WORLD_ALIGNED)             (6, 7)
    step           dq = -J+ r + (I - J+ J) k (q_rest - q),   J+ = J^T (J J^T + l^2 I)^-1

The null-space term pulls the redundancy (elbow, wrist yaw) towards the ready posture, so postures
along a path stay close to it and to each other. Joint limits are respected by projection: a joint
that the step would push past a limit is locked at the limit and the step is recomputed without
it. Warm-starting each waypoint from the previous solution makes a path cost 1-3 iterations per
waypoint and keeps the arm on one continuous branch.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from tsrrt_common.robot_model import ARM_JOINT_NAMES, READY_POSTURE, TOOL_FRAME, pusher_urdf_path
from tsrrt_executor.errors import IKError

TOOL_AXIS_DOWN = np.array([0.0, 0.0, -1.0])
# Franka Emika Panda datasheet joint acceleration limits (rad/s^2); the URDF carries none.
PANDA_ACCELERATION_LIMITS = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])


@dataclass(frozen=True)
class IKSettings:
    """Tuning of the solver. Tolerances are on the converged task, not on each step."""

    position_tolerance: float = 1e-5      # metres (target: <= 0.1 mm)
    axis_tolerance: float = 1e-4          # |z_tool - down|, ~ radians of tool tilt
    damping: float = 1e-3                 # lambda of damped least squares
    null_space_gain: float = 0.2          # fraction of (q_rest - q) pulled per iteration
    max_step: float = 0.4                 # rad, largest joint change per iteration
    max_iterations: int = 200
    limit_margin: float = 0.01            # rad kept inside every joint limit


class PusherIK:
    """IK for the ball centre (TOOL_FRAME) with the tool axis pointing straight down."""

    def __init__(self, urdf_path: Path | None = None, settings: IKSettings | None = None,
                 rest_posture: tuple[float, ...] = READY_POSTURE) -> None:
        self.model = pin.buildModelFromUrdf(str(urdf_path or pusher_urdf_path()))
        self.data = self.model.createData()
        self.settings = settings or IKSettings()
        joint_names = tuple(self.model.names[1:])
        if joint_names != ARM_JOINT_NAMES or self.model.nq != len(ARM_JOINT_NAMES):
            raise IKError(f"expected the 7 revolute joints {ARM_JOINT_NAMES}, the URDF has "
                          f"{joint_names}", float("nan"), float("nan"))
        self.tool_frame_id = self.model.getFrameId(TOOL_FRAME)
        margin = self.settings.limit_margin
        self.lower_limits = self.model.lowerPositionLimit.copy() + margin   # (7,)
        self.upper_limits = self.model.upperPositionLimit.copy() - margin   # (7,)
        self.velocity_limits = self.model.velocityLimit.copy()              # (7,)
        self.acceleration_limits = PANDA_ACCELERATION_LIMITS.copy()         # (7,)
        self.rest_posture = np.array(rest_posture, dtype=float)

    def tool_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ball centre position (3,) and tool z axis (3,) in the base frame."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        placement = self.data.oMf[self.tool_frame_id]
        return placement.translation.copy(), placement.rotation[:, 2].copy()

    def tool_position(self, q: np.ndarray) -> np.ndarray:
        """Ball centre position (3,) in the base frame."""
        return self.tool_pose(q)[0]

    def tool_positions(self, joint_path: np.ndarray) -> np.ndarray:
        """Ball centre positions (N, 3) for joint configurations (N, 7)."""
        return np.array([self.tool_position(q) for q in np.atleast_2d(joint_path)])

    def task_residual(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        """r(q) (6,): position error and tool-axis error of configuration q (7,)."""
        position, axis = self.tool_pose(q)
        return np.concatenate([position - target, axis - TOOL_AXIS_DOWN])

    def _residual_and_jacobian(self, q: np.ndarray, target: np.ndarray
                               ) -> tuple[np.ndarray, np.ndarray]:
        frame_jacobian = pin.computeFrameJacobian(self.model, self.data, q, self.tool_frame_id,
                                                  pin.LOCAL_WORLD_ALIGNED)          # (6, 7)
        placement = self.data.oMf[self.tool_frame_id]
        axis = placement.rotation[:, 2]
        residual = np.concatenate([placement.translation - target, axis - TOOL_AXIS_DOWN])
        jacobian = np.vstack([frame_jacobian[:3], -pin.skew(axis) @ frame_jacobian[3:]])
        return residual, jacobian

    def task_jacobian(self, q: np.ndarray) -> np.ndarray:
        """dr/dq (6, 7), analytic: linear velocity rows and d(z_tool) = w x z_tool rows."""
        return self._residual_and_jacobian(np.asarray(q, dtype=float), np.zeros(3))[1]

    def _converged(self, residual: np.ndarray) -> bool:
        return (float(np.linalg.norm(residual[:3])) <= self.settings.position_tolerance
                and float(np.linalg.norm(residual[3:])) <= self.settings.axis_tolerance)

    def _step(self, q: np.ndarray, residual: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
        settings = self.settings
        free = np.ones(q.size, dtype=bool)
        for _ in range(2):  # second pass only when a joint had to be locked at its limit
            active = jacobian * free                                           # (6, 7)
            gram = active @ active.T + settings.damping ** 2 * np.eye(residual.size)
            pseudo_inverse = active.T @ np.linalg.solve(gram, np.eye(residual.size))  # (7, 6)
            null_projector = np.eye(q.size) - pseudo_inverse @ active
            pull = settings.null_space_gain * (self.rest_posture - q) * free
            step = -pseudo_inverse @ residual + null_projector @ pull
            largest = float(np.abs(step).max())
            if largest > settings.max_step:
                step *= settings.max_step / largest
            proposed = q + step
            blocked = free & (((proposed < self.lower_limits) & (step < 0.0))
                              | ((proposed > self.upper_limits) & (step > 0.0)))
            if not blocked.any():
                break
            free &= ~blocked
        return np.clip(q + step, self.lower_limits, self.upper_limits)

    def solve(self, target: np.ndarray, q_init: np.ndarray | None = None
              ) -> tuple[np.ndarray, int]:
        """Joint configuration (7,) putting the ball centre at `target` (3,), tool down.

        Args:
            target: ball centre position in the base frame, metres.
            q_init: start of the iteration (warm start); the rest posture when None.

        Returns:
            (q, iterations used).

        Raises:
            IKError: no convergence within max_iterations (target out of reach, or a joint limit
                in the way), with the remaining residual.
        """
        target = np.asarray(target, dtype=float).reshape(3)
        q = np.clip(np.array(self.rest_posture if q_init is None else q_init, dtype=float),
                    self.lower_limits, self.upper_limits)
        for iteration in range(self.settings.max_iterations + 1):
            residual, jacobian = self._residual_and_jacobian(q, target)
            if self._converged(residual):
                return q, iteration
            q = self._step(q, residual, jacobian)
        raise IKError(f"no IK solution for ball centre at {np.round(target, 4).tolist()} with "
                      "the tool pointing down", float(np.linalg.norm(residual[:3])),
                      float(np.linalg.norm(residual[3:])))

    def solve_path(self, targets: np.ndarray, q_start: np.ndarray | None = None
                   ) -> tuple[np.ndarray, int]:
        """Joint path (N, 7) through ball-centre targets (N, 3), each warm-started from the last.

        Returns:
            (joint path, total iterations). Raises IKError naming the first failing waypoint.
        """
        targets = np.atleast_2d(np.asarray(targets, dtype=float))
        path = np.empty((len(targets), self.model.nq))
        q = q_start
        total = 0
        for index, target in enumerate(targets):
            try:
                q, iterations = self.solve(target, q)
            except IKError as error:
                raise IKError(f"waypoint {index} of {len(targets)}: {error.reason}",
                              error.position_error, error.orientation_error) from None
            path[index] = q
            total += iterations
        return path, total
