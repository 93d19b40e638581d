"""The ``rs`` layout family: i.i.d. boxes from a fixed set of types (the field's RS protocol).

Zhao et al. (AAAI 2021) test on sequences drawn i.i.d. and uniformly from 64 box types, every
side in {2, 3, 4, 5} units of a 10 x 10 x 10 bin. Here:

* **Container**: the scenario's (``scenario.sample_scenario``, same stream as the other
  families), so containers follow the difficulty table; only its container is used.
* **Unit** ``u``: a tenth of the container's smaller floor side, rounded to the 2.5 cm xy grid
  (half a cell rounds up): a 50 cm cube gives 5 cm units and sides 10-25 cm. Footprint sides are
  ``k u`` exactly (on the grid); heights ``k u`` rounded to whole cm (half up), the height grid of
  the other families (equal to ``k u`` whenever u is a multiple of 5 cm). The smallest container
  side (50 cm) gives u = 5 cm, so every side is >= 10 cm (> ``min_side_mm``) and every footprint
  aspect <= 5 / 2 (< ``max_aspect``); a box of 5 u is at most half the floor's smaller side plus
  6.25 cm, and no taller than any container of the difficulty table.
* **Types**: the 64 triples (a, b, c) in {2, 3, 4, 5}^3 (l = a u along x, w = b u, h = c u),
  indexed ``16 (a - 2) + 4 (b - 2) + (c - 2)``.
* **Length**: types are drawn i.i.d. uniformly until the drawn volume reaches the container's
  volume (the box that reaches it is kept, so the sequence holds more than fits: an online
  episode ends at the first box that fits nowhere), or until ``MAX_BOXES`` boxes (a guard never
  reached by the difficulty table: a container holds at most about 10 x 10 x 13 units and the
  mean type 42.9 unit^3, about 30 boxes).

There is no perfect layout and no ``gt_plan`` (the oracle refuses these cases, like ``random``);
arrival order is the draw order; ``Box.type_id`` is a colour id from the presentation stream, as
for every family.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from packlab.core.types import Container

#: Side multiples of the unit (Zhao et al.'s 2..5 of a 10-unit bin).
MULTIPLES: tuple[int, ...] = (2, 3, 4, 5)
#: The 64 box types, (a, b, c) multiples of the unit, in index order.
TYPES: tuple[tuple[int, int, int], ...] = tuple(product(MULTIPLES, MULTIPLES, MULTIPLES))
#: Units across the container's smaller floor side (Zhao et al.'s bin is 10 units wide).
UNITS_ACROSS = 10
#: Cap on a sequence's length (see the module docstring: never reached by the table).
MAX_BOXES = 200


@dataclass(frozen=True, slots=True)
class RSDraw:
    """The boxes of one RS case, in draw (= arrival) order."""

    unit_mm: int
    type_index: tuple[int, ...]  # per box, into TYPES
    sizes_mm: tuple[tuple[int, int, int], ...]  # (l, w, h) per box, l along x


def _round_half_up(value: int, step: int) -> int:
    return (2 * value + step) // (2 * step) * step


def unit_mm(container: Container) -> int:
    """The RS unit of a container: a tenth of its smaller floor side on the xy grid."""
    xy = container.cell_xy_mm
    return max(xy, _round_half_up(min(container.size_mm[:2]), UNITS_ACROSS * xy) // UNITS_ACROSS)


def type_size_mm(t: tuple[int, int, int], unit: int, height_step_mm: int) -> tuple[int, int, int]:
    """(l, w, h) of a type: footprint sides k u, height k u to whole ``height_step_mm``."""
    a, b, c = t
    return (a * unit, b * unit, _round_half_up(c * unit, height_step_mm))


def draw_rs_boxes(container: Container, height_step_mm: int, rng: np.random.Generator) -> RSDraw:
    """The boxes of an RS case in ``container`` (pure; draws only from ``rng``)."""
    unit = unit_mm(container)
    target = container.volume_mm3
    picks: list[int] = []
    sizes: list[tuple[int, int, int]] = []
    total = 0
    while total < target and len(picks) < MAX_BOXES:
        k = int(rng.integers(len(TYPES)))
        size = type_size_mm(TYPES[k], unit, height_step_mm)
        picks.append(k)
        sizes.append(size)
        total += size[0] * size[1] * size[2]
    return RSDraw(unit, tuple(picks), tuple(sizes))


__all__ = ["MAX_BOXES", "MULTIPLES", "TYPES", "RSDraw", "draw_rs_boxes", "type_size_mm", "unit_mm"]
