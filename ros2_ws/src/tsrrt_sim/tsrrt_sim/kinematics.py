"""Pinocchio model of the Panda pusher: joint limits and the tool (ball centre) position.

The simulator measures tracking error at the tool, where pushing happens, rather than per joint.
Pinocchio loads the very URDF that PyBullet simulates, so both agree on the kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from tsrrt_common.robot_model import ARM_JOINT_NAMES, TOOL_FRAME, pusher_urdf_path


@dataclass(frozen=True)
class JointLimits:
    """Limits of the arm joints, each (7,) in ARM_JOINT_NAMES order, as the URDF states them."""

    lower: np.ndarray      # rad
    upper: np.ndarray      # rad
    velocity: np.ndarray   # rad/s
    effort: np.ndarray     # N m


class PusherKinematics:
    """Forward kinematics of the tool frame; not thread-safe (one pinocchio Data per instance)."""

    def __init__(self, urdf_path: Path | None = None) -> None:
        self.model = pin.buildModelFromUrdf(str(urdf_path or pusher_urdf_path()))
        names = tuple(self.model.names[1:])
        if names != ARM_JOINT_NAMES:
            raise ValueError(f"expected joints {ARM_JOINT_NAMES} in the URDF, found {names}")
        self._data = self.model.createData()
        self._tool_frame_id = self.model.getFrameId(TOOL_FRAME)
        self.limits = JointLimits(
            lower=self.model.lowerPositionLimit.copy(),
            upper=self.model.upperPositionLimit.copy(),
            velocity=self.model.velocityLimit.copy(),
            effort=self.model.effortLimit.copy(),
        )

    def tool_position(self, joint_positions: np.ndarray) -> np.ndarray:
        """Ball centre (3,) in the base (world) frame for joint positions (7,)."""
        pin.forwardKinematics(self.model, self._data, np.asarray(joint_positions, dtype=float))
        return pin.updateFramePlacement(self.model, self._data,
                                        self._tool_frame_id).translation.copy()
