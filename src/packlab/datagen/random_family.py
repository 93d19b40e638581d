"""The ``random`` layout family: independently drawn boxes, with no perfect layout behind them.

Where ``layered`` and ``stepped`` cut a cuboid into boxes (so a perfect packing exists and the
case carries it as ``gt_plan``), a random case is a list of boxes drawn one at a time:

* The frame is the scenario of the other families (``scenario.sample_scenario``, same stream):
  the container, the stack height (in the difficulty's stack/container height ratio range), the
  layer count L and the object count n.
* **Target fill**: ``X * Y * stack height``, i.e. the ratio range times the container volume
  (0.45-0.70 for easy and medium, 0.84-0.96 for hard). Boxes are drawn until the next one would
  exceed it (that box is dropped and drawing stops), or until the difficulty's largest object
  count is reached. The total volume is therefore at most the target, below the container's.
* **Sizes** obey the rules of the other families: every side on the 2.5 cm grid and at least
  ``min_side_mm``, footprint aspect at most ``max_aspect`` (pairs drawn again until it holds),
  heights whole cm in the layer-height range. Their scale follows the scenario, so the object
  count lands near the difficulty's range: footprint sides are uniform on the grid with a mean
  of about ``side / sqrt(n / L)`` (the typical piece of a layer of n / L objects) and at most
  the container's side; heights are uniform with a mean of about ``stack / L`` and at most the
  stack height. A single box thus never exceeds the target, so a case has at least one object.
* Arrival order is the draw order; presentation (colour ids) comes from the case's
  presentation stream. There are no rotations to undo: a box's size is its drawn (l, w, h).

Nothing guarantees that all boxes fit: that is the point of the family (no oracle ceiling; the
oracle refuses these cases, they have no ``gt_plan``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from packlab.datagen.config import CaseConfig, DifficultySpec
from packlab.datagen.scenario import Scenario

#: Draws of a footprint pair before falling back to a square of the minimum side.
_ASPECT_TRIES = 100


@dataclass(frozen=True, slots=True)
class RandomDraw:
    """The boxes of one random case, in draw (= arrival) order."""

    sizes_mm: tuple[tuple[int, int, int], ...]  # (l, w, h) per box, l along x
    target_mm3: int  # the fill target the draw stopped under


def _side_bound(cells: int, per_layer: float, min_side: int) -> int:
    """Upper bound (cells) of a uniform side in [min_side, bound] whose mean is about
    ``cells / sqrt(per_layer)``, never above the container's side."""
    typical = cells / math.sqrt(max(per_layer, 1.0))
    return max(min_side, min(cells, round(2 * typical) - min_side))


def draw_random_boxes(
    scenario: Scenario, spec: DifficultySpec, cfg: CaseConfig, rng: np.random.Generator
) -> RandomDraw:
    """The boxes of a random case of ``scenario`` (pure; draws only from ``rng``)."""
    c = scenario.container
    xy = c.cell_xy_mm
    nx, ny = c.cells
    obj = cfg.objects
    min_side = -(-obj.min_side_mm // xy)
    n_layers = len(scenario.layer_heights_mm)
    per_layer = scenario.n_objects / n_layers
    ux = _side_bound(nx, per_layer, min_side)
    uy = _side_bound(ny, per_layer, min_side)
    step = obj.height_step_mm
    h_lo = obj.layer_height_mm[0]
    h_cap = min(obj.layer_height_mm[1], scenario.stack_height_mm)
    h_hi = max(h_lo, min(h_cap, 2 * scenario.stack_height_mm // n_layers - h_lo))
    h_units = (h_lo // step, h_hi // step)
    target = c.size_mm[0] * c.size_mm[1] * scenario.stack_height_mm
    sizes: list[tuple[int, int, int]] = []
    total = 0
    while len(sizes) < spec.n_objects[1]:
        for _ in range(_ASPECT_TRIES):
            a = int(rng.integers(min_side, ux + 1))
            b = int(rng.integers(min_side, uy + 1))
            if max(a, b) <= obj.max_aspect * min(a, b):
                break
        else:
            a = b = min_side
        h = int(rng.integers(h_units[0], h_units[1] + 1)) * step
        size = (a * xy, b * xy, h)
        volume = size[0] * size[1] * size[2]
        if total + volume > target:
            break
        sizes.append(size)
        total += volume
    return RandomDraw(tuple(sizes), target)


__all__ = ["RandomDraw", "draw_random_boxes"]
