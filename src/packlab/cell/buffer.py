"""The boxes on the buffer from its top-down depth image: packlab's segmentation and box fit.

The robot's side of ``packlab.sim.sensing.buffer`` on one scan: segment the image from depth
alone (``segment_depth``), fit a box to each segment (``estimate_objects``) and keep the
box-like ones. The settings are the simulator's for the same sensor preset, so an image packlab
rendered gives the boxes its simulated robot finds (tests/cell/test_buffer.py checks it against
``perceive_buffer``). What the simulator adds, a re-scan after the boxes moved, is the cell's to
do: it sends a new image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from packlab.sim.sensing.buffer import MIN_FILL
from packlab.sim.sensing.camera import CARTON_BEVEL_MM, DepthImage
from packlab.sim.sensing.perception import EstimatedBox, estimate_objects, segment_depth
from packlab.sim.sensing.presets import SensorPreset


@dataclass(frozen=True, slots=True)
class BufferBoxes:
    """The box-like segments of one buffer image, and every segment's label image."""

    labels: np.ndarray  # (nx, ny) int32 segment per pixel, -1 none
    boxes: tuple[EstimatedBox, ...]  # box-like segments, in label order
    dropped: int  # segments that were not box-like (merged boxes, a box cut in two)


def segment_buffer(image: DepthImage, preset: SensorPreset) -> np.ndarray:
    """Labels (nx, ny) int32 of the boxes in a buffer image, from depth alone.

    The thresholds scale with the sensor's noise as the simulated robot's do: foreground 5 sigma
    over the table; cuts that stand out of the noise left after a 1-pixel Gaussian; a window that
    spans the groove between two touching cartons' rounded edges and a pixel more.
    """
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


def measure_boxes(image: DepthImage, preset: SensorPreset, grid: tuple[int, int]) -> BufferBoxes:
    """Segment ``image`` and fit a box to each segment; sizes snap to ``grid`` (xy, z) mm."""
    labels = segment_buffer(image, preset)
    everything = estimate_objects(image, labels, *grid)
    pixels = np.bincount(labels.ravel() + 1)[1:]  # per label
    boxes = tuple(e for e in everything if is_box_like(e, int(pixels[e.label]), image.pixel_mm))
    return BufferBoxes(labels, boxes, len(everything) - len(boxes))


__all__ = ["BufferBoxes", "is_box_like", "measure_boxes", "segment_buffer"]
