"""The heightmap rasteriser: shape, orientation, aspect, fixed colour scale, grid, PNG modes."""

from __future__ import annotations

import io

import numpy as np
import pytest

from packlab.core.types import Container
from packlab.sim.raster import (
    BACKGROUND_INDEX,
    FRAME_INDEX,
    LEVELS,
    PALETTE,
    height_colour,
    height_levels,
    heightmap_to_image,
    heightmap_to_indices,
    heightmap_to_rgb,
)

C = Container((1000, 500, 800))  # 40 x 20 cells


def test_shape_dtype_and_default_size():
    rgb = heightmap_to_rgb(np.zeros(C.cells, np.int32), C)
    assert rgb.shape == (224, 224, 3) and rgb.dtype == np.uint8


def test_orientation_x_columns_y_rows_origin_top_left():
    hm = np.zeros(C.cells, np.int32)
    hm[0:4, 0:2] = 400  # a box at the origin, 4 cells along x and 2 along y
    idx = heightmap_to_indices(hm, C, size=224)
    px = 224 // 40  # 5 px per cell
    top = (224 - 20 * px) // 2
    left = (224 - 40 * px) // 2
    level = height_levels(np.array([[400]]), C.height_mm)[0, 0]

    # Interior pixel of cell (x=3, y=1) is the box; of cell (x=1, y=3) and (x=5, y=0) it is floor.
    def cell_px(x, y):
        return idx[top + y * px + px // 2, left + x * px + px // 2]

    assert cell_px(3, 1) == level and cell_px(1, 3) == 0 and cell_px(5, 0) == 0


def test_aspect_is_preserved_with_square_cells():
    idx = heightmap_to_indices(np.zeros(C.cells, np.int32), C, size=224)
    inside = idx != BACKGROUND_INDEX
    rows, cols = np.nonzero(inside)
    # 40 x 20 cells at 5 px, plus a one-pixel frame on each side.
    assert cols.max() - cols.min() + 1 == 40 * 5 + 2
    assert rows.max() - rows.min() + 1 == 20 * 5 + 2


def test_colour_scale_is_fixed_and_monotone():
    a = np.zeros(C.cells, np.int32)
    b = np.full(C.cells, 300, np.int32)
    a[0, 0] = 300
    ra, rb = heightmap_to_rgb(a, C), heightmap_to_rgb(b, C)
    px, top, left = 5, 62, 12
    centre = (top + px // 2, left + px // 2)
    assert (ra[centre] == rb[centre]).all()  # the same height is the same colour in any map
    levels = height_levels(np.array([np.arange(0, 801, 20)]), C.height_mm)[0]
    assert levels[0] == 0 and levels[1] >= 1 and np.all(np.diff(levels.astype(int)) >= 0)
    assert levels[-1] == LEVELS - 2  # the rim is the top of the ramp
    assert height_levels(np.array([[801]]), C.height_mm)[0, 0] == LEVELS - 1  # above the rim
    brightness = PALETTE[1 : LEVELS - 1].astype(int).sum(axis=1)
    assert np.all(np.diff(brightness) >= 0)  # higher is lighter
    assert height_colour(0, C) != height_colour(2, C)  # floor differs from any box


def test_grid_lines_darken_without_hiding_height():
    hm = np.full(C.cells, 400, np.int32)
    level = height_levels(np.array([[400]]), C.height_mm)[0, 0]
    # 5 px cells: interior and major lines only (thin lines would dominate so small a cell).
    values = set(np.unique(heightmap_to_indices(hm, C, size=224)[100])) - {
        BACKGROUND_INDEX,
        FRAME_INDEX,
    }
    assert values == {level, level + 2 * LEVELS}
    # 10 px cells: interior, thin line, major line.
    values = set(np.unique(heightmap_to_indices(hm, C, size=448)[200])) - {
        BACKGROUND_INDEX,
        FRAME_INDEX,
    }
    assert values == {level, level + LEVELS, level + 2 * LEVELS}


@pytest.mark.parametrize("cells", [(20, 20), (68, 48), (7, 3), (300, 10)])
def test_any_grid_fits_the_canvas(cells):
    c = Container((cells[0] * 25, cells[1] * 25, 500))
    rng = np.random.default_rng(0)
    hm = rng.integers(0, 600, size=cells).astype(np.int32)
    assert heightmap_to_rgb(hm, c, size=96).shape == (96, 96, 3)


def test_png_palette_and_rgb_images_agree():
    hm = np.random.default_rng(1).integers(0, 800, size=C.cells).astype(np.int32)
    from PIL import Image

    rgb = heightmap_to_image(hm, C)
    buf = io.BytesIO()
    heightmap_to_image(hm, C, mode="P").save(buf, format="PNG")
    back = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))
    assert rgb.mode == "RGB" and (back == np.asarray(rgb)).all()
