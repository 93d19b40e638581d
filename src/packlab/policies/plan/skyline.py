"""Skyline exact cover: fill the container to one flat top with every remaining box (pure).

Where :mod:`.cover` tiles one flat region with boxes of one height, this search packs boxes of
any heights on a stepped surface (a *skyline*: the heightmap), which is what a perfect packing
that is not built in flat layers needs (the ``cut`` family, the field's CUT sets). It answers
one question: can these boxes fill the space between the heightmap and a flat top at
``ceiling_mm`` exactly, and in which order and poses?

Branching (complete, like :mod:`.cover`'s): the *first empty cell* is the lowest cell of the
heightmap, ties broken by lowest x, then lowest y. In every exact filling a box rests on that
cell's level with its minimum corner on that cell: the box over it rests at its height (nothing
lower is open), its footprint lies on cells of that level (a box rests flat), and no cell of
that level comes before it in the scan. So each node places one box, either yaw, with its
corner there; boxes of one size are interchangeable and tried once per node. The order the
boxes are placed in is a build order: every box rests on what was placed before it.

Pruning, each of which only removes nodes that cannot be completed:

* **ceiling**: a box's top may not pass ``ceiling_mm``, and the gap it leaves under the ceiling
  must be a sum of the heights of the boxes still unused (0 included): the column over its
  footprint can only be closed by boxes stacked on it;
* **runs**: the cells of the first empty cell's level that follow it along x (same y) up to a
  wall or a higher cell form a run that boxes resting at that level cover exactly, end to end;
  the same holds along y. So each run's length must be a sum of sides of distinct unused boxes
  (either yaw), checked with a bitset of reachable sums;
* **memo**: a surface and set of unused boxes found hopeless once is not searched again
  (a transposition table; many orders of the same boxes reach the same surface).

Branch order (a heuristic; it decides which filling is found first, not whether one is): a box
whose top meets the level of a neighbouring column first (a guillotine packing closes
sub-blocks to one plane), then boxes that end a run exactly, then larger footprints first.

A node budget bounds the work; running out answers "not found" (``exhausted``).
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

#: 4-connectivity: boxes join cells that share a side.
_FOUR = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True, slots=True)
class Block:
    """A box that may be used once: ``key`` is the caller's id (e.g. a shown index)."""

    key: int
    length: int  # cells along x at yaw 0
    width: int  # cells along y at yaw 0
    height_mm: int

    @property
    def size(self) -> tuple[int, int, int]:
        return (self.length, self.width, self.height_mm)


@dataclass(frozen=True, slots=True)
class Placed:
    """One box of a filling: its key, yaw (0/1), min corner in cells and the level it rests at."""

    key: int
    rotation: int
    x: int
    y: int
    z_mm: int
    fx: int  # footprint cells along x (after the yaw)
    fy: int
    height_mm: int

    @property
    def top_mm(self) -> int:
        return self.z_mm + self.height_mm


@dataclass(frozen=True, slots=True)
class SkylineResult:
    """A filling in build order (None when none was found), the nodes it took and whether the
    budget ran out before the search ended."""

    placements: tuple[Placed, ...] | None
    nodes: int
    exhausted: bool


def filling_ceiling(heightmap: np.ndarray, blocks: Sequence[Block]) -> int | None:
    """The flat top (mm) that the heightmap plus every block would make if they filled it
    exactly, or None when their volume does not make a whole-millimetre top at or above the
    heightmap's highest cell (then no exact filling exists)."""
    hm = np.asarray(heightmap, dtype=np.int64)
    volume = int(hm.sum()) + sum(b.length * b.width * b.height_mm for b in blocks)
    ceiling, rest = divmod(volume, hm.size)
    if rest or ceiling < int(hm.max()):
        return None
    return ceiling


def _reachable(values: Sequence[tuple[int, int]]) -> int:
    """Bitset of the sums of subsets of ``values``, each pair used at most once and then as
    either of its two numbers (a box's side along a run, in either yaw; or its height twice)."""
    reach = 1
    for a, b in values:
        reach |= (reach << a) | (reach << b)
    return reach


class _Search:
    def __init__(
        self,
        heightmap: np.ndarray,
        blocks: Sequence[Block],
        ceiling_mm: int,
        max_nodes: int,
        shuffle: random.Random | None = None,
        failed: set[tuple[bytes, tuple[int, ...]]] | None = None,
    ) -> None:
        self.shuffle = shuffle
        self.hm = np.array(heightmap, dtype=np.int32)
        self.nx, self.ny = self.hm.shape
        self.ceiling = ceiling_mm
        self.max_nodes = max_nodes
        self.nodes = 0
        # Interchangeable boxes share a type; the search counts them instead of listing them.
        sizes = sorted({b.size for b in blocks}, key=lambda s: (-s[0] * s[1], -s[2], s))
        self.types = sizes
        self.count = [sum(b.size == s for b in blocks) for s in sizes]
        self.keys: list[list[int]] = [[b.key for b in blocks if b.size == s] for s in sizes]
        # Volumes in cells x this unit (the heights' common divisor keeps the bitsets short).
        levels = [b.height_mm for b in blocks] + [ceiling_mm, *(int(v) for v in np.unique(self.hm))]
        self.z_unit = int(np.gcd.reduce(levels)) or 1
        # Surfaces proven hopeless (searched to the end); shared by the restarts of one filling.
        self.failed: set[tuple[bytes, tuple[int, ...]]] = set() if failed is None else failed
        self.path: list[tuple[int, int, int, int, int]] = []  # (type, yaw, x, y, z)

    def exhausted(self) -> bool:
        return self.nodes >= self.max_nodes

    def _closed_runs(self) -> set[int]:
        """Lengths of every run (along x and along y) of equal-height cells below the ceiling
        whose two ends are walls or higher cells: no neighbour can rise to join it, so boxes
        resting on it must cover it end to end."""
        lengths: set[int] = set()
        big = np.int32(np.iinfo(np.int32).max)
        for grid in (self.hm, self.hm.T):
            padded = np.full((grid.shape[0] + 2, grid.shape[1]), big, dtype=np.int32)
            padded[1:-1] = grid
            change = np.flatnonzero(np.diff(padded.T.ravel()) != 0)  # run ends, column-major
            # Walk every column's runs: starts after a change, ends at the next change.
            flat = padded.T.ravel()
            starts, ends = change[:-1] + 1, change[1:]
            ok = ends - starts + 1 > 0
            for a, b in zip(starts[ok], ends[ok]):
                z = flat[a]
                if z == big or z >= self.ceiling:
                    continue
                if flat[a - 1] > z and flat[b + 1] > z:
                    lengths.add(int(b - a + 1))
        return lengths

    def _unused(self) -> list[tuple[int, int, int]]:
        out = []
        for t, n in enumerate(self.count):
            out.extend([self.types[t]] * n)
        return out

    def solve(self) -> bool:
        if self.exhausted():
            return False
        if not any(self.count):
            return bool((self.hm == self.ceiling).all())
        key = (self.hm.tobytes(), tuple(self.count))
        if key in self.failed:
            return False
        self.nodes += 1
        moves = self._branch()
        if moves is None:
            self.failed.add(key)
            return False
        for t, yaw, x, y, fx, fy, z0, h in moves:
            self.count[t] -= 1
            saved = self.hm[x : x + fx, y : y + fy].copy()
            self.hm[x : x + fx, y : y + fy] = z0 + h
            self.path.append((t, yaw, x, y, z0))
            if self.solve():
                return True
            self.path.pop()
            self.hm[x : x + fx, y : y + fy] = saved
            self.count[t] += 1
            if self.exhausted():
                return False
        if not self.exhausted():
            self.failed.add(key)
        return False

    def _branch(self) -> list[tuple[int, int, int, int, int, int, int, int]] | None:
        """The moves of the most constrained corner of the lowest level, best first; None when
        a prune shows the node hopeless (a corner no box fits is one)."""
        hm = self.hm
        unused = self._unused()
        reach = _reachable([(s[0], s[1]) for s in unused])
        if any(not (reach >> n) & 1 for n in self._closed_runs()):
            return None
        heights = _reachable([(s[2], s[2]) for s in unused])
        if any(not (heights >> int(g)) & 1 for g in np.unique(self.ceiling - hm)):
            return None
        if not self._pockets_fillable(unused) or not self._low_gaps_coverable(unused):
            return None
        if not self._plateaus_tileable(unused):
            return None
        z0 = int(hm.min())
        level = hm == z0
        # Integral image of the level: a footprint lies on it iff its cell count is full.
        integral = np.zeros((self.nx + 1, self.ny + 1), dtype=np.int32)
        integral[1:, 1:] = level.cumsum(0).cumsum(1)
        padded = np.zeros((self.nx + 2, self.ny + 2), dtype=bool)
        padded[1:-1, 1:-1] = level
        best: list[tuple[int, int, int, int, int, int, int, int]] | None = None
        best_key: tuple[int, int] | None = None
        for sx in (1, -1):
            for sy in (1, -1):
                # Cells of the level whose neighbours against (sx, sy) are walls or higher:
                # the box over such a cell has its corner there and extends along (sx, sy).
                behind_x = padded[1 - sx : self.nx + 1 - sx, 1:-1]
                behind_y = padded[1:-1, 1 - sy : self.ny + 1 - sy]
                corners = np.argwhere(level & ~behind_x & ~behind_y)
                for cx, cy in corners:
                    moves = self._corner_moves(int(cx), int(cy), sx, sy, z0, integral)
                    rank = (len(moves), int(cx) * self.ny + int(cy))
                    if best_key is None or rank < best_key:
                        best, best_key = moves, rank
                        if not moves:
                            return None
        return best

    def _low_gaps_coverable(self, unused: list[tuple[int, int, int]]) -> bool:
        """The box resting on an open cell is at most as tall as the cell's gap to the ceiling,
        and boxes resting side by side cover disjoint cells: so for every gap g, the unused
        boxes no taller than g must have footprints of at least as many cells as there are open
        cells with a gap of g or less."""
        gaps = (self.ceiling - self.hm).ravel()
        gaps = np.sort(gaps[gaps > 0])
        if not len(gaps):
            return True
        by_height = sorted((s[2], s[0] * s[1]) for s in unused)
        heights = np.array([h for h, _ in by_height])
        areas = np.cumsum([a for _, a in by_height])
        volumes = np.cumsum([a * h for h, a in by_height])
        open_volume = np.cumsum(gaps)
        stack = _reachable([(h, h) for h, _ in by_height])
        for g in np.unique(gaps):
            cells = int(np.searchsorted(gaps, g, side="right"))
            k = int(np.searchsorted(heights, g, side="right"))
            if not k or int(areas[k - 1]) < cells or int(volumes[k - 1]) < open_volume[cells - 1]:
                return False
            # The box resting on a cell whose gap is g is g tall, or leaves a gap that other
            # boxes stacked on it can close: only such boxes can cover these cells.
            g = int(g)
            fits = sum(a for h, a in by_height if h == g or (h < g and (stack >> (g - h)) & 1))
            if fits < int(np.count_nonzero(gaps == g)):
                return False
        return True

    def _plateaus_tileable(self, unused: list[tuple[int, int, int]]) -> bool:
        """A plateau (cells of one level, 4-connected) whose every neighbour is higher or a wall
        can neither grow nor be spanned: boxes resting on it tile it exactly, so its area must
        be the footprint area of a subset of the unused boxes."""
        reach = _reachable([(s[0] * s[1], s[0] * s[1]) for s in unused])
        big = np.iinfo(np.int32).max
        padded = np.full((self.nx + 2, self.ny + 2), big, dtype=np.int64)
        padded[1:-1, 1:-1] = self.hm
        for z in np.unique(self.hm):
            if z >= self.ceiling:
                continue
            labels, n = ndimage.label(self.hm == z, structure=_FOUR)
            lower = np.zeros_like(self.hm, dtype=bool)
            for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                lower |= padded[1 + dx : self.nx + 1 + dx, 1 + dy : self.ny + 1 + dy] < z
            # Components touching a lower cell may still grow when it rises: skip those.
            open_labels = set(np.unique(labels[lower & (labels > 0)]))
            areas = np.bincount(labels.ravel(), minlength=n + 1)
            for k in range(1, n + 1):
                if k not in open_labels and not (reach >> int(areas[k])) & 1:
                    return False
        return True

    def _pockets_fillable(self, unused: list[tuple[int, int, int]]) -> bool:
        """Columns already at the ceiling split the open space into pockets no box spans; each
        pocket's volume must be the volume of a subset of the unused boxes."""
        open_cells = self.hm < self.ceiling
        labels, n = ndimage.label(open_cells, structure=_FOUR)
        if n < 2:
            return True
        unit = self.z_unit
        reach = _reachable([(v, v) for v in (s[0] * s[1] * s[2] // unit for s in unused)])
        gaps = (self.ceiling - self.hm) // unit
        volumes = ndimage.sum_labels(gaps, labels, index=np.arange(1, n + 1))
        return all((reach >> int(v)) & 1 for v in volumes)

    def _corner_moves(
        self, cx: int, cy: int, sx: int, sy: int, z0: int, integral: np.ndarray
    ) -> list[tuple[int, int, int, int, int, int, int, int]]:
        """(type, yaw, x, y, fx, fy, z0, height) of every box that fits over the corner."""
        hm = self.hm
        neighbours: set[int] = set()
        moves = []
        for t, (length, width, h) in enumerate(self.types):
            if not self.count[t] or z0 + h > self.ceiling:
                continue
            for yaw, (fx, fy) in enumerate(((length, width), (width, length))):
                if yaw and length == width:
                    continue
                x = cx if sx > 0 else cx - fx + 1
                y = cy if sy > 0 else cy - fy + 1
                if x < 0 or y < 0 or x + fx > self.nx or y + fy > self.ny:
                    continue
                full = (
                    integral[x + fx, y + fy]
                    - integral[x, y + fy]
                    - integral[x + fx, y]
                    + integral[x, y]
                )
                if full != fx * fy:
                    continue
                if not neighbours:
                    ring = []
                    for nx_, ny_ in ((cx - sx, cy), (cx, cy - sy)):
                        if 0 <= nx_ < self.nx and 0 <= ny_ < self.ny:
                            ring.append(int(hm[nx_, ny_]))
                    neighbours = set(ring) | {self.ceiling}
                meets = (z0 + h) in neighbours
                noise = self.shuffle.random() if self.shuffle is not None else 0.0
                order = (not meets, noise, -fx * fy, -h, t, yaw)
                moves.append((order, (t, yaw, x, y, fx, fy, z0, h)))
        moves.sort(key=lambda m: m[0])
        return [m[1] for m in moves]


#: Nodes of the first attempt; each restart may spend twice the one before.
FIRST_ATTEMPT_NODES = 250


def skyline_fill(
    heightmap: np.ndarray,
    blocks: Sequence[Block],
    ceiling_mm: int,
    max_nodes: int = 200_000,
) -> SkylineResult:
    """Place every block so the heightmap becomes flat at ``ceiling_mm`` with no gap (module
    docstring), or say that none was found within ``max_nodes`` nodes. The heightmap's cells
    must sit on the millimetre levels the blocks make (exact observations; a noisy heightmap
    has no exact filling).

    Restarts: how long a depth-first search takes depends on its first choices far more than
    on the problem (one order of the same boxes needed 10 nodes, another 5,566), so the budget
    is spent on attempts of growing size (250, 500, 1000, ... nodes), the first in the heuristic
    order and each later one with ties within the heuristic's first key broken at random (a
    generator seeded by the attempt's number: the same call gives the same answer). Surfaces an
    attempt proved hopeless stay proved for the next."""
    failed: set[tuple[bytes, tuple[int, ...]]] = set()
    spent, attempt = 0, 0
    while spent < max_nodes:
        budget = min(FIRST_ATTEMPT_NODES << attempt, max_nodes - spent)
        shuffle = random.Random(attempt) if attempt else None
        search = _Search(heightmap, blocks, ceiling_mm, budget, shuffle, failed)
        found = search.solve()
        spent += search.nodes
        if found:
            return SkylineResult(_placements(search), spent, False)
        if not search.exhausted():  # searched to the end: there is no filling
            return SkylineResult(None, spent, False)
        attempt += 1
    return SkylineResult(None, spent, True)


def _placements(search: _Search) -> tuple[Placed, ...]:
    used: list[list[int]] = [list(keys) for keys in search.keys]
    placements = []
    for t, yaw, x, y, z in search.path:
        length, width, h = search.types[t]
        fx, fy = (length, width) if yaw == 0 else (width, length)
        placements.append(Placed(used[t].pop(0), yaw, x, y, z, fx, fy, h))
    return tuple(placements)
