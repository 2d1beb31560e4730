"""Shared fixtures: the overhead camera as perception sees it; synthetic depth/colour frames."""

import numpy as np
import pytest

from tsrrt_common.camera import OverheadCamera
from tsrrt_common.geometry import Pose2D, footprint_polygon
from tsrrt_common.object_classes import ObjectClass, load_class_table
from tsrrt_perception.camera_view import CameraView

Face = tuple[np.ndarray, float, tuple[int, int, int]]


class FacePainter:
    """Synthetic frames of flat faces (no side faces, no shading) seen by a camera."""

    def __init__(self, camera: CameraView) -> None:
        self.camera = camera

    @staticmethod
    def face(cls: ObjectClass, pose: Pose2D,
             colour: tuple[int, int, int] = (200, 60, 60)) -> Face:
        """Top face of an object of class cls at pose."""
        polygon = footprint_polygon(cls.shape, cls.length, cls.width, pose, disc_sides=90)
        return polygon, cls.height, colour

    def draw(self, faces: list[Face]) -> tuple[np.ndarray, np.ndarray]:
        """Depth (H, W) float32 and rgb (H, W, 3) of faces over a grey table at z = 0.

        A pixel shows a face when its centre lies inside the face's projection (as a renderer
        samples it) and no higher face covers it.

        Args:
            faces: (convex footprint (N, 2) in the world, height above the table, colour).
        """
        camera = self.camera
        heights = np.zeros((camera.height, camera.width), np.float32)
        rgb = np.full((camera.height, camera.width, 3), 120, np.uint8)
        u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        for footprint, height, colour in faces:
            corners = np.column_stack([footprint, np.full(len(footprint), height)])
            pixels = camera.world_to_pixels(corners)
            edges = np.roll(pixels, -1, axis=0) - pixels
            crosses = np.stack([edge[0] * (v - start[1]) - edge[1] * (u - start[0])
                                for start, edge in zip(pixels, edges, strict=True)])
            inside = np.all(crosses >= 0, axis=0) | np.all(crosses <= 0, axis=0)
            visible = inside & (heights < height)
            heights[visible] = height
            rgb[visible] = colour
        return (camera.position[2] - heights).astype(np.float32), rgb


@pytest.fixture(scope="session")
def classes() -> dict[str, ObjectClass]:
    return load_class_table()


@pytest.fixture(scope="session")
def camera_view() -> CameraView:
    camera = OverheadCamera()
    return CameraView(camera.intrinsics, camera.width, camera.height)


@pytest.fixture(scope="session")
def painter(camera_view) -> FacePainter:
    return FacePainter(camera_view)
