"""The transition-backend protocol: how a placed box becomes settled poses and a heightmap."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from packlab.types import Box, Container


@dataclass(frozen=True, slots=True)
class Transition:
    """The outcome of one placement."""

    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm after everything settled
    settle_steps: int  # physics steps taken (0 for the geometric backend)
    capped: bool  # True when the step cap ended settling before the bodies came to rest


class TransitionBackend(Protocol):
    """One engine behind the episode. Boxes are addressed by their index in the case."""

    name: str

    def reset(self, container: Container, boxes: Sequence[Box]) -> np.ndarray:
        """Start an empty container holding none of ``boxes``; return the empty heightmap."""
        ...

    def place(self, index: int, rotation: int, min_corner_mm: tuple[int, int, int]) -> Transition:
        """Put box ``index`` with its footprint's minimum corner at ``min_corner_mm`` and settle."""
        ...

    def finish(self) -> Transition:
        """Called once after the last object: let everything come to rest before scoring."""
        ...

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (n, 3) float mm and quaternions (n, 4) wxyz of all boxes; NaN rows = not placed."""
        ...
