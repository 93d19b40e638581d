"""Driving the cell service with packlab's own simulated cameras: their calibrations, and a
case's steps rendered as a cell would send them (tests, benchmarks, a bench adapter).

``planned_steps`` renders step t of a case as the container holding the first t boxes of its
perfect plan at their planned poses, and the buffer holding the next ``buffer_size`` boxes,
laid out and scanned as packlab's perceived mode does (``perceive_buffer``: its noisy image
and, for comparison, the boxes its simulated robot found in it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from packlab.cell import schema
from packlab.cell.client import step_request
from packlab.cell.geometry import TOP_DOWN
from packlab.core.types import Case
from packlab.metrics import planned_centres_mm
from packlab.sim.heightmap import yaw_quaternion
from packlab.sim.sensing import (
    BufferPerception,
    DepthImage,
    add_sensor_noise,
    container_camera,
    perceive_buffer,
    sensor_preset,
)


def simulated_camera(image: DepthImage) -> schema.Camera:
    """The calibration of the packlab camera that rendered ``image``: orthographic, looking
    straight down with packlab's axes (``geometry.TOP_DOWN``), its origin (cx = cy = -0.5) at
    the outer corner of pixel (0, 0), so its pose's translation is the image's origin as it is."""
    nx, ny = image.shape
    matrix = np.eye(4)
    matrix[:3, :3] = TOP_DOWN
    matrix[:3, 3] = (*image.origin_mm, image.camera_z_mm)
    return schema.Camera(
        intrinsics=schema.OrthographicIntrinsics(
            model="orthographic", pixel_mm=image.pixel_mm, width=ny, height=nx, cx=-0.5, cy=-0.5
        ),
        pose=schema.Pose.model_validate({"matrix": matrix.tolist()}),
    )


@dataclass(frozen=True)
class SimulatedStep:
    """One step's images, and what packlab's simulated robot perceived from them."""

    container_image: DepthImage  # noisy, over the container
    buffer: BufferPerception  # the buffer's last scan: its noisy image and the boxes found
    remaining: int  # boxes still to pack, the shown ones included

    def request(self, encoding: Any = "f32") -> schema.StepRequest:
        """The step as a cell sends it: both images, the buffer camera of this scan (the
        simulated buffer camera frames each scan anew), the boxes still to come."""
        request = step_request(
            self.container_image.depth_mm,
            self.buffer.image.depth_mm,
            remaining=self.remaining,
            encoding=encoding,
        )
        request.buffer_camera = simulated_camera(self.buffer.image)
        return request


def planned_steps(case: Case, preset: str, steps: int, seed: int = 0) -> list[SimulatedStep]:
    """The first ``steps`` steps of ``case`` packed by its perfect plan, under sensor ``preset``
    (noise, buffer layouts and re-scans drawn from ``seed``)."""
    if case.gt_plan is None:
        raise ValueError(f"case {case.episode_id!r} has no perfect plan to render steps from")
    sensor = sensor_preset(preset)
    rng = np.random.default_rng(seed)
    index = {b.internal_id: i for i, b in enumerate(case.objects)}
    order = [index[s.internal_id] for s in case.gt_plan]
    centres = planned_centres_mm(case)
    sizes = np.array([b.size_mm for b in case.objects], dtype=float)
    positions = np.full((len(sizes), 3), np.nan)
    quats = np.full((len(sizes), 4), np.nan)
    grid = (case.container.cell_xy_mm, case.container.cell_z_mm)
    out = []
    for t in range(min(steps, len(order))):
        if t:  # the box the plan placed last step is in the container now
            placed = case.gt_plan[t - 1]
            positions[order[t - 1]] = centres[placed.internal_id]
            quats[order[t - 1]] = yaw_quaternion(placed.rotation)
        clean = container_camera(case.container, sizes, positions, quats, sensor)
        image = add_sensor_noise(clean, sensor, rng)
        shown = np.array([case.objects[i].size_mm for i in order[t : t + case.buffer_size]])
        buffer = perceive_buffer(shown, sensor, rng, "depth", grid)
        out.append(SimulatedStep(image, buffer, len(order) - t))
    return out


def session_request(
    case: Case, preset: schema.PresetName, first: SimulatedStep, **fields: Any
) -> schema.SessionRequest:
    """The session a cell opens for ``case``'s container with packlab's simulated cameras (the
    buffer camera of ``first``'s scan; each step sends its own)."""
    x, y, z = case.container.size_mm
    return schema.SessionRequest(
        container=schema.ContainerSpec(
            size_mm=(x, y, z),
            cell_mm=case.container.cell_xy_mm,
            height_step_mm=case.container.cell_z_mm,
        ),
        buffer_size=case.buffer_size,
        container_camera=simulated_camera(first.container_image),
        buffer_camera=simulated_camera(first.buffer.image),
        sensing=schema.Sensing(preset=preset),
        **fields,
    )


__all__ = ["SimulatedStep", "planned_steps", "session_request", "simulated_camera"]
