"""Shared value types of packlab.

Geometry is integer millimetres everywhere inside the library (files speak centimetres, see
``packlab.cases``). Axes: x along the container's first dimension, y along the second, z up;
cell (0, 0) is the corner at the container origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Default horizontal action-grid cell (2.5 cm) and vertical height quantum (0.2 cm), in mm.
DEFAULT_CELL_XY_MM = 25
DEFAULT_CELL_Z_MM = 2

#: An object's identity within its case, kept exactly as the case file gives it: packlab's
#: generator numbers objects (``3``), the reference writes strings (``"obj_00003"``). All ids of
#: one case have the same type (checked on load), so they compare and sort without surprises.
InternalId = int | str


@dataclass(frozen=True, slots=True)
class Container:
    """An open-top container of ``size_mm = (X, Y, Z)`` millimetres on a grid of ``cell_xy_mm``."""

    size_mm: tuple[int, int, int]
    cell_xy_mm: int = DEFAULT_CELL_XY_MM
    cell_z_mm: int = DEFAULT_CELL_Z_MM

    @property
    def cells(self) -> tuple[int, int]:
        """Heightmap shape (x_cells, y_cells)."""
        return (self.size_mm[0] // self.cell_xy_mm, self.size_mm[1] // self.cell_xy_mm)

    @property
    def height_mm(self) -> int:
        return self.size_mm[2]

    @property
    def volume_mm3(self) -> int:
        x, y, z = self.size_mm
        return x * y * z


@dataclass(frozen=True, slots=True)
class Box:
    """One object of a case: a cuboid of ``size_mm = (l, w, h)`` at rotation 0 (l along x)."""

    internal_id: InternalId
    size_mm: tuple[int, int, int]
    gt_index: int = -1
    type_id: int = 0

    @property
    def volume_mm3(self) -> int:
        l, w, h = self.size_mm
        return l * w * h

    def footprint_mm(self, rotation: int) -> tuple[int, int]:
        """(extent along x, extent along y); rotation 1 is a 90 degree yaw that swaps l and w."""
        l, w, _ = self.size_mm
        return (w, l) if rotation == 1 else (l, w)


@dataclass(frozen=True, slots=True)
class PlanStep:
    """One entry of a case's perfect layout (``gt_plan``), in grid cells.

    ``cell_min``/``cell_size`` are (x, y, z) in (xy cells, xy cells, z cells) of the final box.
    """

    internal_id: InternalId
    gt_index: int
    layer_index: int
    cell_min: tuple[int, int, int]
    cell_size: tuple[int, int, int]
    x: int
    y: int
    rotation: int


@dataclass(frozen=True, slots=True)
class CaseOrigin:
    """Where a case's row sat in a reference-layout file: its ``extra_info.split`` and ``index``.

    Provenance, not content: it takes no part in a case's equality or checksum and is not
    written to packlab's own JSONL; the reference exporter writes it back into ``extra_info``.
    """

    split: str | None  # None: the row had no ``split``
    index: int | None  # None: the row had no ``index``


@dataclass(frozen=True, slots=True)
class Case:
    """A packing problem: container, arrival sequence, buffer size and optional perfect plan."""

    episode_id: str
    container: Container
    buffer_size: int
    objects: tuple[Box, ...]
    seed: int = 0
    difficulty: str = ""
    gt_plan: tuple[PlanStep, ...] | None = None
    generator: dict[str, Any] = field(default_factory=dict)
    #: Set when the case was read from a reference-layout row (see ``CaseOrigin``).
    origin: CaseOrigin | None = field(default=None, compare=False)

    @property
    def total_volume_mm3(self) -> int:
        return sum(b.volume_mm3 for b in self.objects)

    def box_by_id(self, internal_id: InternalId) -> Box:
        for b in self.objects:
            if b.internal_id == internal_id:
                return b
        raise KeyError(f"case {self.episode_id!r}: no object with internal_id={internal_id!r}")


@dataclass(frozen=True, slots=True)
class Action:
    """A placement: ``object_id`` indexes the *shown* buffer.

    (x, y) is the footprint's minimum cell.
    """

    object_id: int
    rotation: int
    x: int
    y: int

    @classmethod
    def set_aside(cls, object_id: int) -> Action:
        """Set shown box ``object_id`` aside on purpose (it counts as unpacked): what a robot
        cell does with a box it will not put in this container. (x, y) = (-1, -1), where no
        footprint starts; the episode records the step with reason ``set_aside``."""
        return cls(object_id, 0, -1, -1)

    @property
    def sets_aside(self) -> bool:
        """Whether this is :meth:`set_aside`'s action."""
        return self.x == -1 and self.y == -1

    def to_dict(self) -> dict[str, int]:
        return {"object_id": self.object_id, "x": self.x, "y": self.y, "rotation": self.rotation}


@dataclass(frozen=True, slots=True)
class Unparsable:
    """Stand-in for an action that could not be obtained (e.g. model text that did not parse)."""

    text: str
    error: str


@dataclass(frozen=True, slots=True)
class Pose:
    """Settled pose of one box: centre position (mm, float) and unit quaternion (w, x, y, z)."""

    position_mm: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class ShownItem:
    """One object as the policy sees it in the buffer at a step."""

    shown_index: int
    internal_id: InternalId
    size_mm: tuple[int, int, int]
    #: (l, w) in xy cells and h in z cells; sizes are multiples of the grid in valid cases.
    size_cells: tuple[int, int, int]
    type_id: int = 0

    @property
    def size_cm(self) -> tuple[float, float, float]:
        return tuple(v / 10.0 for v in self.size_mm)  # type: ignore[return-value]


@dataclass(frozen=True, slots=True)
class HistoryEntry:
    """A past step as the policy saw it: the heightmap before, the shown buffer and the action."""

    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, before the action
    shown: tuple[ShownItem, ...]
    action: Action | Unparsable
    valid: bool


@dataclass(frozen=True, slots=True)
class Observation:
    """What a policy sees at one step."""

    step_index: int
    container: Container
    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, top surface over each cell
    shown: tuple[ShownItem, ...]
    history: tuple[HistoryEntry, ...] = ()
    #: Objects not yet processed, shown ones included: an extension of the reference's
    #: observation (a robot cell knows its order's size); None when the run hides it
    #: (``--remaining hidden``), and a policy must then do without.
    remaining: int | None = 0
    #: The online protocol (``packlab.core.packing_protocol``): ``shown`` is the next boxes in
    #: arrival order and only the first (index 0) may be placed; the others are lookahead. The
    #: shared candidate search (``core.feasibility.observation_candidates``) and so every
    #: policy built on it obey this; an action naming another index is an invalid step.
    must_place_first: bool = False

    def placeable(self, index: int) -> bool:
        """Whether shown box ``index`` may be placed now (the one rule of the online protocol)."""
        return 0 <= index < len(self.shown) and (index == 0 or not self.must_place_first)

    def remaining_at_least(self) -> int:
        """``remaining`` where the run shows it, else the least it can be (the shown objects)."""
        return len(self.shown) if self.remaining is None else self.remaining

    def remaining_known(self) -> int:
        """``remaining``; a ValueError when the run hides it (for producers of training data,
        which record it and must not record a guess)."""
        if self.remaining is None:
            raise ValueError(
                f"step {self.step_index}: the observation hides `remaining` "
                "(--remaining hidden); this producer records it and needs it shown"
            )
        return self.remaining
