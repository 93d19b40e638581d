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


@st.composite
def packing_states(draw, max_cells: int = 6, max_items: int = 3):
    """(heightmap (X, Y) int32 mm, shown items, rim mm)."""
    nx = draw(st.integers(1, max_cells))
    ny = draw(st.integers(1, max_cells))
    flat = draw(st.lists(st.sampled_from(HEIGHTS_MM), min_size=nx * ny, max_size=nx * ny))
    hm = np.array(flat, dtype=np.int32).reshape(nx, ny)
    rim = draw(st.integers(10, 300))
    sizes = draw(
        st.lists(
            st.tuples(st.integers(1, 4), st.integers(1, 4), EVEN_HEIGHTS_MM),
            min_size=0,
            max_size=max_items,
        )
    )
    shown = [shown_item(i, fx, fy, h) for i, (fx, fy, h) in enumerate(sizes)]
    return hm, shown, rim
