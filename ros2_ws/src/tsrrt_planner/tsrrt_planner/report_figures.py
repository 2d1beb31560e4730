"""Pictures of a run, free of ROS: the paper's Fig. 1/6/7 outlines, Fig. 3 model bars, the cost.

Outlines are drawn on the overhead camera image through the same camera model the simulator
renders with, so a drawn outline sits on the object it describes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
from matplotlib.figure import Figure  # the object API draws to files with no display or pyplot

from tsrrt_common.camera import OverheadCamera
from tsrrt_common.geometry import Pose2D, footprint_polygon
from tsrrt_common.scenario import ObjectSpec
from tsrrt_planner.model_learning import DisplacementStats, ModelStore

COMPONENT_LABELS = ("dx (mm)", "dy (mm)", "dθ (deg)")
COMPONENT_SCALE = np.array([1000.0, 1000.0, 180.0 / np.pi])


def draw_visited_outlines(image_rgb: np.ndarray, camera: OverheadCamera,
                          specs: Sequence[ObjectSpec],
                          visited: Sequence[Mapping[str, Pose2D]],
                          table_height: float) -> np.ndarray:
    """The image (H, W, 3) with every object's outline at every visited state, older fainter."""
    canvas = image_rgb.copy()
    count = len(visited)
    for k, poses in enumerate(visited):
        strength = 0.3 + 0.7 * (k + 1) / max(count, 1)
        for spec in specs:
            if spec.id not in poses:
                continue
            outline = footprint_polygon(spec.shape, spec.length, spec.width, poses[spec.id])
            points = np.column_stack([outline, np.full(len(outline), table_height + spec.height)])
            pixels = camera.project_world_points(points)
            colour = tuple(int(255 * c * strength) for c in spec.color)
            cv2.polylines(canvas, [np.round(pixels).astype(np.int32)], True, colour,
                          2 if k == count - 1 else 1, cv2.LINE_AA)
    return canvas


def save_rgb(path: Path, image_rgb: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR))


def plot_models(store: ModelStore, object_ids: Sequence[str], path: Path,
                confidence: float = 0.95) -> None:
    """Fig. 3: mean displacement of each primitive with its confidence interval, per object."""
    figure = Figure(figsize=(11, 2.4 * len(object_ids)))
    axes = figure.subplots(len(object_ids), 3, squeeze=False)
    for row, object_id in enumerate(object_ids):
        primitives = sorted(p for (o, p) in store.models if o == object_id)
        means, half_widths = [], []
        for primitive in primitives:
            model = store.get(object_id, primitive)
            statistics = DisplacementStats(model.count, model.mean.copy(), model.m2.copy())
            means.append(model.mean * COMPONENT_SCALE)
            half = statistics.mean_half_width(confidence)
            half_widths.append(np.where(np.isfinite(half), half, 0.0) * COMPONENT_SCALE)
        for column in range(3):
            axis = axes[row, column]
            values = [m[column] for m in means]
            errors = [h[column] for h in half_widths]
            axis.bar([str(p) for p in primitives], values, yerr=errors, capsize=3,
                     color="#4a78b5")
            axis.axhline(0.0, color="black", linewidth=0.6)
            axis.set_title(f"{object_id}: {COMPONENT_LABELS[column]}", fontsize=9)
            axis.tick_params(labelsize=8)
    figure.suptitle(f"Learned push models: mean and {confidence:.0%} confidence interval "
                    "per primitive (paper Fig. 3)", fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def plot_cost(costs: Sequence[float], lower_bound: float, path: Path,
              predicted: float | None = None) -> None:
    """Observed objective after every push, with the lower bound and the plan's prediction."""
    figure = Figure(figsize=(6, 3.4))
    axis = figure.subplots()
    axis.plot(range(len(costs)), costs, marker="o", markersize=3, label="observed cost")
    axis.axhline(lower_bound, color="green", linestyle="--", label="lower bound")
    if predicted is not None:
        axis.axhline(predicted, color="orange", linestyle=":", label="last plan's prediction")
    axis.set_xlabel("pushes executed (after learning)")
    axis.set_ylabel("objective (Eq. 6)")
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
