"""The geometric backend: exact paper Eq. 2, boxes never move, no physics."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from packlab.core.protocols import Transition
from packlab.core.types import Box, Container
from packlab.sim.heightmap import place_box, yaw_quaternion


class GeometricBackend:
    """Heightmap-only transitions: a box rests at exactly the drop height it was given."""

    name = "geometric"

    def __init__(self) -> None:
        self._container: Container | None = None
        self._boxes: tuple[Box, ...] = ()
        self._heightmap = np.zeros((0, 0), dtype=np.int32)
        self._positions = np.zeros((0, 3))
        self._quats = np.zeros((0, 4))

    def reset(self, container: Container, boxes: Sequence[Box]) -> np.ndarray:
        self._container = container
        self._boxes = tuple(boxes)
        self._heightmap = np.zeros(container.cells, dtype=np.int32)
        self._positions = np.full((len(boxes), 3), np.nan)
        self._quats = np.full((len(boxes), 4), np.nan)
        return self._heightmap.copy()

    def place(self, index: int, rotation: int, min_corner_mm: tuple[int, int, int]) -> Transition:
        assert self._container is not None, "reset() first"
        box = self._boxes[index]
        fx_mm, fy_mm = box.footprint_mm(rotation)
        cell = self._container.cell_xy_mm
        x_mm, y_mm, z_mm = min_corner_mm
        self._positions[index] = (x_mm + fx_mm / 2, y_mm + fy_mm / 2, z_mm + box.size_mm[2] / 2)
        self._quats[index] = yaw_quaternion(rotation)
        # Footprints of valid actions lie on whole cells; ceil keeps partial cells covered.
        x0, y0 = x_mm // cell, y_mm // cell
        fx, fy = -(-fx_mm // cell), -(-fy_mm // cell)
        self._heightmap = place_box(self._heightmap, x0, y0, fx, fy, z_mm + box.size_mm[2])
        return Transition(self._heightmap, settle_steps=0, capped=False)

    def finish(self) -> Transition:
        return Transition(self._heightmap, settle_steps=0, capped=False)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        return self._positions.copy(), self._quats.copy()
