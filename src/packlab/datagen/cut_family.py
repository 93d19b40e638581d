"""The ``cut`` layout family: the stack cuboid cut recursively into boxes (Zhao et al. 2021, CUT).

Zhao et al. ("Online 3D Bin Packing with Constrained Deep Reinforcement Learning", AAAI 2021)
make their perfect-packing sets by cutting a 10 x 10 x 10 bin: pick a box, a random axis and a
random position, and cut, until every side of every box lies in [2, 5]. Here the same recipe runs
on the scenario's stack cuboid (container floor X x Y, the scenario's stack height; drawn by
``scenario.sample_scenario`` exactly as for the other families):

* **Grid.** Footprint cuts fall on the 2.5 cm xy grid; height cuts on whole cm (the z grid's
  ``height_step_mm``), so every height is whole cm as in the other families.
* **Side range** ``[lo, hi]`` per axis. ``lo`` is ``min_side_mm`` rounded up to the grid
  (3 cells = 7.5 cm across, 8 cm tall: heights keep 7.5 cm too, in whole cm). ``hi`` sets the
  object count, so it is chosen per case from the difficulty (``calibrated_range``): the
  footprint bound (the same across x and y) is the grid value whose *expected* count (computed
  exactly by ``expected_count``, no sampling) lies in the difficulty's ``n_objects`` range,
  nearest the scenario's object count (uniform in that range); the height bound is at most the
  footprint bound, half the stack height (Zhao's largest side is half the bin, so every column
  is cut at least once and every layout mixes heights) and ``layer_height_mm[1]``. No bound is
  below ``2 lo`` less one step, so an oversized side can always be cut into two sides >= lo.
  Small easy floors where no common bound fits (one column or four) try x and y bounds apart.
* **Cut.** A pending piece is drawn uniformly; if a side exceeds ``hi`` it is cut along such an
  axis (drawn uniformly among them) at a grid position drawn uniformly in ``[lo, side - lo]``.
* **Aspect.** A piece within ``hi`` whose footprint is longer than ``max_aspect`` times its
  width is cut once more across its long side (that side is then > 3 lo, so a cut exists); every
  object thus keeps footprint aspect <= ``max_aspect``, with no exception.
* **Count.** The cut is random, so its count scatters around the expected one. A cut whose count
  lies outside the difficulty's range is drawn again (same range, same stream), at most
  ``TRIES`` times; if none lands in range the draw closest to it is kept (the first of equals):
  a deterministic fallback, about 1 % of easy cases and none of medium or hard (200 seeds each;
  docs/datagen.md).

The result is an exact 3-D partition of the cuboid (a guillotine partition, every cut splits one
box in two), so ``layout.partition_problems`` holds and every box is fully supported, as for the
other families. ``LayoutBox.layer_index`` of a cut box is the index of its base height among the
layout's distinct base heights (0 on the floor): cut layouts have no layers, and this is what the
base-height order (``cut_order``) sorts by.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from packlab.datagen.config import CaseConfig, DifficultySpec
from packlab.datagen.layout import Layout, LayoutBox
from packlab.datagen.scenario import Scenario

#: Draws of one case's cut (same side range) before the one closest to the count range is kept.
TRIES = 16


@dataclass(frozen=True, slots=True)
class SideRange:
    """Allowed sides of a cut box per axis (x, y in xy cells; z in z cells), inclusive."""

    lo: tuple[int, int, int]
    hi: tuple[int, int, int]
    step: tuple[int, int, int]  # cut positions are multiples of this (1, 1, z cells per cm)


@dataclass(frozen=True, slots=True)
class CutDraw:
    """A cut layout and the side range of the draw that was kept."""

    layout: Layout
    sides: SideRange
    draws: int  # how many cuts were drawn (1 when the first landed in range)


@dataclass(frozen=True, slots=True)
class _Piece:
    origin: tuple[int, int, int]
    size: tuple[int, int, int]


def side_range(
    scenario: Scenario, cfg: CaseConfig, hi_x: int, hi_y: int | None = None
) -> SideRange:
    """The side range of a cut of ``scenario``'s stack cuboid whose footprint sides are at most
    ``hi_x`` x ``hi_y`` cells (``hi_y`` defaults to ``hi_x``: the same bound across).

    Heights: at most the longer footprint bound, half the stack height (Zhao et al.'s largest
    side is half their bin: every column is cut at least once, so every layout has boxes of
    mixed heights) and the objects' height cap, in whole cm. No bound falls below ``2 lo`` less
    one step: a side above it always has a cut leaving two sides >= lo.
    """
    hi_y = hi_x if hi_y is None else hi_y
    c = scenario.container
    xy, zc = c.cell_xy_mm, c.cell_z_mm
    obj = cfg.objects
    step_mm = obj.height_step_mm
    z_step = step_mm // zc
    lo_xy = -(-obj.min_side_mm // xy)
    lo_z = -(-max(obj.min_side_mm, obj.layer_height_mm[0]) // step_mm) * z_step
    z_mm = min(max(hi_x, hi_y) * xy, scenario.stack_height_mm / 2, obj.layer_height_mm[1])
    return SideRange(
        (lo_xy, lo_xy, lo_z),
        (
            max(2 * lo_xy - 1, hi_x),
            max(2 * lo_xy - 1, hi_y),
            max(2 * lo_z - z_step, int(z_mm // step_mm) * z_step),
        ),
        (1, 1, z_step),
    )


@functools.lru_cache(maxsize=4096)
def expected_pieces(length: int, lo: int, hi: int, step: int) -> float:
    """Expected number of pieces a side of ``length`` is cut into by the recipe on one axis.

    ``m(L) = 1`` for ``L <= hi``, else the mean of ``m(p) + m(L - p)`` over the cut positions
    ``p``. The cut of a box is one such recursion per axis, interleaved; by linearity the
    expected count of a box is the product of its three sides' ``m`` (the aspect rule's extra
    cuts aside), which is what ``calibrated_range`` aims at the target count.
    """
    units, lo_u, hi_u = length // step, lo // step, max(hi // step, 1)
    m = np.ones(units + 1)
    prefix = np.zeros(units + 2)  # prefix[k] = m[0] + ... + m[k - 1]
    prefix[1:] = np.cumsum(m)
    for n in range(units + 1):
        if n > hi_u and n >= 2 * lo_u:
            # positions p = lo_u .. n - lo_u: the mean of m(p) + m(n - p) is twice m's mean there
            k = n - 2 * lo_u + 1
            m[n] = 2 * (prefix[n - lo_u + 1] - prefix[lo_u]) / k
        prefix[n + 1] = prefix[n] + m[n]
    return float(m[units])


def expected_count(size: tuple[int, int, int], sides: SideRange) -> float:
    """Expected number of boxes of a cut of ``size`` with ``sides`` (see expected_pieces)."""
    out = 1.0
    for a in range(3):
        out *= expected_pieces(size[a], sides.lo[a], sides.hi[a], sides.step[a])
    return out


def calibrated_range(
    scenario: Scenario, cfg: CaseConfig, size: tuple[int, int, int], spec: DifficultySpec
) -> SideRange:
    """The side range aimed at the scenario's object count (no randomness).

    Every footprint bound on the grid, the same across x and y, is tried; ranges whose expected
    count lies in the difficulty's range are preferred, and among them the one nearest
    ``scenario.n_objects`` (by ratio), ties to the larger bound. Where no such range exists
    (small floors: one column or four, each cut in two or three tall), the x and y bounds are
    tried apart as well (two columns), and failing that the range whose expected count is
    nearest the difficulty's range is taken.
    """
    n_lo, n_hi = spec.n_objects
    target = scenario.n_objects

    def score(r: SideRange) -> tuple[int, float]:
        e = expected_count(size, r)
        outside = max(n_lo - e, 0.0, e - n_hi)
        return (0, abs(math.log(e / target))) if outside == 0 else (1, outside)

    bounds = range(max(size[:2]), 0, -1)
    best = min((side_range(scenario, cfg, k) for k in bounds), key=score)
    if score(best)[0] == 0:
        return best
    pairs = (side_range(scenario, cfg, kx, ky) for kx in bounds for ky in bounds)
    return min(pairs, key=score)


def _cut_axes(size: tuple[int, int, int], sides: SideRange, max_aspect: float) -> list[int]:
    """Axes along which a piece must still be cut (empty: the piece is a finished box)."""
    over = [a for a in range(3) if size[a] > sides.hi[a]]
    if over:
        return over
    dx, dy = size[0], size[1]
    if max(dx, dy) > max_aspect * min(dx, dy):
        return [0 if dx > dy else 1]
    return []


def cut_cuboid(
    size: tuple[int, int, int], sides: SideRange, max_aspect: float, rng: np.random.Generator
) -> list[_Piece]:
    """The cuboid ``size`` cut until every piece's sides lie in ``sides`` (Zhao's recipe).

    A piece still to cut is drawn uniformly among the pending ones, then an axis among those it
    must be cut along, then a grid position uniform in ``[lo, side - lo]`` on that axis.
    """
    pending = [_Piece((0, 0, 0), size)]
    done: list[_Piece] = []
    while pending:
        piece = pending.pop(int(rng.integers(len(pending))))
        axes = _cut_axes(piece.size, sides, max_aspect)
        if not axes:
            done.append(piece)
            continue
        a = axes[int(rng.integers(len(axes)))]
        lo, step, length = sides.lo[a], sides.step[a], piece.size[a]
        # Positions p with lo <= p <= length - lo, on the step grid (lo and length are on it).
        n_pos = (length - 2 * lo) // step + 1
        p = lo + step * int(rng.integers(n_pos))
        first, second = list(piece.size), list(piece.size)
        first[a], second[a] = p, length - p
        origin = list(piece.origin)
        origin[a] += p
        pending.append(_Piece(piece.origin, (first[0], first[1], first[2])))
        pending.append(_Piece((origin[0], origin[1], origin[2]), (second[0], second[1], second[2])))
    return done


def _layout(pieces: list[_Piece], cells: tuple[int, int], height: int) -> Layout:
    """Pieces as a layout, bottom first (by base height, then y, then x), layer_index = index of
    the base height among the distinct base heights."""
    bases = sorted({p.origin[2] for p in pieces})
    index = {z: i for i, z in enumerate(bases)}
    ordered = sorted(pieces, key=lambda p: (p.origin[2], p.origin[1], p.origin[0]))
    boxes = tuple(LayoutBox(*p.origin, *p.size, layer_index=index[p.origin[2]]) for p in ordered)
    return Layout(cells, height, boxes, "cut")


def _distance(count: int, lo: int, hi: int) -> int:
    return max(lo - count, 0, count - hi)


def build_cut_layout(
    scenario: Scenario, spec: DifficultySpec, cfg: CaseConfig, rng: np.random.Generator
) -> CutDraw:
    """The cut layout of a scenario (pure; draws only from ``rng``), see the module docstring."""
    c = scenario.container
    height = scenario.stack_height_mm // c.cell_z_mm
    size = (*c.cells, height)
    n_lo, n_hi = spec.n_objects
    sides = calibrated_range(scenario, cfg, size, spec)
    best: CutDraw | None = None
    best_miss = 0
    for draw in range(1, TRIES + 1):
        pieces = cut_cuboid(size, sides, cfg.objects.max_aspect, rng)
        miss = _distance(len(pieces), n_lo, n_hi)
        if best is None or miss < best_miss:
            best, best_miss = CutDraw(_layout(pieces, c.cells, height), sides, draw), miss
        if miss == 0:
            break
    assert best is not None  # TRIES >= 1
    return best


__all__ = [
    "CutDraw",
    "SideRange",
    "build_cut_layout",
    "calibrated_range",
    "cut_cuboid",
    "expected_count",
    "side_range",
]
