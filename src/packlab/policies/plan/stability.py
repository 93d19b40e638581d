"""A cheap static-stability test of one placement: is the box's centre over its support?

A box dropped at Eq. 2's height ``z`` rests on the cells under its footprint whose top is the
same level as ``z`` (the highest ones, :func:`packlab.policies.features.same_level`; every other
cell leaves a gap). Treated as a rigid body on rigid
supports, it stays put when the vertical line through its centre of mass (the footprint's centre,
boxes being uniform) passes through the convex hull of those contact cells, and tips over an
edge of that hull otherwise. On the floor (``z == 0``) every cell is contact.

This is the support-polygon test the planner's ``stability=support`` option applies before
committing a placement; it ignores friction and what the box leans against (walls and taller
neighbours can hold an overhanging box up), so it can refuse a placement mujoco would keep, never
the other way round for a box standing on its own.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from packlab.policies.features import same_level


def contact_cells(heightmap: np.ndarray, x: int, y: int, fx: int, fy: int, z: int) -> np.ndarray:
    """(n, 2) cell coordinates (relative to the footprint's corner) that carry the box."""
    under = np.asarray(heightmap)[x : x + fx, y : y + fy]
    return np.argwhere(same_level(under, z))


def centre_supported(heightmap: np.ndarray, x: int, y: int, fx: int, fy: int, z: int) -> bool:
    """Whether a box resting at ``z`` on footprint (x, y, fx, fy) has its centre over the convex
    hull of its contact cells (each cell a unit square), i.e. will not tip on its own."""
    if z <= 0:
        return True
    cells = contact_cells(heightmap, x, y, fx, fy, z)
    if cells.size == 0:
        return False
    corners = (cells[:, None, :] + np.array([[0, 0], [1, 0], [0, 1], [1, 1]])[None]).reshape(-1, 2)
    centre = np.array([fx / 2.0, fy / 2.0])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    if np.any(centre < lo) or np.any(centre > hi):
        return False
    try:
        hull = ConvexHull(corners.astype(float))
    except QhullError:  # collinear corners cannot happen for unit squares; be safe
        return False
    # Qhull's facets are a . p + b <= 0 inside; a small slack keeps centres on an edge stable.
    return bool(np.all(hull.equations[:, :2] @ centre + hull.equations[:, 2] <= 1e-9))
