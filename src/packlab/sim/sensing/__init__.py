"""Simulated sensing: top-down depth cameras over the container and the buffer, and perception.

``perceive_state`` is the one entry the episode loop calls in perceived mode: it images the
container (boxes at their settled poses) and the shown objects (lying together in a tote), and
returns the heightmap and the shown sizes a policy would see on a robot, which objects were not
found, and the perception's errors. Modules: ``presets`` (noise models), ``camera`` (ray
casting, noise, buffer layouts), ``perception`` (heightmap, segmentation, box estimation),
``buffer`` (scan, check, re-scan, and which segment is which box).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.core.choices import DEFAULT_SIZE_PRIOR, Segmentation, SizePrior, require_choice
from packlab.core.types import Container
from packlab.sim.heightmap import rasterise_poses
from packlab.sim.sensing.buffer import BufferPerception, perceive_buffer
from packlab.sim.sensing.camera import (
    BufferScene,
    DepthImage,
    add_sensor_noise,
    buffer_camera,
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
    size_quanta,
)
from packlab.sim.sensing.presets import SENSOR_PRESETS, SensorPreset, sensor_preset


@dataclass(frozen=True, slots=True)
class PerceptionStats:
    """How far perception was from the truth at one step (NaN for a missed object)."""

    #: Per listed box (``PerceivedState.picks``), against the box a pick at it takes:
    dims_error_mm: np.ndarray  # (m,) float64 max |estimated - true| over (l, w, h), snapped sizes
    raw_dims_error_mm: np.ndarray  # (m,) float64 the same before snapping to the grids
    yaw_error_deg: np.ndarray  # (m,) float64 |estimated - true| yaw of the long axis, degrees
    heightmap_mae_mm: float  # mean |perceived - exact| over the container's cells, mm
    missed: int  # buffered boxes no listed segment takes (left in the buffer, unidentified)
    scans: int = 1  # looks at the buffer this step took (2: one re-scan)


@dataclass(frozen=True, slots=True)
class PerceivedState:
    """What a policy sees in perceived mode, and the intermediate data (for figures)."""

    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, perceived
    #: (m, 3) int64 estimated (long side, short side, height) mm per listed box: the buffer's
    #: box-like segments in label order (``BufferPerception.listed``). Longer side first: which
    #: side a catalogue calls l is a label no camera can see.
    shown_sizes_mm: np.ndarray
    stats: PerceptionStats
    container_image: DepthImage  # noisy depth image over the container
    buffer: BufferPerception  # the last scan of the buffer and its segments
    #: Simulator bookkeeping per listed box: the buffered box (its row in the ``shown`` sizes) a
    #: pick at it takes; two entries are the same box where a box was cut in two pieces.
    picks: tuple[int, ...]
    #: Simulator bookkeeping per listed box: the estimated long axis is the true box's w axis
    #: (so the episode turns the box by the other rotation to do what the policy chose).
    axis_swapped: np.ndarray  # (m,) bool
    #: Per listed box (dx mm, dy mm, dyaw deg), estimated minus true pose on the buffer.
    grasp_errors: np.ndarray  # (m, 3) float64

    @property
    def missed(self) -> tuple[int, ...]:
        """Rows of the buffered boxes no listed segment takes (not identified at this look)."""
        return self.buffer.unpicked


def perceive_state(
    container: Container,
    box_sizes_mm: np.ndarray,
    positions_mm: np.ndarray,
    quaternions: np.ndarray,
    shown_sizes_mm: np.ndarray,
    preset: SensorPreset | str,
    rng: np.random.Generator,
    segmentation: Segmentation = "depth",
    arrangement: str = "touching",
    size_prior: SizePrior = DEFAULT_SIZE_PRIOR,
) -> PerceivedState:
    """Perceive the container and the shown buffer through the preset's cameras.

    ``box_sizes_mm`` (n, 3), ``positions_mm`` (n, 3) and ``quaternions`` (n, 4, w x y z) are the
    case's boxes and their poses as ``backend.poses()`` returns them (NaN rows: not placed,
    ignored). ``shown_sizes_mm`` (k, 3) are the shown objects' true (l, w, h): they place the
    boxes in the buffer scene and score the estimates, nothing else. Noise and the buffer layout
    are drawn from ``rng``. With a noise-free preset the heightmap equals the rasterised one and
    the sizes are exact (longer side first). ``size_prior`` (``perception.SizePrior``): the
    shown sizes snap to the container's grids (``grid``) or are the raw estimates in whole mm
    (``none``).
    """
    require_choice(segmentation, Segmentation, "segmentation")
    preset = sensor_preset(preset)
    sizes = np.asarray(box_sizes_mm, dtype=np.float64).reshape(-1, 3)
    positions = np.asarray(positions_mm, dtype=np.float64).reshape(-1, 3)
    quats = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
    # Independent streams: the buffer layout does not depend on how much noise was drawn.
    buffer_rng, container_rng = rng.spawn(2)
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
    grid = size_quanta(size_prior, container.cell_xy_mm, container.cell_z_mm)
    buffer = perceive_buffer(shown, preset, buffer_rng, segmentation, grid, arrangement)
    sizes_out, swapped, grasp, errors = _compare_to_truth(shown, buffer)
    hm_error = float(np.mean(np.abs(heightmap.astype(np.int64) - exact))) if exact.size else 0.0
    missed = len(buffer.unpicked)
    stats = PerceptionStats(*errors, heightmap_mae_mm=hm_error, missed=missed, scans=buffer.scans)
    picks = tuple(buffer.picks[i] for i in buffer.listed)
    return PerceivedState(
        heightmap, sizes_out, stats, container_image, buffer, picks, swapped, grasp
    )


def _wrap(angle_deg: float, period: float) -> float:
    """``angle_deg`` wrapped into [-period / 2, period / 2)."""
    return (angle_deg + period / 2) % period - period / 2


def _compare_to_truth(
    shown: np.ndarray, buffer: BufferPerception
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(sizes, axis_swapped, grasp errors, (dims, raw dims, yaw errors)) per listed box, each
    compared with the buffered box a pick at it takes.

    The sizes are the estimates as measured (longer side first). Which true axis the estimated
    long axis is, and the errors, are the simulator's: the long axis is the true l axis when the
    two lie within 45 degrees, else the true w axis (a square box: always its l axis, yaws
    compared modulo 90 degrees).
    """
    listed = buffer.listed
    m = len(listed)
    sizes = np.zeros((m, 3), dtype=np.int64)
    swapped = np.zeros(m, dtype=bool)
    grasp = np.zeros((m, 3))
    dims, raw_dims, yaw = np.full(m, np.nan), np.full(m, np.nan), np.full(m, np.nan)
    for j, segment in enumerate(listed):
        est, i = buffer.found[segment], buffer.picks[segment]
        sizes[j] = est.size_mm
        true_yaw = float(np.degrees(buffer.scene.yaws_rad[i]))
        square = shown[i, 0] == shown[i, 1]
        swapped[j] = not square and abs(_wrap(est.yaw_deg - true_yaw, 180.0)) > 45.0
        axis_yaw = true_yaw + (90.0 if swapped[j] else 0.0)
        dyaw = _wrap(est.yaw_deg - axis_yaw, 90.0 if square else 180.0)
        truth = shown[i][[1, 0, 2]] if swapped[j] else shown[i]
        dims[j] = np.max(np.abs(sizes[j] - truth))
        raw_dims[j] = np.max(np.abs(np.asarray(est.raw_size_mm) - truth))
        yaw[j] = abs(dyaw)
        centre = buffer.scene.positions_mm[i, :2]
        grasp[j] = (est.top_centre_mm[0] - centre[0], est.top_centre_mm[1] - centre[1], dyaw)
    return sizes, swapped, grasp, (dims, raw_dims, yaw)


__all__ = [
    "SENSOR_PRESETS",
    "BufferPerception",
    "BufferScene",
    "DepthImage",
    "EstimatedBox",
    "PerceivedState",
    "PerceptionStats",
    "SensorPreset",
    "add_sensor_noise",
    "buffer_camera",
    "container_camera",
    "estimate_objects",
    "heightmap_from_depth",
    "layout_buffer",
    "perceive_buffer",
    "perceive_state",
    "render_depth",
    "segment_depth",
    "segment_truth",
    "sensor_preset",
]
