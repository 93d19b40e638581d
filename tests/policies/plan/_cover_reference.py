"""Frozen copy of the numpy exact-cover search, the reference for the bitmask search.

The property test (test_plan_cover_equivalence.py) and benchmarks/maintainers/cover_speed.py
compare :func:`packlab.policies.plan.cover.exact_cover` with this one: node budgets decide
results, so the fast search must take the same nodes and answer the same slots. Do not edit: it
is the reference. The result types come from packlab so results compare equal.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from packlab.policies.plan.cover import JOKER, CoverResult, CoverRules, Piece, Slot


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


def _run(line: np.ndarray | np.bool) -> int:
    """Length of the leading run of True in a 1-D bool array (a 0-d one: 0 or 1)."""
    stop = np.flatnonzero(~line)
    return int(stop[0]) if stop.size else int(line.size)


def _joker_sides(run: int, sides: set[int], smallest: int) -> list[int]:
    """Joker lengths along a run of ``run`` free cells, longest first: the whole run, or the run
    less one side of a box still unused (room for exactly that box after the joker)."""
    out = {run} | {run - d for d in sides if run - d >= smallest}
    return sorted((v for v in out if v >= smallest), reverse=True)


class _Search:
    """One depth-first search (state shared by the recursion; see the module docstring)."""

    def __init__(self, todo: np.ndarray, pieces: Sequence[Piece], rules: CoverRules, nodes: int):
        self.todo = todo
        self.pieces = pieces
        self.rules = rules
        self.max_nodes = nodes
        self.nodes = 0
        # Larger pieces first: they are the hardest to fit later, so failures show early.
        self.order = sorted(range(len(pieces)), key=lambda i: (-pieces[i].area, i))
        self.used = [False] * len(pieces)
        self.placed: list[Slot] = []
        self.found: list[tuple[Slot, ...]] = []
        self.wanted = rules.tilings if rules.jokers else 1

    def run(self, left: int, unused_area: int, jokers_left: int) -> bool:
        """Whether the cells still to do (``left`` of them) can be finished."""
        self.nodes += 1
        if self.nodes > self.max_nodes:
            raise _OutOfBudget
        if left == 0:
            if self.rules.use_all and unused_area:
                return False
            self.found.append(tuple(self.placed))
            return len(self.found) >= self.wanted
        if (unused_area < left and not jokers_left) or (self.rules.use_all and unused_area > left):
            return False
        x0, y0 = divmod(int(np.argmax(self.todo.ravel())), self.todo.shape[1])
        free = [i for i in self.order if not self.used[i]]
        if self._pieces_at(x0, y0, free, left, unused_area, jokers_left):
            return True
        return bool(jokers_left) and self._jokers_at(x0, y0, free, left, unused_area, jokers_left)

    def _gap_ok(self, rest: int, others: list[int], jokers_left: int) -> bool:
        """A run of ``rest`` cells left in the first empty column must fit one more rectangle."""
        if rest == 0:
            return True
        sides = [min(self.pieces[j].length, self.pieces[j].width) for j in others]
        if jokers_left:
            sides.append(self.rules.joker_side)
        return bool(sides) and rest >= min(sides)

    def _try(self, slot: Slot, left: int, unused_area: int, jokers_left: int) -> bool:
        window = self.todo[slot.x : slot.x + slot.fx, slot.y : slot.y + slot.fy]
        window[...] = False
        self.placed.append(slot)
        if self.run(left - slot.fx * slot.fy, unused_area, jokers_left):
            return True
        self.placed.pop()
        window[...] = True
        return False

    def _pieces_at(
        self, x0: int, y0: int, free: list[int], left: int, unused_area: int, jokers_left: int
    ) -> bool:
        run_y = _run(self.todo[x0, y0:])
        run_x = _run(self.todo[x0:, y0])
        options = []
        for rank, i in enumerate(free):
            p = self.pieces[i]
            for rotation, (fx, fy) in enumerate(((p.length, p.width), (p.width, p.length))):
                if fx <= run_x and fy <= run_y and (rotation == 0 or p.length != p.width):
                    # A piece that spans the whole free run in either direction first: it
                    # leaves the rest as simple as it was (the tiling a guess is built on).
                    spans = fy == run_y or fx == run_x
                    options.append((not spans, rank, rotation, i, fx, fy))
        tried: set[tuple[int, int]] = set()
        for _, _, rotation, i, fx, fy in sorted(options):
            if (fx, fy) in tried:
                continue
            tried.add((fx, fy))
            if not self._gap_ok(run_y - fy, [j for j in free if j != i], jokers_left):
                continue
            if not self.todo[x0 : x0 + fx, y0 : y0 + fy].all():
                continue
            self.used[i] = True
            slot = Slot(self.pieces[i].key, rotation, x0, y0, fx, fy)
            if self._try(slot, left, unused_area - self.pieces[i].area, jokers_left):
                return True
            self.used[i] = False
        return False

    def _jokers_at(
        self, x0: int, y0: int, free: list[int], left: int, unused_area: int, jokers_left: int
    ) -> bool:
        sides = {v for i in free for v in (self.pieces[i].length, self.pieces[i].width)}
        side = self.rules.joker_side
        spare = left - unused_area  # what the jokers must fill when every piece is used
        for fy in _joker_sides(_run(self.todo[x0, y0:]), sides, side):
            if not self._gap_ok(_run(self.todo[x0, y0:]) - fy, free, jokers_left - 1):
                continue
            # the widest joker of this length whose cells are all free, then narrower ones
            reach = _run(self.todo[x0:, y0 : y0 + fy].all(axis=1))
            for fx in _joker_sides(reach, sides, side):
                if self.rules.use_all and (
                    fx * fy > spare or (jokers_left == 1 and fx * fy != spare)
                ):
                    continue
                if self._try(Slot(JOKER, 0, x0, y0, fx, fy), left, unused_area, jokers_left - 1):
                    return True
        return False


def exact_cover(
    region: np.ndarray,
    pieces: Sequence[Piece],
    max_nodes: int = 20_000,
    rules: CoverRules = CoverRules(),  # noqa: B008  (frozen: immutable)
) -> CoverResult:
    """A tiling of the True cells of ``region`` (a 2-D bool array) by a subset of ``pieces``.

    Slots come in the order the search placed them (scan order of their corners), so the first
    slot covers the region's first cell. See the module docstring for completeness and pruning.

    ``rules.jokers`` > 0 also allows up to that many rectangles of free size (``Slot.key`` is
    :data:`JOKER`, sides at least ``rules.joker_side``): the space boxes not yet seen must fill.
    A joker ends at the region's boundary or leaves room for one unused piece's side (a
    heuristic restriction: that search is not complete). ``rules.use_all`` demands every piece.
    """
    todo = np.array(region, dtype=bool, copy=True)
    area = int(todo.sum())
    if area == 0:
        return CoverResult((), 0, False)
    total = sum(p.area for p in pieces)
    if not pieces or (rules.use_all and total > area):
        return CoverResult(None, 0, False)
    if not rules.jokers and not (subset_sums([p.area for p in pieces]) >> area) & 1:
        return CoverResult(None, 0, False)
    smallest = min(min(p.length, p.width) for p in pieces)
    if not coverable_by_squares(
        todo, min(smallest, rules.joker_side) if rules.jokers else smallest
    ):
        return CoverResult(None, 0, False)
    search = _Search(todo, pieces, rules, max_nodes)
    try:
        search.run(area, total, rules.jokers)
    except _OutOfBudget:
        if not search.found:
            return CoverResult(None, search.nodes, True)
    if not search.found:
        return CoverResult(None, search.nodes, False)
    best = max(search.found, key=_narrowest_joker)
    # Every tiling found, as the fast search reports them for a guess (its commit rule).
    return CoverResult(best, search.nodes, False, tuple(search.found) if rules.jokers else ())


def _narrowest_joker(slots: tuple[Slot, ...]) -> int:
    """The narrowest side among a tiling's jokers (large when it has none); ``max`` keeps the
    first of equals, i.e. the search order."""
    return min((min(s.fx, s.fy) for s in slots if s.key == JOKER), default=1 << 30)
