"""Reverse removal: a placement order for a layout, found by taking it apart from the top.

An object is *accessible* when nothing rests on any part of its top face. Removing accessible
objects one at a time until the container is empty and reading the removals backwards gives an
order in which every object is placed after everything it rests on, i.e. fully supported (the
layout fills its cuboid, see ``packlab.datagen.layout``). Among the accessible objects the next
removal is drawn uniformly with the case RNG, so orders vary between cases, except that the
*anchor* (the object to be placed first) is held back until it is the only one left.

An accessible non-anchor object exists at every stage: if all remaining objects sit on the
floor nothing rests on any of them; otherwise the remaining object with the highest bottom is
not the anchor (the anchor is on the floor) and nothing can rest on it.

The other arrival order, ``layers`` (``CaseConfig.order``, :func:`layer_order`), is the
reference benchmark's: objects arrive layer by layer (``layer_index`` ascending), in an order
drawn within each layer with the case RNG. The anchor (a floor object, so in layer 0) comes
first, as with removal. In a ``stepped`` layer a sub-layer object rests on objects of its own
layer, so within a layer the next object is drawn uniformly among those whose supports have all
arrived (for ``layered`` layouts, where nothing rests on its own layer, that is a uniform
shuffle of the layer). Every object therefore still comes after everything it rests on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.datagen.config import CORNERS, AnchorConfig
from packlab.datagen.layout import Layout, LayoutBox

#: Anchor label when the first object is not pinned to a corner.
FREE_ANCHOR = "free"


@dataclass(frozen=True, slots=True)
class PlacementOrder:
    """Indices into ``Layout.boxes`` in placement order, and where the first placement went."""

    order: tuple[int, ...]
    anchor: str  # a key of config.CORNERS, or FREE_ANCHOR
    rule: str = "removal"  # how it was drawn: a value of core.choices.ArrivalOrder


def _overlap_xy(a: LayoutBox, b: LayoutBox) -> bool:
    return a.x < b.x + b.dx and b.x < a.x + a.dx and a.y < b.y + b.dy and b.y < a.y + a.dy


def resting_on(boxes: tuple[LayoutBox, ...]) -> list[list[int]]:
    """``out[j]``: the boxes that box j rests on (bottom face touching their top with area > 0)."""
    return [
        [i for i, below in enumerate(boxes) if below.top == b.z and _overlap_xy(b, below)]
        for b in boxes
    ]


def _contains_cell(b: LayoutBox, x: int, y: int) -> bool:
    return b.x <= x < b.x + b.dx and b.y <= y < b.y + b.dy


def choose_anchor(layout: Layout, cfg: AnchorConfig, rng: np.random.Generator) -> tuple[int, str]:
    """(index of the object placed first, its anchor label): a floor object at a corner with
    probability ``cfg.corner_prob``, else a floor object touching no corner (any if none)."""
    nx, ny = layout.cells
    floor = [i for i, b in enumerate(layout.boxes) if b.z == 0]
    corner_cells = {
        name: (nx - 1 if hx else 0, ny - 1 if hy else 0) for name, (hx, hy) in CORNERS.items()
    }
    if rng.random() < cfg.corner_prob:
        name = cfg.corners[int(rng.integers(len(cfg.corners)))]
        cx, cy = corner_cells[name]
        return next(i for i in floor if _contains_cell(layout.boxes[i], cx, cy)), name
    inner = [
        i
        for i in floor
        if not any(_contains_cell(layout.boxes[i], cx, cy) for cx, cy in corner_cells.values())
    ]
    pool = inner or floor
    return pool[int(rng.integers(len(pool)))], FREE_ANCHOR


def reverse_removal(
    layout: Layout, anchor_cfg: AnchorConfig, rng: np.random.Generator
) -> PlacementOrder:
    """A random supported placement order whose first object is the chosen anchor."""
    boxes = layout.boxes
    anchor, label = choose_anchor(layout, anchor_cfg, rng)
    below = resting_on(boxes)
    n_above = [0] * len(boxes)  # how many remaining objects rest on each object
    for supports in below:
        for i in supports:
            n_above[i] += 1
    remaining = set(range(len(boxes)))
    removed: list[int] = []
    while remaining:
        free = sorted(i for i in remaining if n_above[i] == 0 and i != anchor)
        if not free:  # only the anchor is left (see the module docstring)
            free = [anchor]
        pick = free[int(rng.integers(len(free)))]
        remaining.remove(pick)
        removed.append(pick)
        for i in below[pick]:
            n_above[i] -= 1
    return PlacementOrder(tuple(reversed(removed)), label)


def layer_order(
    layout: Layout, anchor_cfg: AnchorConfig, rng: np.random.Generator
) -> PlacementOrder:
    """A supported placement order that goes layer by layer, the chosen anchor first.

    Within a layer the next object is drawn uniformly among the layer's objects whose supports
    have all been placed (see the module docstring).
    """
    boxes = layout.boxes
    anchor, label = choose_anchor(layout, anchor_cfg, rng)
    below = resting_on(boxes)
    placed: set[int] = set()
    order: list[int] = []
    for layer in sorted({b.layer_index for b in boxes}):
        pending = {i for i, b in enumerate(boxes) if b.layer_index == layer}
        while pending:
            if not order and anchor in pending:
                pick = anchor
            else:
                ready = sorted(i for i in pending if placed.issuperset(below[i]))
                if not ready:  # a support in a later layer: not a layout of this module
                    raise ValueError(f"layer {layer}: objects {sorted(pending)} are unsupported")
                pick = ready[int(rng.integers(len(ready)))]
            pending.remove(pick)
            placed.add(pick)
            order.append(pick)
    return PlacementOrder(tuple(order), label, "layers")


def order_problems(layout: Layout, order: tuple[int, ...]) -> list[str]:
    """Why ``order`` does not place every object fully supported (empty when it does).

    Checked on the voxel-column heights: when an object is placed, every cell under its
    footprint must already be filled exactly up to its bottom.
    """
    nx, ny = layout.cells
    height = np.zeros((nx, ny), dtype=np.int64)
    problems = []
    if sorted(order) != list(range(len(layout.boxes))):
        return [f"order {order} is not a permutation of the {len(layout.boxes)} objects"]
    for step, i in enumerate(order):
        b = layout.boxes[i]
        under = height[b.x : b.x + b.dx, b.y : b.y + b.dy]
        if not np.all(under == b.z):
            problems.append(
                f"step {step}: object {i} at z={b.z} is over cells of height "
                f"{int(under.min())}..{int(under.max())}"
            )
        under[...] = b.top
    return problems
