"""Level-fit features: how a placement leaves the level it rests on for the other shown boxes.

A perfect packing closes each level without waste, so whether a placement is good depends less
on the box itself than on what it leaves beside it: the strips of free floor at the box's
resting level ``z`` on each side, and whether the other shown boxes of the same height can fill
them. These are the facts the planner's exact-cover search weighs (:mod:`.plan.complete`); here
they are read off one placement in closed form, cheaply enough for every listed line, so a
learned policy can be shown them next to the placement's own geometry
(:mod:`packlab.policies.features`). They read only the heightmap and the shown boxes, what a
robot observes.

For a placement (footprint ``fx`` x ``fy`` at minimum cell ``(x, y)``, resting at ``z``) the
*level* is the set of cells whose top is the same level as ``z`` or below it
(:func:`packlab.policies.features.at_or_below`, the planner's one "same level" tolerance), less
the footprint. Features (:data:`FEATURE_NAMES`, all floats, scaled to about [0, 1]):

- ``run_*``: free cells in a straight line from the box's side outward on the level, along +x
  from its two x-far corners, along +y from its two y-far corners, and along -x and -y from its
  minimum corner (a run of 0: the box is flush there), in cells / :data:`RUN_SCALE`;
- ``fits_*``: for the four far runs, 1 when the run is 0 or equals a side, or a sum of two
  sides, of the other shown boxes of the same height (so the strip can be closed exactly);
- ``region``: the free area of the level connected to the box, as a share of the floor;
- ``same_area``: the other same-height shown boxes' footprint area over that region (capped at
  :data:`AREA_CAP`);
- ``closes``: 1 when that region is empty or some subset of the other same-height boxes has
  exactly its area (a necessary condition for an exact tiling by them);
- ``level_with``: the share of the box's ring of neighbour cells whose top is the same level as
  the box's top (the placement ends level with its surroundings);
- ``same_count``: other shown boxes of the same height / :data:`COUNT_SCALE`;
- ``lowest``: 1 when the box rests on the lowest level of the container.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from packlab.core.types import ShownItem
from packlab.policies.candidates import Candidate
from packlab.policies.features import at_or_below, same_level
from packlab.policies.windows import ring4

RUN_SCALE = 32.0
AREA_CAP = 3.0
COUNT_SCALE = 10.0

_FOUR = ndimage.generate_binary_structure(2, 1)

FEATURE_NAMES = (
    "run_x_near", "run_x_far", "run_y_near", "run_y_far", "run_x_back", "run_y_back",
    "fits_x_near", "fits_x_far", "fits_y_near", "fits_y_far",
    "region", "same_area", "closes", "level_with", "same_count", "lowest",
)  # fmt: skip
N_FEATURES = len(FEATURE_NAMES)


def _run(free: np.ndarray, x: int, y: int, dx: int, dy: int) -> int:
    nx, ny = free.shape
    n = 0
    while 0 <= x < nx and 0 <= y < ny and free[x, y]:
        n += 1
        x += dx
        y += dy
    return n


def _subset_areas(areas: Sequence[int], limit: int) -> np.ndarray:
    """Bool (limit + 1,): which totals up to ``limit`` some subset of ``areas`` makes."""
    reach = np.zeros(limit + 1, dtype=bool)
    reach[0] = True
    for a in areas:
        if a <= limit:
            reach[a:] |= reach[: limit + 1 - a].copy()
    return reach


class Levels:
    """The levels of one heightmap, each labelled once: what :func:`level_fit` reads, shared by
    every listed placement of one state (a decision lists up to 16 of them, most at one z)."""

    def __init__(self, heightmap: np.ndarray) -> None:
        self.heightmap = np.asarray(heightmap)
        self.lowest = int(self.heightmap.min())
        self._levels: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def at(self, z: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(level, labels, sizes) at ``z``: the cells at or below its level, their 4-connected
        components and each component's cell count (indexed by label)."""
        if z not in self._levels:
            level = at_or_below(self.heightmap, z)
            labels, _ = ndimage.label(level, structure=_FOUR)
            self._levels[z] = (level, labels, np.bincount(labels.ravel()))
        return self._levels[z]


def _ring_tops(hm: np.ndarray, c: Candidate) -> np.ndarray:
    """Heights of the footprint's 4-neighbour ring inside the map (the cells ``ring4`` marks)."""
    nx, ny = hm.shape
    x1, y1 = c.x + c.fx, c.y + c.fy
    strips = [
        hm[c.x - 1, c.y : y1] if c.x > 0 else hm[:0, 0],
        hm[x1, c.y : y1] if x1 < nx else hm[:0, 0],
        hm[c.x : x1, c.y - 1] if c.y > 0 else hm[:0, 0],
        hm[c.x : x1, y1] if y1 < ny else hm[:0, 0],
    ]
    return np.concatenate(strips)


def level_fit(
    heightmap: np.ndarray,
    shown: Sequence[ShownItem],
    c: Candidate,
    levels: Levels | None = None,
) -> np.ndarray:
    """(N_FEATURES,) float32 for one listed placement (module docstring).

    ``levels``: the state's :class:`Levels` when several placements of one heightmap are read;
    the heightmap is then read from it (it must be made from ``heightmap``).
    """
    levels = Levels(heightmap) if levels is None else levels
    hm = levels.heightmap
    nx, ny = hm.shape
    height = shown[c.object_index].size_mm[2]
    level, labels, sizes = levels.at(c.z_mm)
    footprint = (slice(c.x, c.x + c.fx), slice(c.y, c.y + c.fy))
    others = [s for s in shown if s.shown_index != c.object_index and s.size_mm[2] == height]
    sides = {int(v) for s in others for v in s.size_cells[:2]}
    closable = sides | {a + b for a in sides for b in sides} | {0}
    x1, y1 = c.x + c.fx, c.y + c.fy
    # Runs start beside the footprint and lead away from it, so the level with the footprint
    # still in it reads the same.
    far = [
        _run(level, x1, c.y, 1, 0),
        _run(level, x1, y1 - 1, 1, 0),
        _run(level, c.x, y1, 0, 1),
        _run(level, x1 - 1, y1, 0, 1),
    ]
    back = [_run(level, c.x - 1, c.y, -1, 0), _run(level, c.x, c.y - 1, 0, -1)]
    if level[footprint].all():
        # The free area connected to the box, once the box stands there, is its level component
        # less the footprint: every cell the footprint joined to the rest touches its ring.
        region = int(sizes[labels[c.x, c.y]]) - c.fx * c.fy
    else:  # z below the footprint's top (not Eq. 2's height): label the level without the box
        free = level.copy()
        free[footprint] = False
        own, _ = ndimage.label(free, structure=_FOUR)
        ring = ring4(_mask(hm.shape, footprint))
        touching = np.unique(own[ring & free])
        region = int(np.bincount(own.ravel())[touching[touching > 0]].sum())
    areas = [s.size_cells[0] * s.size_cells[1] for s in others]
    closes = region == 0 or bool(_subset_areas(areas, region)[region])
    tops = _ring_tops(hm, c)
    level_with = np.mean(same_level(tops, c.z_mm + height)) if tops.size else 0.0
    row = [
        *(r / RUN_SCALE for r in far[:2]),
        *(r / RUN_SCALE for r in far[2:]),
        *(r / RUN_SCALE for r in back),
        *(float(r in closable) for r in far),
        region / (nx * ny),
        min(sum(areas) / max(region, 1), AREA_CAP),
        float(closes),
        float(level_with),
        len(others) / COUNT_SCALE,
        float(at_or_below(c.z_mm, levels.lowest)),
    ]
    return np.asarray(row, dtype=np.float32)


def _mask(shape: tuple[int, ...], cells: tuple[slice, slice]) -> np.ndarray:
    out = np.zeros(shape, dtype=bool)
    out[cells] = True
    return out


def level_fit_rows(
    heightmap: np.ndarray, shown: Sequence[ShownItem], listed: Sequence[Candidate]
) -> np.ndarray:
    """(len(listed), N_FEATURES) float32: :func:`level_fit` of every listed placement."""
    if not listed:
        return np.zeros((0, N_FEATURES), dtype=np.float32)
    levels = Levels(heightmap)
    return np.stack([level_fit(heightmap, shown, c, levels) for c in listed])
