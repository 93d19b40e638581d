"""The planner's own past placements, read back into the heightmap it completes (pure).

A heightmap takes each cell's height at its centre. A box that is shorter than the cells its
footprint covers (a carton a few mm short of the 25 mm grid) covers its last cell's centre by
as little as half a millimetre, so a few mm of the arm's error, a degree of yaw at a long box's
far corner, or a seat push that closes the gap to a shorter neighbour leaves one cell of floor
showing at the box's edge or corner. No box fits in such a strip, and an exact cover of the
level (:mod:`.complete`) must cover every cell, so one such cell blocks every tiling of its
level.

The planner knows where it put each box: the footprint it chose (the shown size's cells at the
action's corner), resting at the Eq. 2 height it saw before the action, up to that plus the
shown height. Where the heightmap still shows the box there (every cell inside its footprint,
the border ring left out, at least at that top, within the level tolerance) and cells of the
ring read lower, those ring cells are read as the box's top: the box is there, and what is
left of the cell beside it is less than a box side. A box that moved, fell or was set aside
fails the check and is read as the heightmap shows it.
"""

from __future__ import annotations

import numpy as np

from packlab.core.feasibility import footprint_cells, footprint_fits, placement_height
from packlab.core.types import Action, Observation
from packlab.policies.features import LEVEL_TOLERANCE_MM


def with_own_placements(
    observation: Observation, tolerance_mm: int = LEVEL_TOLERANCE_MM
) -> np.ndarray:
    """The observation's heightmap with each past placement's border cells read as its top
    where the rest of its footprint shows it there (module docstring); the heightmap itself
    when nothing changes."""
    hm = observation.heightmap
    out: np.ndarray | None = None
    for entry in observation.history:
        action = entry.action
        if not isinstance(action, Action) or action.sets_aside or not entry.valid:
            continue
        if not 0 <= action.object_id < len(entry.shown):
            continue
        item = entry.shown[action.object_id]
        fx, fy = footprint_cells(item, action.rotation)
        x, y = action.x, action.y
        # A footprint under 3 cells across has no inside to show the box by.
        if fx < 3 or fy < 3 or not footprint_fits(hm.shape, x, y, fx, fy):
            continue
        top = placement_height(entry.heightmap, x, y, fx, fy) + int(item.size_mm[2])
        current = hm if out is None else out
        window = current[x : x + fx, y : y + fy]
        inside = window[1:-1, 1:-1]
        if not (inside >= top - tolerance_mm).all():
            continue  # the box is not (all) where it was put
        low = window < top - tolerance_mm  # border cells only: the inside passed above
        if not low.any():
            continue
        if out is None:
            out = hm.copy()
        patch = out[x : x + fx, y : y + fy]
        patch[low] = top
    return hm if out is None else out
