"""Exact rectangle cover: tile a region of grid cells with a subset of given rectangles (pure).

The search places, at each node, one rectangle with its minimum corner on the region's *first
empty cell* (x-major scan: lowest x, then lowest y). Every exact tiling has a rectangle whose
corner is that cell (every cell before it in the scan is covered already), so the search is
complete: with an unlimited budget it finds a tiling whenever one exists (Huang & Korf, JAIR
2013, use the same branching for perfect rectangle packing). Both rotations are tried;
rectangles of the same footprint are interchangeable, so each footprint is tried once per node.

Pruning, each of which only removes nodes that have no completion:

* area: the region's cell count must be a sum of a subset of the rectangles' areas (checked
  once, a bitset of reachable sums), and never more than the area still unused;
* slivers: cells of the first empty column below the placed rectangle can only be covered by
  rectangles whose corner is in that column, so the run left there must be 0 or at least the
  smallest side still available; the same holds for the region at the start (a cell no
  smallest-side square fits over can never be covered).

A node budget bounds the work; running out answers "not found" (``CoverResult.exhausted``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True, slots=True)
class Piece:
    """A rectangle that may be used once: ``key`` is the caller's id (e.g. a shown index)."""

    key: int
    length: int  # cells along x at rotation 0
    width: int  # cells along y at rotation 0

    @property
    def area(self) -> int:
        return self.length * self.width


@dataclass(frozen=True, slots=True)
class Slot:
    """One rectangle of a tiling: the piece, its rotation and its footprint in cells."""

    key: int
    rotation: int
    x: int
    y: int
    fx: int
    fy: int


@dataclass(frozen=True, slots=True)
class CoverResult:
    """A tiling in placement order (None when none was found) and the nodes it took."""

    slots: tuple[Slot, ...] | None
    nodes: int
    exhausted: bool  # the budget ran out before the search could answer


class _OutOfBudget(Exception):
    pass


def subset_sums(areas: Sequence[int]) -> int:
    """Bitset (a Python int) whose bit ``s`` is set when some subset of ``areas`` sums to s."""
    reach = 1
    for a in areas:
        reach |= reach << a
    return reach


def coverable_by_squares(region: np.ndarray, side: int) -> bool:
    """Whether every cell of ``region`` lies under some ``side`` x ``side`` square inside it
    (a morphological opening that keeps the region): otherwise no rectangle with both sides
    at least ``side`` can cover that cell."""
    if side <= 1:
        return True
    square = np.ones((side, side), dtype=bool)
    opened = ndimage.binary_opening(region, structure=square, border_value=0)
    return bool(np.array_equal(opened, region))


def _run(line: np.ndarray) -> int:
    """Length of the leading run of True in a 1-D bool array."""
    stop = np.flatnonzero(~line)
    return int(stop[0]) if stop.size else int(line.size)


#: ``Slot.key`` of a joker: a rectangle left for boxes not yet seen.
JOKER = -1


def _joker_sides(run: int, sides: set[int], smallest: int) -> list[int]:
    """Joker lengths along a run of ``run`` free cells, longest first: the whole run, or the run
    less one side of a box still unused (room for exactly that box after the joker)."""
    out = {run} | {run - d for d in sides if run - d >= smallest}
    return sorted((v for v in out if v >= smallest), reverse=True)


def exact_cover(
    region: np.ndarray,
    pieces: Sequence[Piece],
    max_nodes: int = 20_000,
    jokers: int = 0,
    use_all: bool = False,
    joker_side: int = 1,
) -> CoverResult:
    """A tiling of the True cells of ``region`` (a 2-D bool array) by a subset of ``pieces``.

    Slots come in the order the search placed them (scan order of their corners), so the first
    slot covers the region's first cell. See the module docstring for completeness and pruning.

    ``jokers`` > 0 also allows up to that many rectangles of free size (``Slot.key`` is
    :data:`JOKER`, sides at least ``joker_side``): the space the boxes not yet seen must fill.
    A joker ends at the region's boundary or leaves room for one unused piece's side (a
    heuristic restriction: that search is not complete). ``use_all`` demands every piece.
    """
    todo = np.array(region, dtype=bool, copy=True)
    area = int(todo.sum())
    if area == 0:
        return CoverResult((), 0, False)
    if not pieces:
        return CoverResult(None, 0, False)
    total = sum(p.area for p in pieces)
    if use_all and total > area:
        return CoverResult(None, 0, False)
    if not jokers and not (subset_sums([p.area for p in pieces]) >> area) & 1:
        return CoverResult(None, 0, False)
    smallest_piece = min(min(p.length, p.width) for p in pieces)
    smallest = min(smallest_piece, joker_side) if jokers else smallest_piece
    if not coverable_by_squares(todo, smallest):
        return CoverResult(None, 0, False)
    # Larger pieces first: they are the hardest to fit later, so failures show early.
    order = sorted(range(len(pieces)), key=lambda i: (-pieces[i].area, i))
    used = [False] * len(pieces)
    placed: list[Slot] = []
    nodes = 0
    ny = todo.shape[1]

    def recurse(left: int, unused_area: int, jokers_left: int) -> bool:
        nonlocal nodes
        nodes += 1
        if nodes > max_nodes:
            raise _OutOfBudget
        if left == 0:
            return not use_all or unused_area == 0
        if unused_area < left and not jokers_left:
            return False
        if use_all and unused_area > left:
            return False
        flat = int(np.argmax(todo.ravel()))
        x0, y0 = divmod(flat, ny)
        run_y = _run(todo[x0, y0:])
        run_x = _run(todo[x0:, y0])
        free = [i for i in order if not used[i]]
        tried: set[tuple[int, int]] = set()
        for i in free:
            p = pieces[i]
            smallest_other = min(
                (min(pieces[j].length, pieces[j].width) for j in free if j != i), default=0
            )
            for rotation, (fx, fy) in enumerate(((p.length, p.width), (p.width, p.length))):
                if (fx, fy) in tried or fx > run_x or fy > run_y:
                    continue
                tried.add((fx, fy))
                rest = run_y - fy
                floor = min(smallest_other, joker_side) if jokers_left else smallest_other
                if rest and (floor == 0 or rest < floor):
                    continue
                window = todo[x0 : x0 + fx, y0 : y0 + fy]
                if not window.all():
                    continue
                window[...] = False
                used[i] = True
                placed.append(Slot(p.key, rotation, x0, y0, fx, fy))
                if recurse(left - fx * fy, unused_area - p.area, jokers_left):
                    return True
                placed.pop()
                used[i] = False
                window[...] = True
        if jokers_left:
            sides = {v for i in free for v in (pieces[i].length, pieces[i].width)}
            small = min(min(smallest_piece, joker_side), *(sides or {joker_side}))
            for fy in _joker_sides(run_y, sides, joker_side):
                rest = run_y - fy
                if rest and rest < small:
                    continue
                # widest joker of this length whose cells are all free, then narrower ones
                cols = todo[x0:, y0 : y0 + fy].all(axis=1)
                reach = _run(cols)
                for fx in _joker_sides(reach, sides, joker_side):
                    spare = left - unused_area  # what the jokers must fill when use_all
                    if use_all and (fx * fy > spare or (jokers_left == 1 and fx * fy != spare)):
                        continue
                    window = todo[x0 : x0 + fx, y0 : y0 + fy]
                    window[...] = False
                    placed.append(Slot(JOKER, 0, x0, y0, fx, fy))
                    if recurse(left - fx * fy, unused_area, jokers_left - 1):
                        return True
                    placed.pop()
                    window[...] = True
        return False

    try:
        found = recurse(area, total, jokers)
    except _OutOfBudget:
        return CoverResult(None, nodes, True)
    return CoverResult(tuple(placed) if found else None, nodes, False)
