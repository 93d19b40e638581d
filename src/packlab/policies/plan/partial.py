"""Partial completion: when the boxes in view cannot close a level, keep it closable (pure).

A perfect packing leaves no gap under any box, so only *flush* placements (every cell under the
footprint at the resting height, within ``tolerance_mm``) can be part of one. Among those, the
planner prefers placements after which every level of the container is still easy to fill by
boxes not yet seen. For a level z, the region still to fill up to z is ``F(z)``, every cell at
or below z. What makes ``F(z)`` hard to fill:

* **slivers**: cells that no square of the smallest side seen so far fits over inside ``F(z)``
  (no box can ever cover them without waste);
* **reflex corners**: a rectangle has none; every concave corner of the region needs one more
  box edge to end on it, and each such edge must be met exactly by the unseen boxes.

A state costs the sum over its levels of ``w_sliver * slivers + reflex corners`` plus
``w_levels`` per distinct level (every new top height is a surface the rest must meet). A short
beam search over flush placements of the shown boxes (each anchored against walls or taller
columns on two perpendicular sides, where every box of a packing can be put) scores states
after the same number of placements and commits the first placement of the cheapest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from packlab.core.feasibility import footprint_max
from packlab.core.types import ShownItem


@dataclass(frozen=True, slots=True)
class PartialConfig:
    """The beam and the cost of :mod:`.partial` (defaults from ``benchmarks/plan_sweep.py``)."""

    tolerance_mm: int = 4
    depth: int = 3  # placements per sequence (at most the shown boxes)
    beam: int = 4  # sequences kept per depth
    w_sliver: float = 4.0  # per sliver cell
    w_levels: float = 2.0  # per distinct level of the surface
    w_lift: float = 2.0  # per layer-height of resting height above the lowest level


@dataclass(frozen=True, slots=True)
class Move:
    """A flush placement: shown box ``key`` at rotation, cells (x, y), resting at z mm."""

    key: int
    rotation: int
    x: int
    y: int
    fx: int
    fy: int
    z: int
    top: int


def reflex_corners(region: np.ndarray) -> int:
    """Concave corners of a cell region: 2x2 windows (walls outside) with exactly 3 cells in."""
    p = np.pad(region, 1).astype(np.int8)
    s = p[:-1, :-1] + p[1:, :-1] + p[:-1, 1:] + p[1:, 1:]
    return int(np.count_nonzero(s == 3))


def sliver_cells(region: np.ndarray, side: int) -> int:
    """Cells of ``region`` that no ``side`` x ``side`` square inside it covers."""
    if side <= 1 or not region.any():
        return 0
    opened = ndimage.binary_opening(region, structure=np.ones((side, side), bool), border_value=0)
    return int(np.count_nonzero(region & ~opened))


def levels(heightmap: np.ndarray, tolerance_mm: int) -> list[int]:
    """The distinct surface levels (mm), lowest first; heights within the tolerance merge."""
    out: list[int] = []
    for h in np.unique(heightmap):
        if not out or int(h) - out[-1] > tolerance_mm:
            out.append(int(h))
    return out


def state_cost(heightmap: np.ndarray, side: int, config: PartialConfig) -> float:
    """How hard the surface is to complete (module docstring); 0 for a flat surface."""
    lv = levels(heightmap, config.tolerance_mm)
    cost = config.w_levels * (len(lv) - 1)
    for z in lv[:-1]:  # the top level's region is everything: nothing to close there
        region = heightmap <= z + config.tolerance_mm
        cost += reflex_corners(region) + config.w_sliver * sliver_cells(region, side)
    return cost


def _blocked(heightmap: np.ndarray, z: int, tol: int) -> np.ndarray:
    """Walls and columns above level z, on a grid padded by one wall cell on each side."""
    return np.pad(heightmap > z + tol, 1, constant_values=True)


def flush_moves(
    heightmap: np.ndarray,
    shown: Sequence[ShownItem],
    keys: Sequence[int],
    container_height_mm: int,
    tol: int,
) -> list[Move]:
    """Every flush, anchored placement of the shown boxes ``keys`` whose top stays in the rim."""
    hm = np.asarray(heightmap, dtype=np.int64)
    nx, ny = hm.shape
    out: list[Move] = []
    seen: set[tuple[int, int, int, int]] = set()  # (h, fx, fy) shapes already expanded
    for k in keys:
        s = shown[k]
        length, width, h = s.size_cells[0], s.size_cells[1], s.size_mm[2]
        for rotation, (fx, fy) in enumerate(((length, width), (width, length))):
            if rotation == 1 and length == width or fx > nx or fy > ny:
                continue
            if (h, fx, fy, 0) in seen:
                continue
            seen.add((h, fx, fy, 0))
            zmax = footprint_max(hm, fx, fy)
            zmin = -footprint_max(-hm, fx, fy)
            ok = (zmax - zmin <= tol) & (zmax + h <= container_height_mm)
            for x, y in zip(*np.nonzero(ok)):
                x, y = int(x), int(y)
                z = int(zmax[x, y])
                wall = _blocked(hm, z, tol)
                # side strips in padded coordinates (index + 1)
                left = wall[x, y + 1 : y + 1 + fy].all()
                right = wall[x + fx + 1, y + 1 : y + 1 + fy].all()
                front = wall[x + 1 : x + 1 + fx, y].all()
                back = wall[x + 1 : x + 1 + fx, y + fy + 1].all()
                if (left or right) and (front or back):
                    out.append(Move(k, rotation, x, y, fx, fy, z, z + h))
    return out


@dataclass(frozen=True, slots=True)
class _Node:
    heightmap: np.ndarray
    left: tuple[int, ...]  # shown keys not yet placed
    first: Move | None
    lift: float  # summed lift cost of the placements so far
    cost: float  # lift + the state's cost


def _apply(hm: np.ndarray, m: Move) -> np.ndarray:
    out = hm.copy()
    out[m.x : m.x + m.fx, m.y : m.y + m.fy] = m.top
    return out


def choose_partial(
    heightmap: np.ndarray,
    shown: Sequence[ShownItem],
    container_height_mm: int,
    smallest_side: int,
    layer_mm: int,
    config: PartialConfig = PartialConfig(),
) -> Move | None:
    """The first flush placement of the cheapest short sequence (module docstring), or None
    when no shown box has a flush, anchored placement."""
    hm0 = np.asarray(heightmap, dtype=np.int64)
    z0 = int(hm0.min())
    beam = [_Node(hm0, tuple(range(len(shown))), None, 0.0, 0.0)]
    best: _Node | None = None
    for _ in range(min(config.depth, len(shown))):
        grown: list[_Node] = []
        for node in beam:
            for m in flush_moves(
                node.heightmap, shown, node.left, container_height_mm, config.tolerance_mm
            ):
                hm = _apply(node.heightmap, m)
                lift = node.lift + config.w_lift * (m.z - z0) / max(layer_mm, 1)
                left = tuple(k for k in node.left if k != m.key)
                cost = lift + state_cost(hm, smallest_side, config)
                grown.append(_Node(hm, left, node.first or m, lift, cost))
        if not grown:
            break
        grown.sort(key=lambda n: n.cost)  # stable: ties keep the scan order
        beam = grown[: config.beam]
        best = beam[0]
    return None if best is None else best.first
