"""A minimal PyBullet tabletop (table + boxes/cylinders, no robot) rendered by TinyRenderer.

Used by the benchmark and the tests to produce images with exact ground truth through the same
OverheadCamera the simulator uses. The camera's view and projection matrices are built from
OverheadCamera exactly as a simulator would; `pixel_centre_fix` optionally shifts the projection by
half a pixel, which is the correction TinyRenderer needs to agree with OverheadCamera.intrinsics
(it samples pixels at their corners: renders appear shifted by (+0.5, -0.5) px in (u, v)
otherwise); tsrrt_sim.world.opengl_projection_matrix applies the same correction, and a caller can
pass that matrix instead. The fix belongs in the renderer, never in perception.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet

from tsrrt_common.camera import OverheadCamera
from tsrrt_common.geometry import Pose2D
from tsrrt_common.object_classes import ObjectClass


@dataclass(frozen=True)
class PlacedObject:
    """Ground truth of one rendered object."""

    name: str
    object_class: ObjectClass
    pose: Pose2D
    color: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class RenderedFrame:
    rgb: np.ndarray       # (H, W, 3) uint8
    depth: np.ndarray     # (H, W) float32 optical depth, metres


class TabletopRenderer:
    """Owns one PyBullet DIRECT client with a table and the objects placed on it."""

    def __init__(self, camera: OverheadCamera | None = None, table_height: float = 0.0,
                 table_center: tuple[float, float] = (0.45, 0.0),
                 table_size: tuple[float, float] = (0.34, 0.52),
                 pixel_centre_fix: bool = False,
                 projection_matrix: list[float] | None = None) -> None:
        self.camera = camera or OverheadCamera()
        self.table_height = table_height
        self.client = pybullet.connect(pybullet.DIRECT)
        half = [table_size[0] / 2, table_size[1] / 2, 0.02]
        visual = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=half,
                                            rgbaColor=[0.55, 0.5, 0.45, 1.0],
                                            physicsClientId=self.client)
        pybullet.createMultiBody(0.0, -1, visual,
                                 basePosition=[*table_center, table_height - half[2]],
                                 physicsClientId=self.client)
        eye = list(self.camera.position)
        self.view_matrix = pybullet.computeViewMatrix(eye, [eye[0], eye[1], table_height],
                                                      [1.0, 0.0, 0.0])
        projection = list(pybullet.computeProjectionMatrixFOV(
            self.camera.fov_y_deg, self.camera.width / self.camera.height,
            self.camera.near, self.camera.far))
        if pixel_centre_fix:
            projection[8] += 1.0 / self.camera.width
            projection[9] += 1.0 / self.camera.height
        self.projection_matrix = projection_matrix or projection
        self.bodies: dict[str, int] = {}
        self.heights: dict[str, float] = {}

    def close(self) -> None:
        pybullet.disconnect(self.client)

    def add(self, name: str, object_class: ObjectClass, color: tuple[float, float, float]) -> None:
        if object_class.shape == "box":
            visual = pybullet.createVisualShape(
                pybullet.GEOM_BOX, rgbaColor=[*color, 1.0], physicsClientId=self.client,
                halfExtents=[object_class.length / 2, object_class.width / 2,
                             object_class.height / 2])
        else:
            visual = pybullet.createVisualShape(
                pybullet.GEOM_CYLINDER, radius=object_class.length / 2,
                length=object_class.height, rgbaColor=[*color, 1.0], physicsClientId=self.client)
        self.bodies[name] = pybullet.createMultiBody(0.0, -1, visual, basePosition=[0, 0, -5],
                                                     physicsClientId=self.client)
        self.heights[name] = object_class.height

    def place(self, name: str, pose: Pose2D) -> None:
        pybullet.resetBasePositionAndOrientation(
            self.bodies[name], [pose.x, pose.y, self.table_height + self.heights[name] / 2],
            pybullet.getQuaternionFromEuler([0.0, 0.0, pose.theta]), physicsClientId=self.client)

    def remove(self, name: str) -> None:
        pybullet.removeBody(self.bodies.pop(name), physicsClientId=self.client)
        del self.heights[name]

    def render(self) -> RenderedFrame:
        camera = self.camera
        _, _, rgba, depth_buffer, _ = pybullet.getCameraImage(
            camera.width, camera.height, self.view_matrix, self.projection_matrix,
            renderer=pybullet.ER_TINY_RENDERER, physicsClientId=self.client)
        rgba = np.reshape(np.asarray(rgba, dtype=np.uint8), (camera.height, camera.width, 4))
        buffer = np.reshape(np.asarray(depth_buffer, dtype=np.float32),
                            (camera.height, camera.width))
        depth = camera.far * camera.near / (camera.far - (camera.far - camera.near) * buffer)
        return RenderedFrame(np.ascontiguousarray(rgba[:, :, :3]), depth.astype(np.float32))


def random_color(rng: np.random.Generator) -> tuple[float, float, float]:
    return tuple(float(c) for c in rng.uniform(0.15, 0.95, size=3))


def principal_point_offset(renderer: TabletopRenderer, object_class: ObjectClass,
                           poses: list[Pose2D]) -> np.ndarray:
    """Mean (du, dv) in px between where renders put top-face centroids and where K says.

    Checks the renderer against OverheadCamera.intrinsics with flat boxes at known poses: the
    centroid of a top face parallel to the image plane is the projection of its centre.
    """
    renderer.add("_probe", object_class, (0.9, 0.1, 0.1))
    offsets = []
    top_depth = renderer.camera.position[2] - renderer.table_height - object_class.height
    for pose in poses:
        renderer.place("_probe", pose)
        frame = renderer.render()
        rows, cols = np.nonzero(np.abs(frame.depth - top_depth) < 2e-4)
        expected = renderer.camera.project_world_points(
            np.array([[pose.x, pose.y, renderer.table_height + object_class.height]]))[0]
        offsets.append([cols.mean() - expected[0], rows.mean() - expected[1]])
    renderer.remove("_probe")
    return np.mean(offsets, axis=0)

