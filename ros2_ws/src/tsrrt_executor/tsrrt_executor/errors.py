"""Errors the executor raises on bad goals and infeasible motions (all TsrrtError subclasses)."""

from __future__ import annotations

from tsrrt_common.errors import TsrrtError


class ExecutorError(TsrrtError):
    """Base of every error raised by tsrrt_executor."""


class PrimitiveError(ExecutorError):
    """A push primitive was asked for that does not exist for this object (or bad push length)."""


class UnreachableError(ExecutorError):
    """A push's workspace path leaves the region the arm can reach with the tool pointing down."""


class IKError(ExecutorError):
    """Inverse kinematics did not converge; carries the remaining task residual."""

    def __init__(self, message: str, position_error: float, orientation_error: float) -> None:
        self.reason = message
        self.position_error = position_error
        self.orientation_error = orientation_error
        super().__init__(
            f"{message} (position residual {position_error * 1000:.3f} mm, "
            f"tool axis residual {orientation_error:.2e})"
        )


class TrajectoryError(ExecutorError):
    """A joint path cannot be time-parameterised (e.g. non-positive limits or speeds)."""
