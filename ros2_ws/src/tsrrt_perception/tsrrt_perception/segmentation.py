"""Threshold segmentation of the overhead image into object footprints (paper Sec. III-D).

The paper's robot found closed contours in a mask image, fitted a bounding box aligned with each
object's long axis, took position and orientation from the box's centroid and angle, and the
class from its size and aspect ratio. Here the mask comes from depth: only flat *top faces* above
the table are kept, because in perspective the side faces of an object away from the image centre
are visible too and shift a colour mask's centroid by millimetres. Each top face lies in a plane
parallel to the table, so it is mapped to the table through the intrinsics at its own measured
height. Centroid and long axis come from the face's second moments, which average over every
boundary pixel and so resolve a fraction of a pixel; the box's extent from the same moments. The
class is the one whose footprint and height the face matches: a footprint alone let the flat top
of an arm link, or a platter's corner left round by the arm, pass for a plate.

Objects that touch are separated by their height (different top levels), by colour steps between
top faces at the same level, and otherwise by eroding the merged face until it falls apart.
A face that borders something much higher (the arm) and does not match its class's footprint is
flagged as occluded: its pose is not to be trusted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from tsrrt_common.geometry import Pose2D
from tsrrt_common.object_classes import ObjectClass
from tsrrt_perception.camera_view import CameraView

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
_SQUARE = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class SegmentationParams:
    """Thresholds of the segmentation; defaults suit the simulated overhead camera."""

    depth_threshold: float = 0.005        # m above the table for a pixel to belong to an object
    flat_tolerance: float = 0.0015        # m of height range in a 3x3 patch on a flat top face
    top_face_tolerance: float = 0.001     # m between a pixel and its face's level
    # m between a face's level and its class's height: a platter's corner left round by the
    # arm, or the arm's own flat link tops, fit a plate's footprint but not its height
    height_tolerance: float = 0.003
    min_area_px: int = 150                # smaller faces are noise
    occluder_margin: float = 0.01         # m above a face that counts as something covering it
    colour_edge_threshold: int = 6        # colour step (0-255) between touching faces; 0 = off
    pose_tolerance: float = 0.003         # m of footprint mismatch tolerated next to an occluder
    area_tolerance: float = 0.02          # relative area mismatch tolerated next to an occluder
    disc_fill_max: float = 0.9            # area / bounding rectangle below which a face is a disc
    max_split_erosions: int = 12          # px of erosion tried to separate touching faces


@dataclass(frozen=True)
class Detection:
    """One top face found in a frame, in the table frame."""

    pose: Pose2D
    object_class: str | None      # None: the footprint matches no class (reported as unknown)
    shape: str                    # "box" or "cylinder"
    length: float                 # measured footprint, metres (diameter for a cylinder)
    width: float
    height: float                 # top face above the table, metres
    symmetry: int
    class_error: float            # largest footprint difference to the class, metres
    occluded: bool                # borders something higher and does not match its class
    truncated: bool               # touches the image border
    area_px: int

    @property
    def pose_valid(self) -> bool:
        """Whether the pose may be published: a known, whole, unobstructed footprint."""
        return self.object_class is not None and not self.occluded and not self.truncated


@dataclass(frozen=True, eq=False)
class HeightImage:
    """Heights above the table of every pixel of one frame, for occlusion and visibility checks."""

    heights: np.ndarray           # (height, width) float32, -inf where depth is invalid
    camera: CameraView
    table_height: float

    def footprint_pixels(self, footprint_world: np.ndarray, top_height: float) -> np.ndarray:
        """Pixel polygon (N, 2) of a world footprint (N, 2) lying at top_height above the table."""
        corners = np.column_stack([footprint_world,
                                   np.full(len(footprint_world), self.table_height + top_height)])
        return self.camera.world_to_pixels(corners)

    def visible_fraction(self, footprint_world: np.ndarray, top_height: float) -> float:
        """Share of the footprint's corners that project inside the image (1 px margin)."""
        pixels = self.footprint_pixels(footprint_world, top_height)
        inside = ((pixels[:, 0] >= 1) & (pixels[:, 0] <= self.camera.width - 2)
                  & (pixels[:, 1] >= 1) & (pixels[:, 1] <= self.camera.height - 2))
        return float(np.mean(inside))

    def covered_fraction(self, footprint_world: np.ndarray, top_height: float,
                         margin: float) -> float:
        """Share of the footprint's pixels where something stands more than margin above it."""
        heights = self._footprint_heights(footprint_world, top_height)
        if heights.size == 0:
            return 0.0
        return float(np.count_nonzero(heights > top_height + margin)) / heights.size

    def bare_fraction(self, footprint_world: np.ndarray, top_height: float,
                      below: float) -> float:
        """Share of the footprint's pixels that see the bare table (lower than `below`):
        an object whose footprint is bare has left, it is not merely missed by segmentation."""
        heights = self._footprint_heights(footprint_world, top_height)
        if heights.size == 0:
            return 0.0
        return float(np.count_nonzero((heights < below) & np.isfinite(heights))) / heights.size

    def _footprint_heights(self, footprint_world: np.ndarray, top_height: float) -> np.ndarray:
        """Heights of the pixels inside the footprint, from a mask of its bounding box only
        (a whole-frame mask per object and frame churned the heap of a long-running node)."""
        polygon = np.round(self.footprint_pixels(footprint_world, top_height)).astype(np.int32)
        rows, cols = self.heights.shape
        u0, v0 = np.clip(polygon.min(axis=0), 0, [cols, rows])
        u1, v1 = np.clip(polygon.max(axis=0) + 1, 0, [cols, rows])
        if u1 <= u0 or v1 <= v0:
            return self.heights[:0, 0]
        mask = np.zeros((v1 - v0, u1 - u0), np.uint8)
        cv2.fillPoly(mask, [polygon - np.array([u0, v0], np.int32)], 1)
        return self.heights[v0:v1, u0:u1][mask.astype(bool)]


def _colour_edges(rgb: np.ndarray, threshold: int) -> np.ndarray:
    """(H, W) bool: pixels whose colour differs from their right or lower neighbour."""
    def largest_channel_step(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        step = cv2.absdiff(a, b)
        return np.maximum(np.maximum(step[..., 0], step[..., 1]), step[..., 2]) > threshold

    edges = np.zeros(rgb.shape[:2], bool)
    edges[:, :-1] |= largest_channel_step(rgb[:, 1:], rgb[:, :-1])
    edges[:-1, :] |= largest_channel_step(rgb[1:, :], rgb[:-1, :])
    return edges


def _grow_labels(labels: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Grow labelled regions (int32) into allowed pixels until none is left to claim."""
    labels = labels.astype(np.float32)
    while True:
        grown = cv2.dilate(labels, _SQUARE)
        claim = allowed & (labels == 0) & (grown > 0)
        if not claim.any():
            return labels.astype(np.int32)
        labels[claim] = grown[claim]


class _Face:
    """A top-face mask in a region of interest and its measurements."""

    def __init__(self, mask: np.ndarray, origin: tuple[int, int], level: float) -> None:
        self.mask = mask                  # (h, w) uint8 in the region of interest
        self.origin = origin              # (u0, v0) of the region in the image
        self.level = level                # height above the table, metres
        self.area_px = int(np.count_nonzero(mask))


def _segment_faces(heights: np.ndarray, rgb: np.ndarray | None,
                   params: SegmentationParams) -> list[_Face]:
    """Split the image into flat top faces standing above the table."""
    finite = np.where(np.isfinite(heights), heights, np.float32(-1.0))
    above = finite > params.depth_threshold
    local_range = cv2.dilate(finite, _SQUARE) - cv2.erode(finite, _SQUARE)
    seeds = above & (local_range < params.flat_tolerance)
    if rgb is not None and params.colour_edge_threshold > 0:
        seeds &= ~_colour_edges(rgb, params.colour_edge_threshold)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(seeds.astype(np.uint8),
                                                               connectivity=4)
    faces = []
    rows, cols = heights.shape
    pad = 3
    for label in range(1, count):
        u0, v0, w, h, area = stats[label]
        if area < params.min_area_px // 4:
            continue
        u0, v0 = max(u0 - pad, 0), max(v0 - pad, 0)
        u1, v1 = min(u0 + w + 2 * pad, cols), min(v0 + h + 2 * pad, rows)
        roi_labels = labels[v0:v1, u0:u1]
        roi_heights = finite[v0:v1, u0:u1]
        own = roi_labels == label
        level = float(np.median(roi_heights[own]))
        allowed = ((np.abs(roi_heights - level) < params.top_face_tolerance)
                   & ((roi_labels == 0) | own))
        mask = _grow_labels(own.astype(np.int32), allowed).astype(np.uint8)
        if np.count_nonzero(mask) >= params.min_area_px:
            faces.append(_Face(mask, (u0, v0), level))
    return faces


def _split_touching(face: _Face, params: SegmentationParams) -> list[_Face]:
    """Erode a merged face until it falls into parts, then grow the parts back over it."""
    eroded = face.mask
    for _ in range(params.max_split_erosions):
        eroded = cv2.erode(eroded, _CROSS)
        count, labels, stats, _ = cv2.connectedComponentsWithStats(eroded, connectivity=4)
        big = [k for k in range(1, count) if stats[k, 4] >= params.min_area_px // 4]
        if len(big) >= 2:
            markers = np.where(np.isin(labels, big), labels, 0)
            grown = _grow_labels(markers, face.mask.astype(bool))
            return [_Face((grown == k).astype(np.uint8), face.origin, face.level) for k in big]
        if count <= 1:
            break
    return [face]


class FaceMeasurer:
    """Turns a top-face mask into a Detection: pose, footprint, class, occlusion flags."""

    def __init__(self, classes: dict[str, ObjectClass], camera: CameraView,
                 heights: np.ndarray, table_height: float, params: SegmentationParams) -> None:
        self.classes = classes
        self.camera = camera
        self.heights = heights
        self.table_height = table_height
        self.params = params

    def classify(self, shape: str, length: float, width: float,
                 height: float) -> tuple[ObjectClass | None, float]:
        """Closest class of this shape and height by footprint, and the footprint error (m)."""
        best, best_error = None, math.inf
        for cls in self.classes.values():
            if cls.shape != shape or abs(height - cls.height) > self.params.height_tolerance:
                continue
            error = max(abs(length - cls.length), abs(width - cls.width))
            if error < best_error:
                best, best_error = cls, error
        if best is None or best_error > best.tolerance:
            return None, best_error
        return best, best_error

    def measure(self, face: _Face) -> Detection:
        moments = cv2.moments(face.mask, binaryImage=True)
        m00 = moments["m00"]
        centre_px = np.array([moments["m10"] / m00 + face.origin[0],
                              moments["m01"] / m00 + face.origin[1]])
        covariance = np.array([[moments["mu20"], moments["mu11"]],
                               [moments["mu11"], moments["mu02"]]]) / m00
        eigenvalues, eigenvectors = np.linalg.eigh(covariance)       # ascending
        axis_px = eigenvectors[:, 1]
        plane_z = self.table_height + face.level
        probe = self.camera.pixels_to_plane(np.array([centre_px, centre_px + 10.0 * axis_px,
                                                      centre_px + 10.0 * eigenvectors[:, 0]]),
                                            plane_z)
        long_axis = probe[1, :2] - probe[0, :2]
        metres_per_px = float(np.linalg.norm(long_axis)) / 10.0
        area = face.area_px * metres_per_px ** 2

        # The shape is read from the face without one-pixel spurs: grown into the colour-edge
        # pixels along a neighbour it touches, a face can keep one there, and it inflated the
        # bounding rectangles of two touching platters until both read as discs (no class: a
        # tset6 demo failed with neither platter seen). A face thinner than the opening keeps
        # its own outline.
        opened = cv2.morphologyEx(face.mask, cv2.MORPH_OPEN, _SQUARE)
        contours, _ = cv2.findContours(opened if opened.any() else face.mask,
                                       cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        contour = max(contours, key=cv2.contourArea)
        (_, _), (rect_w, rect_h), rect_angle = cv2.minAreaRect(contour)
        fill = face.area_px / ((rect_w + 1.0) * (rect_h + 1.0))
        shape = "cylinder" if fill < self.params.disc_fill_max else "box"
        if shape == "cylinder":
            length = width = 2.0 * math.sqrt(area / math.pi)
            theta = 0.0
        else:
            length = math.sqrt(12.0 * eigenvalues[1]) * metres_per_px
            width = math.sqrt(12.0 * eigenvalues[0]) * metres_per_px
            if eigenvalues[1] < 1.1 ** 2 * eigenvalues[0]:
                # Near-square: moments do not define an axis, the rectangle's side does.
                side = np.array([math.cos(math.radians(rect_angle)),
                                 math.sin(math.radians(rect_angle))])
                ends = self.camera.pixels_to_plane(np.array([centre_px, centre_px + 10 * side]),
                                                   plane_z)
                long_axis = ends[1, :2] - ends[0, :2]
            theta = math.atan2(long_axis[1], long_axis[0])
        cls, class_error = self.classify(shape, length, width, face.level)

        u0, v0 = face.origin
        h, w = face.mask.shape
        rows, cols = self.heights.shape
        ys, xs = np.nonzero(face.mask)
        truncated = bool(
            (u0 == 0 and xs.min() == 0) or (v0 == 0 and ys.min() == 0)
            or (u0 + w == cols and xs.max() == w - 1) or (v0 + h == rows and ys.max() == h - 1))
        occluded = self._borders_occluder(face) and (
            cls is None or class_error > self.params.pose_tolerance
            or abs(area / (cls.length * cls.width * (math.pi / 4 if cls.shape == "cylinder"
                                                     else 1.0)) - 1.0)
            > self.params.area_tolerance)
        return Detection(
            pose=Pose2D(float(probe[0, 0]), float(probe[0, 1]), theta),
            object_class=cls.name if cls else None, shape=shape, length=length, width=width,
            height=face.level, symmetry=cls.symmetry if cls else (0 if shape == "cylinder" else 2),
            class_error=class_error, occluded=occluded, truncated=truncated,
            area_px=face.area_px)

    def _borders_occluder(self, face: _Face) -> bool:
        """Whether pixels just outside the face stand well above it (the arm, a taller object)."""
        u0, v0 = face.origin
        h, w = face.mask.shape
        ring = cv2.dilate(face.mask, _SQUARE, iterations=2).astype(bool) & ~face.mask.astype(bool)
        higher = self.heights[v0:v0 + h, u0:u0 + w] > face.level + self.params.occluder_margin
        return int(np.count_nonzero(ring & higher)) >= 3


@dataclass(frozen=True, eq=False)
class SegmentationResult:
    detections: list[Detection]
    height_image: HeightImage


def segment_objects(depth: np.ndarray, camera: CameraView, table_height: float,
                    classes: dict[str, ObjectClass], params: SegmentationParams | None = None,
                    rgb: np.ndarray | None = None) -> SegmentationResult:
    """Detect the objects standing on the table in one frame.

    Args:
        depth: (H, W) optical depth in metres.
        camera: intrinsics and pose of the camera that took the frame.
        table_height: world z of the table top.
        classes: the class table (tsrrt_common.object_classes.load_class_table()).
        params: thresholds; defaults when None.
        rgb: optional (H, W, 3) colour image of the same frame, used only to separate touching
            faces of equal height (never to classify).
    Returns:
        The detections (unknown footprints included, with object_class None) and the frame's
        heights for occlusion checks.
    """
    params = params or SegmentationParams()
    heights = camera.heights_above_plane(depth, table_height)
    measurer = FaceMeasurer(classes, camera, heights, table_height, params)
    detections = []
    for face in _segment_faces(heights, rgb, params):
        detection = measurer.measure(face)
        if detection.object_class is None and not detection.occluded and not detection.truncated:
            parts = _split_touching(face, params)
            if len(parts) > 1:
                measured = [measurer.measure(part) for part in parts]
                if all(part.object_class is not None for part in measured):
                    detections.extend(measured)
                    continue
        detections.append(detection)
    return SegmentationResult(detections, HeightImage(heights, camera, table_height))
