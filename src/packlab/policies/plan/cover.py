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

A node budget bounds the work; running out answers "not found" (``CoverResult.exhausted``),
or, when looking for several tilings (``CoverRules.tilings``), the best of those found so far.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import accumulate

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
    #: Every tiling the search found (``CoverRules.tilings`` > 1: a guess), in search order;
    #: ``slots`` is one of them. Empty when only one was looked for.
    tilings: tuple[tuple[Slot, ...], ...] = ()


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


#: ``Slot.key`` of a joker: a rectangle left for boxes not yet seen.
JOKER = -1


def _joker_sides(run: int, sides: Sequence[int], smallest: int) -> list[int]:
    """Joker lengths along a run of ``run`` free cells, longest first: the whole run, or the run
    less one side of a box still unused (room for exactly that box after the joker).
    ``sides``: the distinct sides of the boxes still unused, ascending."""
    if run < smallest:
        return []
    out = [run]
    for d in sides:
        if run - d < smallest:
            break  # the sides ascend, so the lengths left only get shorter
        if d:
            out.append(run - d)
    return out


@dataclass(frozen=True, slots=True)
class CoverRules:
    """What a tiling may use besides the pieces (see :func:`exact_cover`)."""

    jokers: int = 0  # rectangles of free size left for boxes not yet seen
    use_all: bool = False  # every piece must be in the tiling
    joker_side: int = 1  # the smallest side of a joker (and of any gap left for one)
    #: With jokers: look at up to this many tilings and keep the one whose narrowest joker is
    #: widest (unseen boxes at least that wide can fill it: the more sizes, the safer a guess).
    tilings: int = 1


#: One orientation of a piece: (rotation, fx, fy, footprint id, window mask).
_Orient = tuple[int, int, int, int, int]
#: One piece as the search reads it: (key, area, smaller side, bit, orientations); ``bit`` is
#: its bit in the masks of unused pieces.
_Rec = tuple[int, int, int, int, tuple[_Orient, ...]]
#: What the search reads of a set of unused pieces: (those pieces in search order, their
#: distinct sides ascending, the smallest of their smaller sides, the second smallest, the
#: bit of the piece with the smallest, joker lengths by run as :func:`_joker_sides` gives).
_Unused = tuple[list[_Rec], list[int], int, int, int, dict[int, list[int]]]

#: A bound no run reaches: the gap test's "no rectangle is left to fill it".
_NEVER = 1 << 62


def _bits(cells: np.ndarray) -> int:
    """A 2-D bool array as one int: cell (x, y) is bit ``x * (ny + 1) + y``. The extra bit per
    row stays 0, so a run of set bits along a row ends at the row's end."""
    padded = np.zeros((cells.shape[0], cells.shape[1] + 1), dtype=bool)
    padded[:, :-1] = cells
    return int.from_bytes(np.packbits(padded.ravel(), bitorder="little").tobytes(), "little")


def _runs_along_x(region: np.ndarray) -> np.ndarray:
    """``runs[x, y]``: the region's cells in a row along x from (x, y), that cell included."""
    x = np.arange(region.shape[0])[:, None]
    # the first cell at or after x of each line that is not the region's (nx when none)
    stop = np.minimum.accumulate(np.where(region, region.shape[0], x)[::-1], axis=0)[::-1]
    return np.asarray(stop - x)


class _Search:
    """One depth-first search (see the module docstring).

    The cells still to do are one int, ``grid`` (:func:`_bits`), passed down as an argument:
    ints are immutable, so backtracking restores nothing. The first empty cell is its lowest
    set bit and the run along y there its lowest zero bit after that.

    Every placement has its corner on the first empty cell, so the placed cells of each line
    along x are a prefix of it (region gaps aside): beyond the first empty cell (x0, y) a line
    holds only cells the region had. Hence for y in the run at (x0, y0) the free run along x is
    the region's own, ``runs[x0, y]``, and an fx x fy rectangle at the corner is free exactly
    when fy is at most the run along y and fx at most min(runs[x0, y0 : y0 + fy]): one look-up
    in a prefix-minimum list, cached per corner. This is the same search, node for node, as the
    earlier numpy one (tests/policies/plan/_cover_reference.py): node budgets decide results.
    """

    def __init__(self, region: np.ndarray, pieces: Sequence[Piece], rules: CoverRules, nodes: int):
        nx, ny = region.shape
        self.stride = ny + 1
        self.runs = _runs_along_x(region)
        self.reach: dict[int, list[int]] = {}  # corner bit -> see _reach
        self.use_all = rules.use_all
        self.joker_side = rules.joker_side
        self.max_nodes = nodes
        self.nodes = 0
        self.placed: list[tuple[int, int, int, int, int, int]] = []
        self.found: list[tuple[Slot, ...]] = []
        self.wanted = rules.tilings if rules.jokers else 1
        # A footprint's id is fx * span + fy: fy < span for every piece and joker, so two
        # footprints never share one (a piece wider than the grid included).
        self.span = 1 + max(self.stride, *(max(p.length, p.width) for p in pieces))
        self.windows: dict[int, int] = {}  # footprint id -> window mask (see _window)
        self.columns = [0]  # columns[fx]: bit 0 of each of the first fx rows
        # Larger pieces first: they are the hardest to fit later, so failures show early.
        order = sorted(range(len(pieces)), key=lambda i: (-pieces[i].area, i))
        #: Per piece in search order; a square has one orientation (its rotation is the same).
        self.order: list[_Rec] = []
        self.sides: list[tuple[int, int]] = []  # (length, width) in the same order
        for rank, i in enumerate(order):
            p = pieces[i]
            turns = ((0, p.length, p.width), (1, p.width, p.length))
            # (a footprint larger than the grid never fits: it needs no window)
            orients = tuple(
                (
                    r,
                    fx,
                    fy,
                    fx * self.span + fy,
                    self._window(fx, fy) if fx <= nx and fy <= ny else 0,
                )
                for r, fx, fy in (turns if p.length != p.width else turns[:1])
            )
            self.order.append((p.key, p.area, min(p.length, p.width), 1 << rank, orients))
            self.sides.append((p.length, p.width))
        self.unused_sets: dict[int, _Unused] = {}  # mask of unused pieces -> what it holds
        #: (mask, run along x, run along y, jokers left) -> the placements to try (_choices)
        self.choices: dict[tuple[int, int, int, bool], list[tuple[_Rec, _Orient]]] = {}

    def _window(self, fx: int, fy: int) -> int:
        """The bits of an fx x fy rectangle with its corner at bit 0 (see :func:`_bits`): one
        row's bits times a bit per row (no carries: a row's bits stop short of the next)."""
        while len(self.columns) <= fx:
            self.columns.append(self.columns[-1] | 1 << (len(self.columns) - 1) * self.stride)
        window = self.windows[fx * self.span + fy] = ((1 << fy) - 1) * self.columns[fx]
        return window

    def _reach(self, pos: int) -> list[int]:
        """``reach[fy]``: how long an fy-wide rectangle at the corner at bit ``pos`` may be
        (fy at most the run along y there): the minimum of the region's runs along x under it.
        ``reach[0]`` is the rows left, as for an empty slice of the grid."""
        x0, y0 = divmod(pos, self.stride)
        runs: list[int] = self.runs[x0, y0:].tolist()
        reach = [self.runs.shape[0] - x0, *accumulate(runs, min)]
        self.reach[pos] = reach
        return reach

    def _unused(self, mask: int) -> _Unused:
        """What the search reads of the unused pieces whose bits are set in ``mask``."""
        free = [rec for rec in self.order if rec[3] & mask]
        sides = sorted({v for rec, s in zip(self.order, self.sides) if rec[3] & mask for v in s})
        first = second = _NEVER
        owner = 0
        for rec in free:
            if rec[2] < first:
                first, second, owner = rec[2], first, rec[3]
            elif rec[2] < second:
                second = rec[2]
        unused = self.unused_sets[mask] = (free, sides, first, second, owner, {})
        return unused

    def run(self, grid: int, left: int, unused_area: int, jokers_left: int, mask: int) -> bool:
        """Whether the cells still to do (``left`` of them, set in ``grid``) can be finished with
        the pieces whose bits are set in ``mask`` and ``jokers_left`` jokers."""
        self.nodes += 1
        if self.nodes > self.max_nodes:
            raise _OutOfBudget
        if left == 0:
            if self.use_all and unused_area:
                return False
            self.found.append(tuple(Slot(*s) for s in self.placed))
            return len(self.found) >= self.wanted
        if (unused_area < left and not jokers_left) or (self.use_all and unused_area > left):
            return False
        pos = (grid & -grid).bit_length() - 1
        here = grid >> pos
        run_y = (here ^ (here + 1)).bit_length() - 1  # the lowest 0 bit: the run along y
        reach = self.reach.get(pos) or self._reach(pos)
        # The pieces first (inlined: this runs at every node). What to try depends only on the
        # unused pieces, the free runs and whether jokers are left: computed once per key.
        key = (mask, reach[1], run_y, jokers_left > 0)
        choices = self.choices.get(key)
        if choices is None:
            unused = self.unused_sets.get(mask) or self._unused(mask)
            choices = self.choices[key] = self._choices(unused, reach[1], run_y, jokers_left > 0)
        x0, y0 = divmod(pos, self.stride)
        placed = self.placed
        for rec, (rotation, fx, fy, _, window) in choices:
            if fx > reach[fy]:
                continue  # a cell of the rectangle is not the region's
            placed.append((rec[0], rotation, x0, y0, fx, fy))
            if self.run(
                grid ^ (window << pos),
                left - fx * fy,
                unused_area - rec[1],
                jokers_left,
                mask ^ rec[3],
            ):
                return True
            placed.pop()
        if not jokers_left:
            return False
        unused = self.unused_sets.get(mask) or self._unused(mask)
        return self._jokers_at(
            grid, pos, reach, run_y, left, unused_area, jokers_left, mask, unused
        )

    def _choices(
        self, unused: _Unused, run_x: int, run_y: int, jokers: bool
    ) -> list[tuple[_Rec, _Orient]]:
        """The placements to try at a first empty cell, in order: all of :meth:`run`'s choice
        that does not depend on where the cell is, so one list serves every node with the same
        unused pieces and free runs (the search revisits them often)."""
        free, _, first, second, owner, _ = unused
        if jokers:
            # the gap may also be left for a joker
            first, second = min(first, self.joker_side), min(second, self.joker_side)
        # A piece that spans the whole free run in either direction first: it leaves the rest
        # as simple as it was (the tiling a guess is built on); within each group by rank in
        # the search order, rotation 0 before 1.
        spanning: list[tuple[_Rec, _Orient]] = []
        others: list[tuple[_Rec, _Orient]] = []
        for rec in free:
            for o in rec[4]:
                fx, fy = o[1], o[2]
                if fx <= run_x and fy <= run_y:
                    (spanning if fy == run_y or fx == run_x else others).append((rec, o))
        tried: set[int] = set()
        choices = []
        for rec, o in spanning + others:
            # one footprint once: pieces of the same footprint are interchangeable (the first
            # in order stands for all, whether or not it passes the gap test below)
            if o[3] in tried:
                continue
            tried.add(o[3])
            rest = run_y - o[2]
            # a gap left in the run must take the smallest side of the other pieces (or a joker)
            if rest and rest < (second if rec[3] == owner else first):
                continue
            choices.append((rec, o))
        return choices

    def _jokers_at(
        self,
        grid: int,
        pos: int,
        reach: list[int],
        run_y: int,
        left: int,
        unused_area: int,
        jokers_left: int,
        mask: int,
        unused: _Unused,
    ) -> bool:
        _, sides, bound, _, _, lengths = unused
        side = self.joker_side
        spare = left - unused_area  # what the jokers must fill when every piece is used
        # the gap test with every unused piece and the jokers after this one
        if jokers_left > 1:
            bound = min(bound, side)
        x0, y0 = divmod(pos, self.stride)
        fys = lengths.get(run_y)
        if fys is None:
            fys = lengths[run_y] = _joker_sides(run_y, sides, side)
        for fy in fys:
            rest = run_y - fy
            if rest and rest < bound:
                continue
            # the widest joker of this length whose cells are all free, then narrower ones
            fxs = lengths.get(reach[fy])
            if fxs is None:
                fxs = lengths[reach[fy]] = _joker_sides(reach[fy], sides, side)
            for fx in fxs:
                area = fx * fy
                if self.use_all and (area > spare or (jokers_left == 1 and area != spare)):
                    continue
                window = self.windows.get(fx * self.span + fy) or self._window(fx, fy)
                self.placed.append((JOKER, 0, x0, y0, fx, fy))
                if self.run(
                    grid ^ (window << pos), left - area, unused_area, jokers_left - 1, mask
                ):
                    return True
                self.placed.pop()
        return False


def exact_cover(
    region: np.ndarray,
    pieces: Sequence[Piece],
    max_nodes: int = 20_000,
    rules: CoverRules = CoverRules(),
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
        search.run(_bits(todo), area, total, rules.jokers, (1 << len(pieces)) - 1)
    except _OutOfBudget:
        if not search.found:
            return CoverResult(None, search.nodes, True)
    if not search.found:
        return CoverResult(None, search.nodes, False)
    best = max(search.found, key=_narrowest_joker)
    return CoverResult(best, search.nodes, False, tuple(search.found) if rules.jokers else ())


def _narrowest_joker(slots: tuple[Slot, ...]) -> int:
    """The narrowest side among a tiling's jokers (large when it has none); ``max`` keeps the
    first of equals, i.e. the search order."""
    return min((min(s.fx, s.fy) for s in slots if s.key == JOKER), default=1 << 30)
