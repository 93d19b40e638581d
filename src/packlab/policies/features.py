"""Placement features: the one implementation of what a placement's geometry offers.

A placement puts a box of footprint ``fx`` x ``fy`` cells (minimum cell ``(x, y)``) at its
resting height ``z``, paper Eq. 2 (the maximum of the heightmap over the footprint). Read from
the heightmap alone, with every column taken as solid from the floor to its height:

- **space under** (cell-mm): the empty volume between the heightmap and the box's underside,
  ``sum over the footprint of (z - hm[c])``; multiply by ``cell_mm ** 2`` for mm^3, divide by
  ``fx * fy`` for the mean gap in mm. What the planner's cost calls "trapped".
- **support** (cells): the footprint cells whose top is the same level as ``z``
  (:func:`same_level`, within :data:`LEVEL_TOLERANCE_MM`), the ones the box rests on. The
  proposer and the listed lines' features use that default; MTA asks for exact equality
  (``tolerance_mm=0``), its published rule. On the empty floor (``z = 0``) every cell counts.
- **flushness** (cells): the side cells, one per cell edge of the footprint's boundary
  (``2 * (fx + fy)`` of them, :func:`side_cells`), whose column across the edge stands above
  ``z`` and is not the same level (:func:`above_level`); a wall counts as a column at the rim's
  height (the heightmap inside a ring of walls, :func:`walled`). A neighbour level with ``z``
  touches nothing of the box.

"The same level" is one definition for the whole planner side (:mod:`packlab.core.levels`,
re-exported here): heights within :data:`LEVEL_TOLERANCE_MM` (4 mm) of each other. Box heights
are whole centimetres, so on an exact heightmap it changes nothing against exact equality; on a
perceived one it absorbs the per-top error that survives ``flatten_tops``.
- **contact area** (mm^2, MTA's measure): support cells times ``cell_mm ** 2``, plus for each
  side cell the z-overlap ``max(0, min(top, H) - z)`` of the box's face ``[z, top)`` with the
  column of height ``H`` across it, times ``cell_mm``. Diagonal neighbours touch only along a
  line and count nothing.

Each measure comes in the forms its callers need:

- ``*_grid``: one orientation at every minimum cell at once, an array shaped like
  :func:`packlab.core.feasibility.footprint_max` (a :class:`~packlab.core.feasibility.Orientation`
  group's ``z``); vectorised over cells, O(cells * (fx + fy)) or one summed-area table;
- the plain names: every candidate of a :class:`~packlab.core.feasibility.CandidateSet`, (n,)
  in scan order (footprint shapes shared by several groups are computed once);
- ``*_at``: one placement, for callers that look at a few listed placements only.

All functions are pure; ``z`` must be the Eq. 2 height of the footprint (the candidate search's
``z``), which every caller passes.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from packlab.core.feasibility import CandidateSet, Orientation, footprint_max
from packlab.core.levels import (
    FACE_RISE_MM,
    LEVEL_TOLERANCE_MM,
    above_level,
    at_or_below,
    same_level,
)
from packlab.policies.windows import padded, side_neighbours, window_count_of_max, window_sum

__all__ = [
    "FACE_RISE_MM",
    "LEVEL_TOLERANCE_MM",
    "above_level",
    "at_or_below",
    "contact_area_mm2",
    "contact_grid",
    "flush_cells",
    "flush_cells_at",
    "flush_grid",
    "flush_share",
    "same_level",
    "side_cells",
    "space_under",
    "space_under_at",
    "space_under_grid",
    "support_cells",
    "support_cells_at",
    "support_grid",
    "support_share",
    "walled",
]


# -- shared pieces ----------------------------------------------------------------------------


def walled(heightmap: np.ndarray, container_height_mm: int) -> np.ndarray:
    """(X + 2, Y + 2) int64: ``heightmap`` inside a one-cell ring of walls at the rim's height.

    Cell (i, j) of the heightmap is entry [i + 1, j + 1]. Flushness and contact read a
    footprint's side columns from it; make it once per state and pass it to many placements.
    """
    return padded(heightmap, container_height_mm)


def side_cells(fx: int, fy: int) -> int:
    """Number of side cells (cell edges of the footprint's boundary): ``2 * (fx + fy)``."""
    return 2 * (fx + fy)


def _per_group(
    cands: CandidateSet, key: Callable[[Orientation], Hashable], grid: Callable[..., np.ndarray]
) -> np.ndarray:
    """(n,) int64 from ``grid(group)`` per group, computed once per ``key(group)``."""
    out = np.empty(len(cands), dtype=np.int64)
    done: dict[Hashable, np.ndarray] = {}
    for g in cands.groups:
        k = key(g)
        if k not in done:
            done[k] = grid(g)
        out[g.offset : g.offset + g.size] = done[k].ravel()
    return out


def _footprint(g: Orientation) -> tuple[int, int]:
    # Groups of one footprint share one Eq. 2 grid (the candidate search computes it once).
    return (g.fx, g.fy)


# -- space under --------------------------------------------------------------------------------


def space_under_grid(heightmap: np.ndarray, fx: int, fy: int, z: np.ndarray) -> np.ndarray:
    """(X', Y') int64 cell-mm: empty space under an (fx, fy) box resting at ``z`` (X', Y')."""
    return fx * fy * np.asarray(z, dtype=np.int64) - window_sum(heightmap, fx, fy)


def space_under(cands: CandidateSet) -> np.ndarray:
    """(n,) int64 cell-mm: empty space between the heightmap and each candidate's underside."""
    hm = cands.heightmap
    return _per_group(cands, _footprint, lambda g: space_under_grid(hm, g.fx, g.fy, g.z))


def space_under_at(heightmap: np.ndarray, x: int, y: int, fx: int, fy: int, z: int) -> int:
    """Empty space (cell-mm) under one box of footprint (x, y, fx, fy) resting at ``z``."""
    under = np.asarray(heightmap)[x : x + fx, y : y + fy]
    return fx * fy * int(z) - int(under.sum(dtype=np.int64))


# -- support ------------------------------------------------------------------------------------


def _has_near_levels(heightmap: np.ndarray, tolerance_mm: int) -> bool:
    """Whether two different heights of the map are within ``tolerance_mm`` of each other: only
    then can the tolerance count a cell that exact equality would not."""
    values = np.unique(heightmap)
    return bool(values.size > 1 and np.diff(values.astype(np.int64)).min() <= tolerance_mm)


def support_grid(
    heightmap: np.ndarray, fx: int, fy: int, tolerance_mm: int = LEVEL_TOLERANCE_MM
) -> np.ndarray:
    """(X', Y') int64: footprint cells the same level as the Eq. 2 height, per window.

    When no two different heights of the map are within ``tolerance_mm`` (every exact
    heightmap, box heights being whole centimetres) that is a separable count of the cells
    reaching the window max (:func:`~packlab.policies.windows.window_count_of_max`), about half
    the cost of the general window count.
    """
    hm = np.asarray(heightmap)
    if tolerance_mm == 0 or not _has_near_levels(hm, tolerance_mm):
        return window_count_of_max(hm, fx, fy)[1].astype(np.int64, copy=False)
    if not np.issubdtype(hm.dtype, np.signedinteger):
        hm = hm.astype(np.int64)  # whole mm as same_level reads them; z - tolerance cannot wrap
    windows = sliding_window_view(hm, (fx, fy))  # (X', Y', fx, fy)
    z = footprint_max(hm, fx, fy)  # the windows' max, separably
    # Every cell of a window is <= its max, so "same level as z" (same_level) is "at least
    # z - tolerance": one comparison per cell in the map's own dtype (about twice as fast as
    # taking int64 differences of every window).
    floor = (z - tolerance_mm)[..., None, None]
    return np.count_nonzero(windows >= floor, axis=(-2, -1)).astype(np.int64, copy=False)


def support_cells(cands: CandidateSet, tolerance_mm: int = LEVEL_TOLERANCE_MM) -> np.ndarray:
    """(n,) int64: footprint cells each candidate rests on (the same level as its z)."""
    hm = cands.heightmap
    return _per_group(cands, _footprint, lambda g: support_grid(hm, g.fx, g.fy, tolerance_mm))


def support_share(cands: CandidateSet, tolerance_mm: int = LEVEL_TOLERANCE_MM) -> np.ndarray:
    """(n,) float64 in [0, 1]: :func:`support_cells` over the footprint's cell count."""
    return support_cells(cands, tolerance_mm) / (cands.fx * cands.fy)


def support_cells_at(
    heightmap: np.ndarray,
    x: int,
    y: int,
    fx: int,
    fy: int,
    z: int,
    tolerance_mm: int = LEVEL_TOLERANCE_MM,
) -> int:
    """Footprint cells of one box resting at ``z`` whose top is the same level as ``z``."""
    under = np.asarray(heightmap)[x : x + fx, y : y + fy]
    return int(np.count_nonzero(same_level(under, z, tolerance_mm)))


# -- flushness ----------------------------------------------------------------------------------


def flush_grid(
    walls: np.ndarray, fx: int, fy: int, z: np.ndarray, origin: tuple[int, int] = (0, 0)
) -> np.ndarray:
    """(X', Y') int64: side cells whose column (or wall) stands above ``z``'s level.

    ``walls`` is :func:`walled` (the heightmap inside a ring of walls at the rim's height).
    ``z`` holds the resting heights of a rectangle of minimum cells whose first is ``origin``
    (the whole group's grid by default; a caller that needs only some positions passes their
    bounding rectangle and pays for it alone).

    Two exact ways, chosen by cost alone: one pass per side cell (cost grows with the footprint's
    perimeter), or one pass per distinct height in ``z`` that counts each face by running sums
    (cost grows with the number of heights; a floor's positions mostly share one).
    """
    z = np.asarray(z)
    x0, y0 = origin
    # Measured on 56 x 57 maps: a height costs about as much as 8 cells of fx + fy.
    heights = np.unique(z)
    if heights.size * 8 < fx + fy:
        return _flush_by_height(walls, fx, fy, z, x0, y0, heights)
    return _flush_by_side_cell(walls, fx, fy, z, x0, y0)


def _flush_by_side_cell(
    walls: np.ndarray, fx: int, fy: int, z: np.ndarray, x0: int, y0: int
) -> np.ndarray:
    """:func:`flush_grid` by one shifted slice per side cell, compared with the limits."""
    px, py = z.shape
    # walls[i + 1, j + 1] is cell (i, j): the column left of x is walls row x, the one right of
    # x + fx - 1 is row x + fx + 1 (likewise along y).
    limit = z.astype(walls.dtype) + LEVEL_TOLERANCE_MM  # above_level: > level + tolerance
    count = np.zeros((px, py), dtype=np.int16)  # at most 2 * (fx + fy) per cell
    above = np.empty((px, py), dtype=bool)
    for row in (x0, x0 + fx + 1):  # the faces at -x and +x, fy cells each
        for col in range(y0 + 1, y0 + 1 + fy):
            np.greater(walls[row : row + px, col : col + py], limit, out=above)
            count += above
    for col in (y0, y0 + fy + 1):  # the faces at -y and +y, fx cells each
        for row in range(x0 + 1, x0 + 1 + fx):
            np.greater(walls[row : row + px, col : col + py], limit, out=above)
            count += above
    return count.astype(np.int64)


def _flush_by_height(
    walls: np.ndarray, fx: int, fy: int, z: np.ndarray, x0: int, y0: int, heights: np.ndarray
) -> np.ndarray:
    """:func:`flush_grid` by one pass per distinct height: the columns above that level, their
    running sums along x and y, and each face's count as a difference of two sums."""
    px, py = z.shape
    # The part of walls any face of the rectangle reads.
    part = walls[x0 : x0 + px + fx + 1, y0 : y0 + py + fy + 1]
    count = np.zeros((px, py), dtype=np.int64)
    along_y = np.zeros((part.shape[0], part.shape[1] + 1), dtype=np.int32)
    along_x = np.zeros((part.shape[0] + 1, part.shape[1]), dtype=np.int32)
    for level in heights:
        above = part > int(level) + LEVEL_TOLERANCE_MM  # above_level
        np.cumsum(above, axis=1, out=along_y[:, 1:])
        np.cumsum(above, axis=0, out=along_x[1:])
        run_y = along_y[:, fy:] - along_y[:, :-fy]  # [r, c]: above[r, c : c + fy]
        run_x = along_x[fx:] - along_x[:-fx]  # [r, c]: above[r : r + fx, c]
        faces = (
            run_y[:px, 1 : 1 + py]  # -x: row x, cells y .. y + fy - 1
            + run_y[fx + 1 : fx + 1 + px, 1 : 1 + py]  # +x
            + run_x[1 : 1 + px, :py]  # -y
            + run_x[1 : 1 + px, fy + 1 : fy + 1 + py]  # +y
        )
        np.copyto(count, faces, where=z == level)
    return count


def flush_cells(cands: CandidateSet, walls: np.ndarray | None = None) -> np.ndarray:
    """(n,) int64: each candidate's side cells against a wall or a column above its z's level.

    ``walls`` (:func:`walled`) is made from the candidate set when not given.
    """
    w = walled(cands.heightmap, cands.container_height_mm) if walls is None else walls
    return _per_group(cands, _footprint, lambda g: flush_grid(w, g.fx, g.fy, g.z))


def flush_share(cands: CandidateSet, walls: np.ndarray | None = None) -> np.ndarray:
    """(n,) float64 in [0, 1]: :func:`flush_cells` over :func:`side_cells`."""
    return flush_cells(cands, walls) / (2 * (cands.fx + cands.fy))


def flush_cells_at(walls: np.ndarray, x: int, y: int, fx: int, fy: int, z: int) -> int:
    """Side cells of one box resting at ``z`` against a wall or a column above ``z``'s level.

    ``walls`` is :func:`walled`: cell (i, j) is entry [i + 1, j + 1].
    """
    sides = np.concatenate(
        [
            walls[x, y + 1 : y + fy + 1],  # -x
            walls[x + fx + 1, y + 1 : y + fy + 1],  # +x
            walls[x + 1 : x + fx + 1, y],  # -y
            walls[x + 1 : x + fx + 1, y + fy + 1],  # +y
        ]
    )
    return int(np.count_nonzero(above_level(sides, z)))


# -- contact area -------------------------------------------------------------------------------


def _faces_overlap_mm(neighbours: np.ndarray, z: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Sum over two opposite faces' cells of the z-overlap (mm) of [z, top] with columns [0, H].

    ``neighbours`` is (2, X', Y', f) from :func:`side_neighbours`; ``z``, ``top`` are (X', Y').
    """
    # min(max(H, z), top) - z == max(0, min(top, H) - z) since top > z; two ufuncs with an
    # output buffer are cheaper than np.clip with broadcast bounds.
    clipped = np.maximum(neighbours, z[..., None])
    np.minimum(clipped, top[..., None], out=clipped)
    cells = neighbours.shape[0] * neighbours.shape[-1]
    return clipped.sum(axis=(0, -1), dtype=np.int64) - cells * z


def contact_grid(
    support: np.ndarray,
    walls: np.ndarray,
    fx: int,
    fy: int,
    z: np.ndarray,
    height_mm: int,
    cell_mm: int,
) -> np.ndarray:
    """(X', Y') int64 mm^2: contact area of an (fx, fy, height_mm) box resting at ``z``.

    ``support`` is :func:`support_grid` of the footprint, ``walls`` :func:`walled`
    (int32 keeps the side arithmetic in half the memory traffic; the result is the same).
    """
    z = np.asarray(z).astype(walls.dtype, copy=False)
    top = z + walls.dtype.type(height_mm)
    x_faces, y_faces = side_neighbours(walls, fx, fy)
    side_mm = _faces_overlap_mm(x_faces, z, top) + _faces_overlap_mm(y_faces, z, top)
    return support * (cell_mm * cell_mm) + side_mm * cell_mm


def contact_area_mm2(cands: CandidateSet, tolerance_mm: int = LEVEL_TOLERANCE_MM) -> np.ndarray:
    """(n,) int64 mm^2: contact area of each candidate with floor, walls and boxes (support
    counted within ``tolerance_mm``)."""
    hm = cands.heightmap.astype(np.int32, copy=False)
    walls = walled(hm, cands.container_height_mm).astype(np.int32)
    support: dict[tuple[int, int], np.ndarray] = {}

    def grid(g: Orientation) -> np.ndarray:
        if (g.fx, g.fy) not in support:
            support[(g.fx, g.fy)] = support_grid(hm, g.fx, g.fy, tolerance_mm)
        return contact_grid(
            support[(g.fx, g.fy)], walls, g.fx, g.fy, g.z, g.height_mm, cands.cell_mm
        )

    # Equal boxes and square footprints repeat an orientation: each shape is computed once.
    return _per_group(cands, lambda g: (g.fx, g.fy, g.height_mm), grid)
