"""The overhead camera: one pinhole model the simulator renders with and perception inverts.

Frames: the camera's optical frame follows ROS (z forward, x right, y down). It looks straight
down, with image right along world -y and image down along world -x, so the robot base is at
the bottom of the image. Pixel coordinates follow OpenCV: the centre of pixel (u, v) is at (u, v).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Columns are the optical axes (x right, y down, z forward) expressed in the world frame.
R_WORLD_OPTICAL = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


@dataclass(frozen=True)
class OverheadCamera:
    """Pinhole camera above the table looking straight down."""

    width: int = 640
    height: int = 480
    fov_y_deg: float = 36.0
    position: tuple[float, float, float] = (0.45, 0.0, 0.9)   # optical centre in the world frame
    near: float = 0.1
    far: float = 2.0

    @property
    def focal_length_px(self) -> float:
        return (self.height / 2.0) / math.tan(math.radians(self.fov_y_deg) / 2.0)

    @property
    def intrinsics(self) -> np.ndarray:
        """K (3, 3) in OpenCV convention, as published in CameraInfo."""
        f = self.focal_length_px
        return np.array([[f, 0.0, (self.width - 1) / 2.0], [0.0, f, (self.height - 1) / 2.0],
                         [0.0, 0.0, 1.0]])

    def project_world_points(self, points_world: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of world points (N, 3)."""
        points_optical = (np.asarray(points_world) - np.array(self.position)) @ R_WORLD_OPTICAL
        uvw = points_optical @ self.intrinsics.T
        return uvw[:, :2] / uvw[:, 2:3]

    def pixels_to_world_on_plane(self, pixels: np.ndarray, plane_z: float) -> np.ndarray:
        """World points (N, 3) where the rays through pixels (N, 2) meet the plane z = plane_z."""
        pixels = np.atleast_2d(np.asarray(pixels, dtype=float))
        rays_optical = np.column_stack([pixels, np.ones(len(pixels))]) @ np.linalg.inv(
            self.intrinsics).T
        rays_world = rays_optical @ R_WORLD_OPTICAL.T
        scale = (plane_z - self.position[2]) / rays_world[:, 2]
        return np.array(self.position) + rays_world * scale[:, None]
