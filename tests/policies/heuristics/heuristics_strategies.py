"""Hypothesis strategies for small random packing states (heightmap, shown buffer, rim)."""

from __future__ import annotations

import numpy as np
from heuristics_reference import shown_item
from hypothesis import strategies as st

#: Few distinct heights, so equal heights (exact support, ties) are common; includes values on
#: and beside voxel-centre boundaries (12.5 mm, 37.5 mm) for the SDF layer rules.
HEIGHTS_MM = (0, 2, 12, 14, 24, 26, 38, 50, 76, 100, 150)


#: Box heights: multiples of the 2 mm height quantum.
EVEN_HEIGHTS_MM = st.integers(1, 90).map(lambda v: 2 * v)


#: Box shapes (fx, fy cells, h mm) of one volume, for the tie-break rule: equal volumes with
#: different footprints, and both orientations of the same box.
EQUAL_VOLUME_SHAPES = st.sampled_from(
    [(1, 1, 80), (1, 2, 40), (2, 1, 40), (2, 2, 20), (1, 4, 20), (4, 1, 20)]
)


#: Heights of the equal-volume shapes' multiples: surfaces level enough for objects to tie.
LEVEL_HEIGHTS_MM = (0, 0, 20, 40, 80)


@st.composite
def packing_states(draw, max_cells: int = 6, max_items: int = 3, shapes=None, heights=HEIGHTS_MM):
    """(heightmap (X, Y) int32 mm, shown items, rim mm); ``shapes`` draws (fx, fy, h) boxes,
    ``heights`` lists the heightmap's values."""
    nx = draw(st.integers(1, max_cells))
    ny = draw(st.integers(1, max_cells))
    flat = draw(st.lists(st.sampled_from(heights), min_size=nx * ny, max_size=nx * ny))
    hm = np.array(flat, dtype=np.int32).reshape(nx, ny)
    rim = draw(st.integers(10, 300))
    if shapes is None:
        shapes = st.tuples(st.integers(1, 4), st.integers(1, 4), EVEN_HEIGHTS_MM)
    sizes = draw(
        st.lists(
            shapes,
            min_size=0,
            max_size=max_items,
        )
    )
    shown = [shown_item(i, fx, fy, h) for i, (fx, fy, h) in enumerate(sizes)]
    return hm, shown, rim
