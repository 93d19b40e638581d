"""Pure heightmap operations: placing boxes and rasterising settled poses.

Eq. 2 lives in core.feasibility.

A heightmap is an int32 array of shape (x_cells, y_cells) holding, for each grid cell, the top
surface height in millimetres over that cell.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def place_box(heightmap: np.ndarray, x: int, y: int, fx: int, fy: int, top_mm: int) -> np.ndarray:
    """A new heightmap with the footprint's cells raised to ``top_mm`` (geometric transition)."""
    out = heightmap.copy()
    region = out[x : x + fx, y : y + fy]
    np.maximum(region, top_mm, out=region)
    return out


def quat_to_matrix(q: Iterable[float]) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def yaw_quaternion(rotation: int) -> tuple[float, float, float, float]:
    """Quaternion of the action's yaw: identity for rotation 0, +90 degrees about z for 1."""
    if rotation == 1:
        s = float(np.sqrt(0.5))
        return (s, 0.0, 0.0, s)
    return (1.0, 0.0, 0.0, 0.0)


def box_top_over_cells(
    centre_mm: np.ndarray,
    rotation: np.ndarray,
    half_size_mm: np.ndarray,
    cell_x_mm: np.ndarray,
    cell_y_mm: np.ndarray,
) -> np.ndarray:
    """Top height (mm) of a posed box along vertical lines through the given points; NaN = miss.

    Slab test of each vertical line against the box in its local frame, so tilted boxes are
    handled exactly: the top is where the upward ray leaves the box.
    """
    px = cell_x_mm - centre_mm[0]
    py = cell_y_mm - centre_mm[1]
    # Line p(t) = (px, py, t - cz) in world offsets; local = R^T p. Direction d = R^T e_z.
    rt = rotation.T
    d = rt[:, 2]
    origin = rt[:, 0:1] * px.ravel() + rt[:, 1:2] * py.ravel() - rt[:, 2:3] * centre_mm[2]
    t_enter = np.full(origin.shape[1], -np.inf)
    t_exit = np.full(origin.shape[1], np.inf)
    for axis in range(3):
        h = half_size_mm[axis]
        if abs(d[axis]) < 1e-12:
            outside = np.abs(origin[axis]) > h
            t_enter[outside] = np.inf
            continue
        t1 = (-h - origin[axis]) / d[axis]
        t2 = (h - origin[axis]) / d[axis]
        t_enter = np.maximum(t_enter, np.minimum(t1, t2))
        t_exit = np.minimum(t_exit, np.maximum(t1, t2))
    top = np.where(t_enter <= t_exit, t_exit, np.nan)
    return top.reshape(np.shape(cell_x_mm))


def box_top_region(
    grid_shape: tuple[int, int],
    cell_mm: int,
    size_mm: np.ndarray,
    position_mm: np.ndarray,
    quaternion: np.ndarray,
) -> tuple[int, int, int, int, np.ndarray] | None:
    """Cell window (i0, i1, j0, j1) and top heights (float mm, NaN = not covered) of one box.

    Cells are sampled at their centres; the window is the box's planar extent clipped to the
    grid, or None when the box covers no cell of the grid.
    """
    nx, ny = grid_shape
    rot = quat_to_matrix(quaternion)
    half = np.asarray(size_mm, dtype=np.float64) / 2.0
    extent = np.abs(rot[:2, :]) @ half  # the box's planar half-extent limits the cells tested
    i0 = max(int(np.floor((position_mm[0] - extent[0]) / cell_mm)), 0)
    i1 = min(int(np.ceil((position_mm[0] + extent[0]) / cell_mm)), nx)
    j0 = max(int(np.floor((position_mm[1] - extent[1]) / cell_mm)), 0)
    j1 = min(int(np.ceil((position_mm[1] + extent[1]) / cell_mm)), ny)
    if i0 >= i1 or j0 >= j1:
        return None
    # The cells' centres as broadcast views (the values of a meshgrid, without its copies).
    shape = (i1 - i0, j1 - j0)
    gx = np.broadcast_to(((np.arange(i0, i1) + 0.5) * cell_mm)[:, None], shape)
    gy = np.broadcast_to(((np.arange(j0, j1) + 0.5) * cell_mm)[None, :], shape)
    top = box_top_over_cells(np.asarray(position_mm, dtype=np.float64), rot, half, gx, gy)
    return i0, i1, j0, j1, top


def compose_regions(grid_shape: tuple[int, int], regions) -> np.ndarray:
    """Heightmap (int32 mm, 0 = floor) as the max over per-box regions from ``box_top_region``."""
    return round_heightmap(max_regions_into(np.zeros(grid_shape, dtype=np.float64), regions))


def max_regions_into(top: np.ndarray, regions) -> np.ndarray:
    """Raise ``top`` (float mm, in place) to the max of itself and per-box regions from
    ``box_top_region`` (None: a box over no cell; NaN cells: not covered); returns ``top``."""
    for region in regions:
        if region is None:
            continue
        i0, i1, j0, j1, cells = region
        window = top[i0:i1, j0:j1]
        np.fmax(window, cells, out=window)
    return top


def round_heightmap(top: np.ndarray) -> np.ndarray:
    """Float top heights (mm) as a heightmap: whole mm, int32."""
    return np.rint(top).astype(np.int32)


def rasterise_poses(
    grid_shape: tuple[int, int],
    cell_mm: int,
    sizes_mm: np.ndarray,
    positions_mm: np.ndarray,
    quaternions: np.ndarray,
) -> np.ndarray:
    """Heightmap (int32 mm) of boxes at settled poses, sampled at cell centres.

    ``sizes_mm`` (n, 3) are the boxes' own (l, w, h), ``positions_mm`` (n, 3) their centres and
    ``quaternions`` (n, 4) their orientations (w, x, y, z). Heights round to whole mm, and a
    cell nothing covers is 0 (the floor).
    """
    return compose_regions(
        grid_shape,
        (
            box_top_region(grid_shape, cell_mm, s, p, q)
            for s, p, q in zip(sizes_mm, positions_mm, quaternions)
        ),
    )
