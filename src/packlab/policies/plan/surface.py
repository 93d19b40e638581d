"""Pure measures of a top surface (heightmap) that a planner's state evaluation adds up.

All volumes are in cell-millimetres (mm x cells); multiply by ``cell_mm ** 2`` for mm^3. Every
function is vectorised over the grid; none loops over cells.
"""

from __future__ import annotations

import numpy as np

from packlab.core.feasibility import footprint_max
from packlab.policies.windows import sliding

#: A height larger than any container: pads the window grids so that border cells take their
#: minimum over the windows that exist only.
_FAR = np.int64(1 << 40)


def reachable_floor(heightmap: np.ndarray, fx: int, fy: int) -> np.ndarray:
    """(X, Y): the lowest height a box of footprint (fx, fy) can rest at over each cell.

    A morphological closing: the window max (Eq. 2 for every placement) followed by the min over
    the windows that cover each cell. Where it exceeds the heightmap, the cell lies in a pit too
    narrow for the footprint: no box of that size can ever fill it from above.
    """
    hm = np.asarray(heightmap, dtype=np.int64)
    nx, ny = hm.shape
    if fx > nx or fy > ny:
        return np.full_like(hm, _FAR)
    z = footprint_max(hm, fx, fy)
    padded = np.pad(z, ((fx - 1, fx - 1), (fy - 1, fy - 1)), constant_values=_FAR)
    return sliding(sliding(padded, fx, 0).min(axis=-1), fy, 1).min(axis=-1)


def unreachable_volume(heightmap: np.ndarray, footprints: tuple[tuple[int, int], ...]) -> int:
    """Volume (cell-mm) of the pits that none of ``footprints`` can reach, up to the level the
    narrowest-fitting of them would bridge at (capped at the highest column)."""
    hm = np.asarray(heightmap, dtype=np.int64)
    best = np.full_like(hm, _FAR)
    for fx, fy in footprints:
        np.minimum(best, reachable_floor(hm, fx, fy), out=best)
    np.minimum(best, hm.max(), out=best)
    return int((best - hm).clip(min=0).sum())


def open_volume(heightmap: np.ndarray) -> int:
    """Volume (cell-mm) between the surface and its highest column: what compactness loses if
    nothing else came."""
    hm = np.asarray(heightmap, dtype=np.int64)
    return int(hm.size * hm.max() - hm.sum())


def water_level(heightmap: np.ndarray, volume: float) -> float:
    """The level (mm) that ``volume`` cell-mm reaches poured over the surface: the lowest cells
    fill first, as boxes settling on the lowest free places would."""
    order = np.sort(np.asarray(heightmap, dtype=np.int64).ravel())
    if volume <= 0:
        return float(order[0])
    # Volume needed to raise the k lowest cells to the (k+1)-th lowest, k = 1 .. n-1.
    to_next = np.arange(1, order.size) * order[1:] - np.cumsum(order)[:-1]
    under = int(np.searchsorted(to_next, volume)) + 1  # cells under water
    return (volume + float(order[:under].sum())) / under


def step_area(heightmap: np.ndarray) -> int:
    """Area (cell-mm) of the vertical faces between neighbouring columns: a level surface has
    none, a ragged one offers few flush placements."""
    hm = np.asarray(heightmap, dtype=np.int64)
    return int(np.abs(np.diff(hm, axis=0)).sum() + np.abs(np.diff(hm, axis=1)).sum())
