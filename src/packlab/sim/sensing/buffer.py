"""Perceiving the buffer: image the shown boxes where they lie, segment, estimate, re-scan.

The robot's side of this module sees only the depth image, the camera's parameters and how many
boxes the buffer holds (a conveyor's or tote's count): it segments the image, fits a box to each
segment and checks the result. Where a segment is not box-like (its pixels fill too little of
its fitted rectangle: two boxes merged into an L, a box cut in two) or the count of segments is
not the count of boxes, it looks again after the boxes were moved (a new random layout, as a
tote shaken or a conveyor advanced), up to ``MAX_SCANS`` scans, and keeps the box-like
segments of the last one.

The simulator's side, ``_assign``, then decides which true box each kept segment stands for:
the box under the segment's centre, where a gripper aimed at that segment would pick. A box no
kept segment lies on, or more than one does, is *missed*: the episode sets it aside and counts
it (a robot cell would pass it to a person). Ground truth is used only there and for the error
statistics, never by the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from packlab.core.choices import Segmentation
from packlab.sim.sensing.camera import (
    CARTON_BEVEL_MM,
    BufferScene,
    DepthImage,
    add_sensor_noise,
    buffer_camera,
    layout_buffer,
)
from packlab.sim.sensing.perception import (
    EstimatedBox,
    estimate_objects,
    segment_depth,
    segment_truth,
)
from packlab.sim.sensing.presets import SensorPreset

#: Looks at the buffer before an object that was not found is given up: the first scan and
#: one re-scan after the boxes moved (a second re-scan found almost nothing the first had not).
MAX_SCANS = 2
#: A segment is box-like when its pixels cover at least this share of its fitted rectangle.
#: A lone box covers 0.95-1.0 of it (a few edge pixels lost or blurred); two boxes merged
#: side by side at different offsets, or a corner cut off, cover markedly less.
MIN_FILL = 0.85


@dataclass(frozen=True, slots=True)
class BufferPerception:
    """The last scan of the buffer and what was recovered from it."""

    scene: BufferScene  # the true layout of that scan (figures, statistics)
    image: DepthImage  # its noisy depth image
    labels: np.ndarray  # (nx, ny) int32 segmentation, -1 none
    found: tuple[EstimatedBox, ...]  # every box-like segment's estimate (what the robot has)
    estimates: tuple[EstimatedBox | None, ...]  # per shown object: the segment it is picked by
    scans: int  # how many scans it took (1: no re-scan)


def perceive_buffer(
    shown: np.ndarray,
    preset: SensorPreset,
    rng: np.random.Generator,
    segmentation: Segmentation,
    grid: tuple[int, int],
    arrangement: str = "touching",
) -> BufferPerception:
    """Scan the ``shown`` boxes (k, 3) until every one is found box-like, or ``MAX_SCANS``."""
    k = len(shown)
    for scans, scan_rng in enumerate(rng.spawn(MAX_SCANS), start=1):
        layout_rng, noise_rng = scan_rng.spawn(2)
        scene = layout_buffer(shown, layout_rng, arrangement)
        image = add_sensor_noise(buffer_camera(shown, scene, preset), preset, noise_rng)
        labels = _segment(image, preset, segmentation)
        everything = estimate_objects(image, labels, *grid)
        pixels = np.bincount(labels.ravel() + 1)[1:]  # per label
        found = tuple(e for e in everything if is_box_like(e, pixels[e.label], image.pixel_mm))
        if len(found) == len(everything) == k:
            break
    if segmentation == "truth":  # the ablation: the true masks say which box is which
        by_label = {e.label: e for e in found}
        estimates = tuple(by_label.get(i) for i in range(k))
    else:
        estimates = _assign(found, scene, shown)
    return BufferPerception(scene, image, labels, found, estimates, scans)


def _segment(image: DepthImage, preset: SensorPreset, segmentation: Segmentation) -> np.ndarray:
    if segmentation == "truth":
        return segment_truth(image)
    return segment_buffer(image, preset)


def segment_buffer(image: DepthImage, preset: SensorPreset) -> np.ndarray:
    """Labels (nx, ny) int32 of the boxes in a buffer image, from depth alone."""
    # Foreground 5 sigma over the table. Cuts must stand out of the noise left after a
    # 1-pixel Gaussian (about 0.3 sigma per pixel, its closing up to 3 times that, its slope
    # about 0.2 sigma per pixel). The window spans the groove of two bevels and a pixel more.
    noise = preset.depth_noise_mm
    window = 2 * math.ceil(CARTON_BEVEL_MM / image.pixel_mm) + 3
    return segment_depth(
        image,
        min_height_mm=max(10.0, 5 * noise),
        groove_mm=max(1.5, 1.2 * noise),
        step_mm=max(2.0, 1.0 * noise),
        window_px=window,
        grow_mm=CARTON_BEVEL_MM + 3 * noise + 1.0,
    )


def is_box_like(estimate: EstimatedBox, pixels: int, pixel_mm: float) -> bool:
    """True when the segment's ``pixels`` fill ``MIN_FILL`` of its fitted rectangle."""
    long_mm, short_mm, _ = estimate.raw_size_mm
    return pixels * pixel_mm**2 >= MIN_FILL * long_mm * short_mm


def _assign(
    found: tuple[EstimatedBox, ...], scene: BufferScene, shown: np.ndarray
) -> tuple[EstimatedBox | None, ...]:
    """Per shown object the one segment whose centre lies on it (simulator side), else None."""
    k = len(shown)
    hits: list[list[EstimatedBox]] = [[] for _ in range(k)]
    cos, sin = np.cos(scene.yaws_rad), np.sin(scene.yaws_rad)
    for estimate in found:
        dx = estimate.top_centre_mm[0] - scene.positions_mm[:, 0]
        dy = estimate.top_centre_mm[1] - scene.positions_mm[:, 1]
        u, v = cos * dx + sin * dy, -sin * dx + cos * dy  # in each box's own frame
        inside = (np.abs(u) <= shown[:, 0] / 2) & (np.abs(v) <= shown[:, 1] / 2)
        for i in np.flatnonzero(inside):
            hits[i].append(estimate)
    return tuple(h[0] if len(h) == 1 else None for h in hits)


__all__ = [
    "MAX_SCANS",
    "MIN_FILL",
    "BufferPerception",
    "is_box_like",
    "perceive_buffer",
    "segment_buffer",
]
