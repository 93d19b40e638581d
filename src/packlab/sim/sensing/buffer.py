"""Perceiving the buffer: image the shown boxes where they lie, segment, estimate, re-scan.

The robot's side of this module sees only the depth image, the camera's parameters and how many
boxes the buffer holds (a conveyor's or tote's count): it segments the image, fits a box to each
segment and checks the result. Where a segment is not box-like (its pixels fill too little of
its fitted rectangle: two boxes merged into an L, a box cut in two) or the count of segments is
not the count of boxes, it looks again after the boxes were moved (a new random layout, as a
tote shaken or a conveyor advanced), up to ``MAX_SCANS`` scans, and keeps the box-like
segments of the last one.

The robot lists the box-like segments of the last scan in the order of their labels, the
order in which the segmentation numbers them in the image (what ``packlab cell serve`` lists
for the same image). A gripper aimed at a listed segment takes the box physically under it:
the simulator's side, ``_picks``, reads the true id of the segment's pixel nearest the centre
the robot estimated. So a box the segmentation cut into two box-like pieces is listed twice
(either pick takes the whole box), and of two boxes merged into one box-like segment only the
one under its centre is listed. A segment lying on no box at all (sensor noise over the
table) is left out: a cell's pick there finds nothing. The segments that are not box-like are
the ones a robot clears when it cannot identify the buffer (``BufferPerception.blobs``: the
box under each one's centre, taken the same way). Ground truth is used only for what a pick
physically takes and for the error statistics, never by the estimate or the list.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

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
    found: tuple[EstimatedBox, ...]  # every box-like segment's estimate, in label order
    #: Per ``found`` segment, the scene row of the box a gripper aimed at it takes (the
    #: simulator's side); -1: no box lies under the segment.
    picks: tuple[int, ...]
    #: Per segment that was not box-like, the scene row of the box under its centre (-1: none):
    #: what a robot clearing the segments it could not identify takes off the buffer.
    blobs: tuple[int, ...]
    #: The robot's own check: as many box-like segments as the buffer holds, and no other.
    clean: bool
    scans: int  # how many scans it took (1: no re-scan)

    @property
    def listed(self) -> tuple[int, ...]:
        """Positions in ``found`` of the segments the robot is shown to pick from: every
        box-like segment that lies on a box, in label order."""
        return tuple(i for i, row in enumerate(self.picks) if row >= 0)

    @property
    def unpicked(self) -> tuple[int, ...]:
        """Scene rows of the boxes no listed segment takes (the simulator's count of boxes the
        robot did not identify at this look)."""
        taken = set(self.picks)
        return tuple(i for i in range(len(self.scene.positions_mm)) if i not in taken)


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
    blobs = tuple(e for e in everything if all(e is not f for f in found))
    picks = _picks(image, labels, found)
    clean = len(found) == len(everything) == k
    return BufferPerception(
        scene, image, labels, found, picks, _picks(image, labels, blobs), clean, scans
    )


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


def _picks(
    image: DepthImage, labels: np.ndarray, segments: tuple[EstimatedBox, ...]
) -> tuple[int, ...]:
    """Per segment, the scene row of the box a gripper aimed at its estimated centre takes (the
    simulator's side): the true id at the segment's pixel nearest that centre, of its pixels
    that lie on a box; -1 where none does."""
    if not segments:
        return ()
    nx, ny = image.shape
    x_axis = image.origin_mm[0] + (np.arange(nx) + 0.5) * image.pixel_mm
    y_axis = image.origin_mm[1] + (np.arange(ny) + 0.5) * image.pixel_mm
    windows = ndimage.find_objects(np.maximum(labels + 1, 0))
    out = []
    for segment in segments:
        window = windows[segment.label]
        on_box = (labels[window] == segment.label) & (image.ids[window] >= 0)
        if not on_box.any():
            out.append(-1)
            continue
        cx, cy = segment.top_centre_mm[:2]
        dx2 = (x_axis[window[0]] - cx) ** 2
        dy2 = (y_axis[window[1]] - cy) ** 2
        distance = np.where(on_box, dx2[:, None] + dy2[None, :], np.inf)
        out.append(int(image.ids[window][np.unravel_index(np.argmin(distance), on_box.shape)]))
    return tuple(out)


__all__ = [
    "MAX_SCANS",
    "MIN_FILL",
    "BufferPerception",
    "is_box_like",
    "perceive_buffer",
    "segment_buffer",
]
