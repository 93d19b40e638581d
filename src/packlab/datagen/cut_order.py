"""The arrival orders of Zhao et al.'s CUT sets, for ``cut`` layouts (``CaseConfig.order``).

* ``base-height`` (their CUT-1): boxes sorted by the height of their base, shuffled among boxes
  of equal base height (case RNG). Every box comes after everything under it: a box's supports
  end at its base, so their bases are lower.
* ``support`` (their CUT-2): a box becomes *available* once the surface under its whole
  footprint stands exactly at its base (every column under it is filled up to its bottom); the
  next box is drawn uniformly among the available ones (case RNG). In an exact partition some
  box is always available (the lowest-based box not yet placed: every box under it is lower
  based, hence placed, and nothing above its base can be in its columns yet), so the draw never
  stalls.

Neither order pins a first box (no anchor, unlike ``removal`` and ``layers``): the recipe draws
the first box like any other, so the orders carry the anchor label ``NO_ANCHOR``.
"""

from __future__ import annotations

import numpy as np

from packlab.datagen.layout import Layout, LayoutBox
from packlab.datagen.removal import PlacementOrder

#: Anchor label of orders that do not choose their first box apart from the rest.
NO_ANCHOR = "none"


def base_height_order(layout: Layout, rng: np.random.Generator) -> PlacementOrder:
    """CUT-1: by base height, uniformly shuffled within each base height."""
    boxes = layout.boxes
    order: list[int] = []
    for z in sorted({b.z for b in boxes}):
        group = [i for i, b in enumerate(boxes) if b.z == z]
        order += [group[int(k)] for k in rng.permutation(len(group))]
    return PlacementOrder(tuple(order), NO_ANCHOR, "base-height")


def _under(surface: np.ndarray, b: LayoutBox) -> np.ndarray:
    """The columns under ``b``'s footprint (a view: writing to it raises them)."""
    return surface[b.x : b.x + b.dx, b.y : b.y + b.dy]


def support_order(layout: Layout, rng: np.random.Generator) -> PlacementOrder:
    """CUT-2: the next box drawn uniformly among those whose footprint's surface is at its base."""
    boxes = layout.boxes
    surface = np.zeros(layout.cells, dtype=np.int64)  # column heights, z cells
    pending = list(range(len(boxes)))
    order: list[int] = []
    while pending:
        ready = [i for i in pending if np.all(_under(surface, boxes[i]) == boxes[i].z)]
        if not ready:  # impossible for an exact partition (module docstring)
            raise ValueError(f"support order: none of objects {pending} is supported")
        pick = ready[int(rng.integers(len(ready)))]
        b = boxes[pick]
        _under(surface, b)[...] = b.top
        pending.remove(pick)
        order.append(pick)
    return PlacementOrder(tuple(order), NO_ANCHOR, "support")


__all__ = ["NO_ANCHOR", "base_height_order", "support_order"]
