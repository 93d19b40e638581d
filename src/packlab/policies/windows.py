"""Pure grid helpers over (fx, fy) footprint windows, vectorised over every minimum cell.

Each function returns an array indexed like :func:`packlab.core.feasibility.footprint_max`:
entry [x, y] belongs to the footprint whose minimum cell is (x, y), shape (X - fx + 1, Y - fy + 1).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import as_strided


def sliding(a: np.ndarray, n: int, axis: int) -> np.ndarray:
    """Read-only view of every length-``n`` window of 2-D ``a`` along ``axis``, as a last axis.

    Same result as ``numpy.lib.stride_tricks.sliding_window_view(a, n, axis=axis)``, without its
    argument checking, which costs more than the arithmetic on these small grids (a decision
    makes a few hundred such views).
    """
    shape = list(a.shape)
    shape[axis] -= n - 1
    return as_strided(a, (*shape, n), (*a.strides, a.strides[axis]), writeable=False)


def window_sum(grid: np.ndarray, fx: int, fy: int) -> np.ndarray:
    """Sum of ``grid`` over every (fx, fy) window, int64, via one summed-area table."""
    nx, ny = grid.shape
    sat = np.zeros((nx + 1, ny + 1), dtype=np.int64)
    np.cumsum(np.cumsum(grid, axis=0, dtype=np.int64), axis=1, out=sat[1:, 1:])
    return sat[fx:, fy:] - sat[:-fx, fy:] - sat[fx:, :-fy] + sat[:-fx, :-fy]


def window_count_of_max(grid: np.ndarray, fx: int, fy: int) -> tuple[np.ndarray, np.ndarray]:
    """(max, number of cells equal to the max) over every (fx, fy) window.

    Separable like the window max itself: a first pass along x keeps, per column strip, its max
    and how many cells reach it; along y, only strips whose max equals the window max contribute
    their counts (a strip with a lower max has no cell at the window max). Cost O(cells*(fx+fy))
    instead of O(cells*fx*fy).
    """
    strips = sliding(grid, fx, 0)  # (X', Y, fx)
    strip_max = strips.max(axis=-1)
    strip_count = (strips == strip_max[..., None]).sum(axis=-1)
    max_win = sliding(strip_max, fy, 1)  # (X', Y', fy)
    count_win = sliding(strip_count, fy, 1)
    wmax = max_win.max(axis=-1)
    count = np.where(max_win == wmax[..., None], count_win, 0).sum(axis=-1)
    return wmax, count


def padded(grid: np.ndarray, wall: int) -> np.ndarray:
    """``grid`` inside a one-cell border of value ``wall`` (the container walls), int64."""
    return np.pad(np.asarray(grid, dtype=np.int64), 1, constant_values=wall)


def side_neighbours(walled: np.ndarray, fx: int, fy: int) -> tuple[np.ndarray, np.ndarray]:
    """Heights of the columns across each side face of every footprint window.

    ``walled`` is :func:`padded` (X + 2, Y + 2). Returns read-only views ``x_faces``
    (2, X', Y', fy): [0] the fy cells beside the face at -x, [1] those at +x; and ``y_faces``
    (2, X', Y', fx) for -y and +y. A face on the container boundary sees the wall value.
    Opposite faces are one view with a leading axis of two (a stride of the footprint plus
    one cell), so each pair costs one pass of arithmetic.
    """
    nx, ny = walled.shape[0] - 2, walled.shape[1] - 2
    px, py = nx - fx + 1, ny - fy + 1
    # walled[i + 1, j + 1] is cell (i, j): the column left of x is walled row x, the one right
    # of x + fx - 1 is row x + fx + 1.
    along_y = sliding(walled[:, 1:-1], fy, 1)  # (X + 2, Y', fy)
    along_x = sliding(walled[1:-1, :], fx, 0)  # (X', Y + 2, fx)
    sy0 = along_y.strides[0]
    x_faces = as_strided(
        along_y, (2, px, py, fy), (sy0 * (fx + 1), *along_y.strides), writeable=False
    )
    sx1 = along_x.strides[1]
    y_faces = as_strided(
        along_x, (2, px, py, fx), (sx1 * (fy + 1), *along_x.strides), writeable=False
    )
    return x_faces, y_faces


def ring4(mask: np.ndarray) -> np.ndarray:
    """The cells outside ``mask`` with a 4-neighbour inside it (``binary_dilation`` with the
    cross structure, less ``mask``), clipped to the grid. Shifted ORs instead of scipy's
    dilation, which cost the planner and the level-fit features more than their own search."""
    grown = mask.copy()
    grown[1:, :] |= mask[:-1, :]
    grown[:-1, :] |= mask[1:, :]
    grown[:, 1:] |= mask[:, :-1]
    grown[:, :-1] |= mask[:, 1:]
    return grown & ~mask
