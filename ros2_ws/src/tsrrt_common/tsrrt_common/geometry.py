"""Planar geometry shared by every package: poses on the table, angle wrapping, footprints."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap to [-pi, pi) so differences of headings are never off by a full turn.

    Works elementwise on arrays; a Python float in gives a float out.
    """
    wrapped = (np.asarray(angle, dtype=float) + math.pi) % (2.0 * math.pi) - math.pi
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def symmetry_period(symmetry: int) -> float:
    """Angle after which a footprint of the given rotational symmetry order looks the same.

    symmetry 0 means continuous (a disc): every angle is equivalent, period 0.
    """
    if symmetry < 0:
        raise ValueError(f"symmetry order must be >= 0, got {symmetry}")
    return 0.0 if symmetry == 0 else 2.0 * math.pi / symmetry


def angle_difference_modulo_symmetry(a: float, b: float, symmetry: int) -> float:
    """Smallest signed rotation taking b to a for a footprint of the given symmetry."""
    period = symmetry_period(symmetry)
    if period == 0.0:
        return 0.0
    return (a - b + period / 2.0) % period - period / 2.0


@dataclass(frozen=True)
class Pose2D:
    """Pose of an object frame in the table (world) frame: T_world_object in the plane."""

    x: float
    y: float
    theta: float

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.theta])

    def transform_point_to_world(self, point_object: np.ndarray) -> np.ndarray:
        """Map points (..., 2) given in the object frame into the world frame."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        rotation = np.array([[c, -s], [s, c]])
        return np.asarray(point_object) @ rotation.T + np.array([self.x, self.y])

    def transform_point_to_object(self, point_world: np.ndarray) -> np.ndarray:
        """Map points (..., 2) given in the world frame into the object frame."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        rotation = np.array([[c, -s], [s, c]])
        return (np.asarray(point_world) - np.array([self.x, self.y])) @ rotation

    def displacement_in_object_frame(self, after: Pose2D) -> np.ndarray:
        """(dx, dy, dtheta) of `after` relative to this pose, in this pose's frame (paper's Δs)."""
        dxy = self.transform_point_to_object(np.array([after.x, after.y]))
        return np.array([dxy[0], dxy[1], wrap_angle(after.theta - self.theta)])

    def apply_displacement(self, delta_object: np.ndarray) -> Pose2D:
        """Pose after a displacement (dx, dy, dtheta) expressed in this pose's frame."""
        xy = self.transform_point_to_world(np.asarray(delta_object[:2], dtype=float))
        return Pose2D(float(xy[0]), float(xy[1]), float(self.theta + delta_object[2]))


def box_corners(length: float, width: float) -> np.ndarray:
    """Corners (4, 2) of a length x width rectangle centred at the origin, counter-clockwise."""
    hl, hw = length / 2.0, width / 2.0
    return np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])


def footprint_polygon(shape: str, length: float, width: float, pose: Pose2D,
                      disc_sides: int = 24) -> np.ndarray:
    """World-frame footprint (N, 2), counter-clockwise; a disc becomes a circumscribed polygon.

    The circumscribed polygon contains the disc, so overlap tests on it are conservative.
    """
    if shape == "box":
        return pose.transform_point_to_world(box_corners(length, width))
    angles = np.arange(disc_sides) * (2.0 * math.pi / disc_sides)
    radius = (length / 2.0) / math.cos(math.pi / disc_sides)
    return np.column_stack([pose.x + radius * np.cos(angles), pose.y + radius * np.sin(angles)])


def convex_polygons_separated(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> bool:
    """Separating-axis test: True when convex polygons a and b are at least `margin` apart
    along some edge normal (a conservative clearance test for margin > 0)."""
    for polygon in (a, b):
        edges = np.roll(polygon, -1, axis=0) - polygon
        normals = np.column_stack([edges[:, 1], -edges[:, 0]])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        projections_a = a @ normals.T
        projections_b = b @ normals.T
        gap = np.maximum(projections_b.min(axis=0) - projections_a.max(axis=0),
                         projections_a.min(axis=0) - projections_b.max(axis=0))
        if np.any(gap >= margin):
            return True
    return False
