"""Simulated sensing: top-down depth cameras over the container and the buffer, and perception.

``perceive_state`` is the one entry the episode loop calls in perceived mode: it images the
container (boxes at their settled poses) and the shown objects (laid out on a buffer table at
random positions and yaws), and returns the heightmap and the shown sizes a policy would see on
a robot, with the perception's errors. Modules: ``presets`` (noise models), ``camera`` (ray
casting, noise, buffer layout), ``perception`` (heightmap, segmentation, box estimation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.core.choices import Segmentation, require_choice
from packlab.core.types import Container
from packlab.sim.heightmap import rasterise_poses
from packlab.sim.sensing.camera import (
    BufferScene,
    DepthImage,
    add_sensor_noise,
    buffer_camera,
    buffer_views,
    container_camera,
    layout_buffer,
    render_depth,
)
from packlab.sim.sensing.perception import (
    EstimatedBox,
    estimate_objects,
    heightmap_from_depth,
    segment_depth,
    segment_truth,
)
from packlab.sim.sensing.presets import SENSOR_PRESETS, SensorPreset, sensor_preset


@dataclass(frozen=True, slots=True)
class PerceptionStats:
    """How far perception was from the truth at one step."""

    dims_error_mm: np.ndarray  # (k,) float64 max |estimated - true| over (l, w, h), snapped sizes
    raw_dims_error_mm: np.ndarray  # (k,) float64 the same before snapping to the grids
    yaw_error_deg: np.ndarray  # (k,) float64 |estimated - true| yaw of the long axis, degrees
    heightmap_mae_mm: float  # mean |perceived - exact| over the container's cells, mm
    missed: int  # shown objects no segment was found for (their true size is passed on)


@dataclass(frozen=True, slots=True)
class PerceivedState:
    """What a policy sees in perceived mode, and the intermediate data (for figures)."""

    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, perceived
    shown_sizes_mm: np.ndarray  # (k, 3) int64 estimated (l, w, h) in mm, shown order
    stats: PerceptionStats
    container_image: DepthImage  # noisy depth image over the container
    buffer_scene: BufferScene  # the true layout of the shown objects on the buffer table
    buffer_images: tuple[DepthImage, ...]  # noisy view of each shown object, shown order
    buffer_labels: tuple[np.ndarray, ...]  # (nx, ny) int32 segmentation of each view, -1 none
    estimates: tuple[EstimatedBox | None, ...]  # each shown object's estimate, None if missed


def perceive_state(
    container: Container,
    box_sizes_mm: np.ndarray,
    positions_mm: np.ndarray,
    quaternions: np.ndarray,
    shown_sizes_mm: np.ndarray,
    preset: SensorPreset | str,
    rng: np.random.Generator,
    segmentation: Segmentation = "truth",
) -> PerceivedState:
    """Perceive the container and the shown buffer through the preset's cameras.

    ``box_sizes_mm`` (n, 3), ``positions_mm`` (n, 3) and ``quaternions`` (n, 4, w x y z) are the
    case's boxes and their poses as ``backend.poses()`` returns them (NaN rows: not placed,
    ignored). ``shown_sizes_mm`` (k, 3) are the shown objects' true (l, w, h). Noise and the
    buffer layout are drawn from ``rng``. With a noise-free preset the heightmap equals the
    rasterised one and the sizes are exact.
    """
    require_choice(segmentation, Segmentation, "segmentation")
    preset = sensor_preset(preset)
    sizes = np.asarray(box_sizes_mm, dtype=np.float64).reshape(-1, 3)
    positions = np.asarray(positions_mm, dtype=np.float64).reshape(-1, 3)
    quats = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
    # Independent streams: the buffer layout does not depend on how much noise was drawn.
    layout_rng, container_rng, buffer_rng = rng.spawn(3)
    clean = container_camera(container, sizes, positions, quats, preset)
    container_image = add_sensor_noise(clean, preset, container_rng)
    heightmap = heightmap_from_depth(
        container_image, container, flat_tolerance_mm=preset.flat_tolerance_mm
    )
    placed = np.all(np.isfinite(positions), axis=1)
    exact = rasterise_poses(
        container.cells, container.cell_xy_mm, sizes[placed], positions[placed], quats[placed]
    )
    shown = np.asarray(shown_sizes_mm, dtype=np.int64).reshape(-1, 3)
    scene = layout_buffer(shown, layout_rng)
    grid = (container.cell_xy_mm, container.cell_z_mm)
    images, labels, estimates = _perceive_buffer(
        shown, scene, preset, buffer_rng, segmentation, grid
    )
    sizes_out, errors = _shown_sizes_and_stats(shown, scene, estimates)
    hm_error = float(np.mean(np.abs(heightmap.astype(np.int64) - exact))) if exact.size else 0.0
    missed = sum(e is None for e in estimates)
    stats = PerceptionStats(*errors, heightmap_mae_mm=hm_error, missed=missed)
    return PerceivedState(
        heightmap, sizes_out, stats, container_image, scene, images, labels, estimates
    )


def _perceive_buffer(shown, scene, preset, rng, segmentation, grid):
    """(noisy views, their labels, each object's estimate or None), one per shown object."""
    images, all_labels, estimates = [], [], []
    view_rngs = rng.spawn(len(shown))
    for index, view in enumerate(buffer_views(shown, scene, preset)):
        image = add_sensor_noise(view, preset, view_rngs[index])
        if segmentation == "truth":
            labels = segment_truth(image)
        else:  # foreground 5 sigma over the table: noise alone almost never crosses it
            labels = segment_depth(image, min_height_mm=max(10.0, 5 * preset.depth_noise_mm))
        found = estimate_objects(image, labels, *grid)
        estimates.append(_pick(found, index, scene.views_mm[index], segmentation == "truth"))
        images.append(image)
        all_labels.append(labels)
    return tuple(images), tuple(all_labels), tuple(estimates)


def _pick(found: list[EstimatedBox], index: int, view_mm: np.ndarray, by_label: bool):
    """The estimate of the view's own object: its ground-truth label, else the segment nearest
    the view's centre (a view holds one box; stray segments are noise). None when none."""
    if by_label:
        return next((e for e in found if e.label == index), None)
    if not found:
        return None
    centre = (view_mm[:2] + view_mm[2:]) / 2.0
    return min(found, key=lambda e: float(np.hypot(*(np.asarray(e.top_centre_mm[:2]) - centre))))


def _shown_sizes_and_stats(shown, scene, estimates):
    """Estimated sizes in the catalogue's l/w order, and the (dims, raw dims, yaw) errors.

    Which side of a box a catalogue calls l is a label, not something a camera can see, so the
    estimated (long, short) pair is written in the order the catalogue uses for that object
    (longer first when its l >= w). A noise-free preset then reproduces the exact observation.
    """
    k = len(shown)
    sizes = shown.copy()
    dims, raw_dims, yaw = np.zeros(k), np.zeros(k), np.zeros(k)
    for i in range(k):
        est = estimates[i]
        if est is None:  # missed: the true size is passed on, and counted in ``missed``
            continue
        flip = shown[i, 0] < shown[i, 1]
        order = [1, 0, 2] if flip else [0, 1, 2]
        sizes[i] = np.asarray(est.size_mm)[order]
        dims[i] = np.max(np.abs(sizes[i] - shown[i]))
        raw_dims[i] = np.max(np.abs(np.asarray(est.raw_size_mm)[order] - shown[i]))
        true_yaw = np.degrees(scene.yaws_rad[i]) + (90.0 if flip else 0.0)
        period = 90.0 if shown[i, 0] == shown[i, 1] else 180.0
        diff = (est.yaw_deg - true_yaw) % period
        yaw[i] = min(diff, period - diff)
    return sizes, (dims, raw_dims, yaw)


__all__ = [
    "SENSOR_PRESETS",
    "BufferScene",
    "DepthImage",
    "EstimatedBox",
    "PerceivedState",
    "PerceptionStats",
    "SensorPreset",
    "add_sensor_noise",
    "buffer_camera",
    "buffer_views",
    "container_camera",
    "estimate_objects",
    "heightmap_from_depth",
    "layout_buffer",
    "perceive_state",
    "render_depth",
    "segment_depth",
    "segment_truth",
    "sensor_preset",
]
