"""Shared geometry, class table, camera model and the generated pusher URDF."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tsrrt_common.camera import OverheadCamera
from tsrrt_common.errors import ClassTableError
from tsrrt_common.geometry import (
    Pose2D,
    angle_difference_modulo_symmetry,
    convex_polygons_separated,
    footprint_polygon,
    wrap_angle,
)
from tsrrt_common.object_classes import load_class_table, lookup_class
from tsrrt_common.robot_model import TOOL_FRAME, pusher_urdf_path


def test_wrap_angle_scalar_and_array() -> None:
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    np.testing.assert_allclose(wrap_angle(np.array([0.1, 2 * math.pi + 0.1])), [0.1, 0.1])


@pytest.mark.parametrize(("a", "b", "symmetry", "expected"), [
    (math.pi - 0.01, -math.pi + 0.01, 2, -0.02),
    (math.pi / 2 + 0.01, 0.0, 4, 0.01),
    (1.0, -2.0, 0, 0.0),
    (0.3, 0.1, 1, 0.2),
])
def test_angle_difference_respects_symmetry(a: float, b: float, symmetry: int,
                                            expected: float) -> None:
    assert angle_difference_modulo_symmetry(a, b, symmetry) == pytest.approx(expected)


def test_displacement_round_trip_in_object_frame() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        pose = Pose2D(*rng.uniform(-1, 1, 3))
        delta = rng.uniform(-0.1, 0.1, 3)
        np.testing.assert_allclose(pose.displacement_in_object_frame(
            pose.apply_displacement(delta)), delta, atol=1e-12)


def test_separating_axis_matches_dense_sampling() -> None:
    rng = np.random.default_rng(1)
    for _ in range(200):
        a = footprint_polygon("box", 0.12, 0.05, Pose2D(0.0, 0.0, rng.uniform(-3, 3)))
        b = footprint_polygon("box", 0.10, 0.04, Pose2D(*rng.uniform(-0.12, 0.12, 2),
                                                        rng.uniform(-3, 3)))
        grid = np.stack(np.meshgrid(np.linspace(-0.2, 0.2, 201), np.linspace(-0.2, 0.2, 201)),
                        axis=-1).reshape(-1, 2)
        inside_a = _inside_convex(grid, a)
        inside_b = _inside_convex(grid, b)
        if np.any(inside_a & inside_b):
            assert not convex_polygons_separated(a, b)


def _inside_convex(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    edges = np.roll(polygon, -1, axis=0) - polygon
    relative = points[:, None, :] - polygon[None, :, :]
    cross = edges[None, :, 0] * relative[:, :, 1] - edges[None, :, 1] * relative[:, :, 0]
    return np.all(cross >= 0, axis=1)


def test_class_table_ships_the_papers_objects() -> None:
    table = load_class_table()
    assert {"plate", "platter", "eraser", "remote", "scale", "hole_punch"} <= set(table)
    assert lookup_class(table, "plate").symmetry == 0
    with pytest.raises(ClassTableError, match="known: "):
        lookup_class(table, "teapot")


def test_malformed_class_table_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "classes.yaml"
    path.write_text("classes:\n  thing: {shape: pyramid, size: [1, 1, 1], symmetry: 2, "
                    "tolerance: 0.01}\n")
    with pytest.raises(ClassTableError, match="pyramid"):
        load_class_table(path)


def test_camera_projection_round_trip() -> None:
    camera = OverheadCamera()
    points = np.array([[0.45, 0.0, 0.0], [0.3, 0.2, 0.02], [0.6, -0.25, 0.05]])
    pixels = camera.project_world_points(points)
    np.testing.assert_allclose(pixels[0], [(camera.width - 1) / 2, (camera.height - 1) / 2])
    # World -y is image right, world -x is image down.
    assert pixels[1, 0] < pixels[0, 0] and pixels[1, 1] > pixels[0, 1]
    for point, pixel in zip(points, pixels, strict=True):
        back = camera.pixels_to_world_on_plane(pixel[None], point[2])
        np.testing.assert_allclose(back[0], point, atol=1e-12)


def test_pusher_urdf_has_ball_tool_and_no_fingers(tmp_path: Path) -> None:
    text = pusher_urdf_path(tmp_path).read_text()
    assert f'name="{TOOL_FRAME}"' in text
    assert "finger" not in text
    assert "package://" not in text
