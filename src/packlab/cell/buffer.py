"""The boxes on the buffer from its top-down depth image: packlab's segmentation and box fit.

The robot's side of ``packlab.sim.sensing.buffer`` on one scan: segment the image from depth
alone (``segment_depth``), fit a box to each segment (``estimate_objects``) and keep the
box-like ones. The settings are the simulator's for the same sensor preset, so an image packlab
rendered gives the boxes its simulated robot finds: the segmentation and the box-like test are
the simulator's own functions (tests/cell/test_buffer.py checks the whole against
``perceive_buffer``). What the simulator adds, a re-scan after the boxes moved, is the cell's to
do: it sends a new image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.sim.sensing.buffer import is_box_like, segment_buffer
from packlab.sim.sensing.camera import DepthImage
from packlab.sim.sensing.perception import EstimatedBox, estimate_objects
from packlab.sim.sensing.presets import SensorPreset


@dataclass(frozen=True, slots=True)
class BufferBoxes:
    """The box-like segments of one buffer image, and every segment's label image."""

    labels: np.ndarray  # (nx, ny) int32 segment per pixel, -1 none
    boxes: tuple[EstimatedBox, ...]  # box-like segments, in label order
    dropped: int  # segments that were not box-like (merged boxes, a box cut in two)


def measure_boxes(image: DepthImage, preset: SensorPreset, grid: tuple[int, int]) -> BufferBoxes:
    """Segment ``image`` and fit a box to each segment; sizes snap to ``grid`` (xy, z) mm."""
    labels = segment_buffer(image, preset)
    everything = estimate_objects(image, labels, *grid)
    pixels = np.bincount(labels.ravel() + 1)[1:]  # per label
    boxes = tuple(e for e in everything if is_box_like(e, int(pixels[e.label]), image.pixel_mm))
    return BufferBoxes(labels, boxes, len(everything) - len(boxes))


__all__ = ["BufferBoxes", "measure_boxes"]
