"""Heightmap -> top-down image: the picture the packing VLM reads (pure numpy; Pillow wraps it).

Convention (the VLM prompt and every figure rely on it):

* The container's x axis runs left to right along image columns and y runs top to bottom along
  image rows, so cell (0, 0) (the container origin) is the top-left cell, as in pixel
  coordinates. ``heightmap[x, y]`` is drawn at column x, row y.
* Aspect is preserved: every cell is drawn as a square of the same whole number of pixels when
  the grid fits (``size // max(x_cells, y_cells)``), centred on a square canvas of ``size`` px
  with a light background and a one-pixel dark frame around the container where there is room.
* Colour is a fixed scale of the absolute height, from the floor (0 mm, a dark slate that no box
  can have) through blue, teal, green and yellow to pale yellow at the rim (the container
  height), and red above the rim. The same height is the same colour in every image of a
  container, so heights can be compared across steps. ``LEVELS`` ramp steps over the container
  height (1.5 cm per step for the tallest 120 cm container).
* Grid lines darken the cell colour (so they never hide a height): a thin line on every cell
  boundary when cells are at least 6 px, and a stronger line every ``major_every`` cells (cell
  indices 5, 10, ... by default) so coordinates can be counted.

The image is palette-indexed internally (``heightmap_to_indices`` + ``PALETTE``), which makes
PNGs small and fast to write; ``heightmap_to_rgb`` and ``heightmap_to_image`` give RGB.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from PIL import Image

from packlab.core.types import Container

DEFAULT_SIZE = 224

#: Height levels: 0 = floor, 1..LEVELS-2 = ramp over (0, rim], LEVELS-1 = above the rim.
LEVELS = 84
_RAMP = LEVELS - 2
#: Shades of each level: cell interior, thin grid line, major grid line (multipliers).
_SHADES = (1.0, 0.8, 0.5)
#: Smallest cell size (px) that gets a thin line on every cell boundary.
THIN_LINES_MIN_PX = 6
BACKGROUND_INDEX = LEVELS * len(_SHADES)
FRAME_INDEX = BACKGROUND_INDEX + 1

_FLOOR_RGB = (38, 42, 54)
_ABOVE_RIM_RGB = (225, 30, 50)
_BACKGROUND_RGB = (236, 236, 236)
_FRAME_RGB = (20, 20, 20)
# Anchors of the height ramp at t = 0, 0.25, ..., 1: dark to light, hue changing along the way,
# so both brightness and hue tell heights apart.
_RAMP_ANCHORS = np.array(
    [(40, 70, 170), (30, 140, 175), (70, 190, 100), (235, 215, 40), (255, 248, 190)],
    dtype=np.float64,
)


def _build_palette() -> np.ndarray:
    t = np.linspace(0.0, 1.0, _RAMP)
    pos = np.linspace(0.0, 1.0, len(_RAMP_ANCHORS))
    ramp = np.stack([np.interp(t, pos, _RAMP_ANCHORS[:, ch]) for ch in range(3)], axis=1)
    base = np.vstack([_FLOOR_RGB, ramp, _ABOVE_RIM_RGB])  # (LEVELS, 3)
    shaded = [base * s for s in _SHADES]
    palette = np.zeros((256, 3), dtype=np.float64)
    palette[:BACKGROUND_INDEX] = np.vstack(shaded)
    palette[BACKGROUND_INDEX] = _BACKGROUND_RGB
    palette[FRAME_INDEX] = _FRAME_RGB
    return np.rint(palette).astype(np.uint8)


#: (256, 3) uint8 RGB of every index ``heightmap_to_indices`` can return.
PALETTE = _build_palette()
PALETTE.setflags(write=False)


def height_levels(heightmap: np.ndarray, container_height_mm: int) -> np.ndarray:
    """Colour level (uint8, 0..LEVELS-1) of each height: 0 floor, ramp to the rim, then above."""
    h = np.asarray(heightmap, dtype=np.int64)
    ramp = np.clip(-(-h * _RAMP // int(container_height_mm)), 1, _RAMP)  # ceil, so any box >= 1
    levels = np.where(h <= 0, 0, np.where(h > container_height_mm, LEVELS - 1, ramp))
    return levels.astype(np.uint8)


def height_colour(height_mm: int, container: Container) -> tuple[int, int, int]:
    """The RGB a cell of this height gets (for legends and figures)."""
    level = int(height_levels(np.array([[height_mm]]), container.height_mm)[0, 0])
    return tuple(int(v) for v in PALETTE[level])  # type: ignore[return-value]


def _pixel_cells(n_cells: int, n_px: int) -> np.ndarray:
    """Cell index of each of ``n_px`` pixels spanning ``n_cells`` cells.

    Nearest cell; exact when ``n_px`` is a whole multiple of ``n_cells``.
    """
    return np.arange(n_px) * n_cells // n_px


def _line_shade(cells: np.ndarray, px_per_cell: int, major_every: int) -> np.ndarray:
    """Per pixel: 0 interior, 1 thin line, 2 major line (on the first pixel of a cell)."""
    shade = np.zeros(cells.shape, dtype=np.uint8)
    if px_per_cell < 2:
        return shade
    first = np.r_[False, cells[1:] != cells[:-1]]
    # Thin lines on every cell only when cells are big enough for them not to dominate the
    # picture; below that only the major lines are drawn, which still let coordinates be counted.
    if px_per_cell >= THIN_LINES_MIN_PX:
        shade[first] = 1
    if major_every > 0:
        shade[first & (cells % major_every == 0)] = 2
    return shade


@dataclass(frozen=True, slots=True)
class _Geometry:
    """Where the map goes on the canvas; depends only on the grid shape and the image size."""

    px: int  # whole pixels per cell, 0 when the grid has more cells than the canvas has pixels
    row_cells: np.ndarray  # (height,) cell y of each map row
    col_cells: np.ndarray  # (width,) cell x of each map column
    shade: (
        np.ndarray
    )  # (height, width) uint8 palette offset of the grid lines (0, LEVELS, 2 LEVELS)
    top: int
    left: int
    canvas: np.ndarray  # (size, size) uint8 background and frame, to be copied


@lru_cache(maxsize=128)
def _geometry(nx: int, ny: int, size: int, major_every: int) -> _Geometry:
    # Cached: a dataset renders thousands of images of one container, and this part is the
    # same for all of them.
    longest = max(nx, ny)
    px = size // longest if longest <= size else 0
    width, height = (
        (nx * px, ny * px) if px else (max(1, nx * size // longest), max(1, ny * size // longest))
    )
    col_cells, row_cells = _pixel_cells(nx, width), _pixel_cells(ny, height)
    shade = np.maximum(
        _line_shade(row_cells, px, major_every)[:, None],
        _line_shade(col_cells, px, major_every)[None, :],
    ) * np.uint8(LEVELS)
    canvas = np.full((size, size), BACKGROUND_INDEX, dtype=np.uint8)
    top, left = (size - height) // 2, (size - width) // 2
    # The frame sits in the margin, one pixel outside the map, on the sides that have room.
    if top > 0:
        canvas[top - 1, max(left - 1, 0) : left + width + 1] = FRAME_INDEX
    if top + height < size:
        canvas[top + height, max(left - 1, 0) : left + width + 1] = FRAME_INDEX
    if left > 0:
        canvas[max(top - 1, 0) : top + height + 1, left - 1] = FRAME_INDEX
    if left + width < size:
        canvas[max(top - 1, 0) : top + height + 1, left + width] = FRAME_INDEX
    for a in (row_cells, col_cells, shade, canvas):
        a.setflags(write=False)
    return _Geometry(px, row_cells, col_cells, shade.astype(np.uint8), top, left, canvas)


def heightmap_to_indices(
    heightmap: np.ndarray, container: Container, size: int = DEFAULT_SIZE, major_every: int = 5
) -> np.ndarray:
    """(size, size) uint8 palette indices of the image of ``heightmap`` (x_cells, y_cells) mm."""
    if size < 1:
        raise ValueError(f"size = {size}: must be positive")
    hm = np.asarray(heightmap)
    if hm.ndim != 2 or hm.size == 0:
        raise ValueError(f"heightmap must be a non-empty 2-D array, got shape {hm.shape}")
    g = _geometry(hm.shape[0], hm.shape[1], size, major_every)
    levels = height_levels(hm, container.height_mm).T  # rows = y, columns = x
    if g.px:
        image = np.repeat(np.repeat(levels, g.px, axis=0), g.px, axis=1)
    else:
        image = levels[g.row_cells[:, None], g.col_cells[None, :]]
    canvas = g.canvas.copy()
    h, w = g.shade.shape
    np.add(image, g.shade, out=canvas[g.top : g.top + h, g.left : g.left + w])
    return canvas


def heightmap_to_rgb(
    heightmap: np.ndarray, container: Container, size: int = DEFAULT_SIZE, major_every: int = 5
) -> np.ndarray:
    """(size, size, 3) uint8 RGB image of ``heightmap`` (see the module docstring)."""
    return PALETTE[heightmap_to_indices(heightmap, container, size, major_every)]


def heightmap_to_image(
    heightmap: np.ndarray,
    container: Container,
    size: int = DEFAULT_SIZE,
    major_every: int = 5,
    mode: str = "RGB",
) -> Image.Image:
    """The image as a PIL image: ``mode="RGB"`` (default) or ``"P"`` (palette, smallest PNGs)."""
    indices = heightmap_to_indices(heightmap, container, size, major_every)
    if mode == "P":
        image = Image.frombytes("P", (indices.shape[1], indices.shape[0]), indices.tobytes())
        image.putpalette(PALETTE.tobytes())
        return image
    if mode == "RGB":
        return Image.fromarray(PALETTE[indices])
    raise ValueError(f"mode = {mode!r}: expected 'RGB' or 'P'")
