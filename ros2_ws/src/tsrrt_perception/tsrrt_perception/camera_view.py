"""The camera as perception knows it: K from CameraInfo plus a configured pose (there is no tf2).

Conventions follow tsrrt_common.camera.OverheadCamera: the optical frame is ROS's (z forward,
x right, y down), pixel (u, v) has its centre at (u, v) (OpenCV), depth images hold the optical z
of each pixel's surface point in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from tsrrt_common.camera import R_WORLD_OPTICAL, OverheadCamera
from tsrrt_common.errors import TsrrtError


class CameraModelError(TsrrtError):
    """CameraInfo is missing, uncalibrated or inconsistent with the image."""


def quaternion_to_matrix(xyzw: tuple[float, float, float, float]) -> np.ndarray:
    """Rotation (3, 3) of a unit quaternion given as (x, y, z, w); rejects a zero quaternion."""
    q = np.asarray(xyzw, dtype=float)
    norm = np.linalg.norm(q)
    if q.shape != (4,) or not np.isfinite(norm) or norm < 1e-9:
        raise CameraModelError(f"camera orientation {list(xyzw)} is not a quaternion (x, y, z, w)")
    x, y, z, w = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


# R_WORLD_OPTICAL of the overhead camera is a half turn about (1, -1, 0) / sqrt(2).
OVERHEAD_ORIENTATION_XYZW = (float(np.sqrt(0.5)), -float(np.sqrt(0.5)), 0.0, 0.0)


@dataclass(frozen=True, eq=False)
class CameraView:
    """A calibrated pinhole camera at a known pose in the world (table) frame."""

    intrinsics: np.ndarray              # K (3, 3)
    width: int
    height: int
    position: np.ndarray = field(default_factory=lambda: np.array(OverheadCamera().position))
    rotation_world_optical: np.ndarray = field(default_factory=lambda: R_WORLD_OPTICAL.copy())

    @classmethod
    def from_camera_info(cls, k: np.ndarray | list[float], width: int, height: int,
                         position: tuple[float, float, float],
                         orientation_xyzw: tuple[float, float, float, float]) -> CameraView:
        """Build from CameraInfo's row-major K (9,) and image size, and the configured pose.

        Raises:
            CameraModelError: K is all zero (uncalibrated), not invertible, or the size is empty.
        """
        k = np.asarray(k, dtype=float).reshape(-1)
        if k.size != 9:
            raise CameraModelError(f"CameraInfo K has {k.size} entries, expected 9")
        if not np.any(k):
            raise CameraModelError("CameraInfo K is all zero: the camera is uncalibrated")
        intrinsics = k.reshape(3, 3)
        if intrinsics[0, 0] <= 0 or intrinsics[1, 1] <= 0 or abs(intrinsics[2, 2] - 1.0) > 1e-9:
            raise CameraModelError(f"CameraInfo K {k.tolist()} is not a valid pinhole matrix")
        if width <= 0 or height <= 0:
            raise CameraModelError(f"CameraInfo image size {width}x{height} is empty")
        return cls(intrinsics, int(width), int(height), np.asarray(position, dtype=float),
                   quaternion_to_matrix(orientation_xyzw))

    @cached_property
    def _intrinsics_inverse(self) -> np.ndarray:
        return np.linalg.inv(self.intrinsics)

    @cached_property
    def _world_z_per_depth(self) -> np.ndarray:
        """(height, width) float32: world z change per metre of optical depth, for each pixel."""
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        rays_optical = np.stack([u, v, np.ones_like(u)], axis=-1) @ self._intrinsics_inverse.T
        return (rays_optical @ self.rotation_world_optical[2]).astype(np.float32)

    def heights_above_plane(self, depth: np.ndarray, plane_z: float) -> np.ndarray:
        """Height above the plane z = plane_z of each pixel's surface point.

        Args:
            depth: (height, width) optical depth in metres; non-finite or <= 0 means no return.
        Returns:
            (height, width) float32 heights; pixels without a valid depth get -inf.
        """
        if depth.shape != (self.height, self.width):
            raise CameraModelError(
                f"depth image is {depth.shape[1]}x{depth.shape[0]} but CameraInfo says "
                f"{self.width}x{self.height}")
        depth = depth.astype(np.float32, copy=False)
        heights = np.float32(self.position[2] - plane_z) + self._world_z_per_depth * depth
        heights[~(np.isfinite(depth) & (depth > 0))] = -np.inf
        return heights

    def pixels_to_plane(self, pixels: np.ndarray, plane_z: float) -> np.ndarray:
        """World points (N, 3) where the rays through pixels (N, 2) meet the plane z = plane_z."""
        pixels = np.atleast_2d(np.asarray(pixels, dtype=float))
        rays_optical = np.column_stack([pixels, np.ones(len(pixels))]) @ self._intrinsics_inverse.T
        rays_world = rays_optical @ self.rotation_world_optical.T
        scale = (plane_z - self.position[2]) / rays_world[:, 2]
        return self.position + rays_world * scale[:, None]

    def world_to_pixels(self, points_world: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of world points (N, 3)."""
        offsets = np.atleast_2d(points_world) - self.position
        points_optical = offsets @ self.rotation_world_optical
        uvw = points_optical @ self.intrinsics.T
        return uvw[:, :2] / uvw[:, 2:3]
