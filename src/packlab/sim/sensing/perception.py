"""Perception from depth images: the container heightmap and the buffered boxes' sizes and poses.

Pure numpy/scipy functions over a ``DepthImage`` (see ``camera``):

- ``heightmap_from_depth``: back-project every valid pixel and bin it to the 25 mm action grid;
  each cell takes a percentile of its points' heights (default the median, see there).
- ``segment_truth`` / ``segment_depth``: per-pixel object labels, from the ground-truth ids
  (the "SAM-perfect" ablation) or from the depth image alone (the robot's default: the region
  above the table, cut along the grooves between touching boxes; a classical pipeline with no
  learned model).
- ``estimate_objects``: each segment's dimensions, top centre and yaw, from its top-face point
  cloud by a minimum-area rectangle refined by line fits to its four edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError

from packlab.core.choices import SizePrior
from packlab.core.types import Container
from packlab.sim.sensing.camera import DepthImage


def heightmap_from_depth(
    image: DepthImage,
    container: Container,
    percentile: float = 50.0,
    z_quantum_mm: int = 1,
    flat_tolerance_mm: float = 0.0,
) -> np.ndarray:
    """Heightmap (x_cells, y_cells) int32 mm of the container from its top-down depth image.

    Rule: the back-projected points are binned by their (x, y) into the container's cells; a cell
    takes the ``percentile`` (nearest rank) of its points' heights, rounded to ``z_quantum_mm``
    and clipped at the floor (0). The median is the default because (a) it ignores the outliers
    and the half of the noise a max would pick up (a max over 25 noisy pixels is biased by about
    2 sigma upwards), and (b) with an odd number of pixels per cell side (5 mm pixels on 25 mm
    cells) the median over a straight box edge crossing the cell equals the sample at the cell
    centre, which is the rasteriser's rule (``packlab.sim.heightmap.rasterise_poses``), so at
    zero noise the two agree. Whole mm is the rasteriser's rounding too. A cell with no valid
    pixel (all dropped) takes the value of its nearest cell that has one. With a
    ``flat_tolerance_mm`` the cells are then flattened into tops (``flatten_tops``).
    """
    nx, ny = container.cells
    cell = container.cell_xy_mm
    per_cell = cell / image.pixel_mm
    aligned = image.origin_mm == (0.0, 0.0) and per_cell == int(per_cell)
    if aligned and image.shape == (nx * int(per_cell), ny * int(per_cell)):
        values, has = _cell_percentile_aligned(image.heights_mm(), int(per_cell), percentile)
    else:
        values, has = _cell_percentile_binned(image, nx, ny, cell, percentile)
    if has.any() and not has.all():
        _, (ii, jj) = ndimage.distance_transform_edt(~has, return_indices=True)
        values = values[ii, jj]
    if flat_tolerance_mm > 0:
        values = flatten_tops(values, flat_tolerance_mm)
    quantum = max(int(z_quantum_mm), 1)
    return (np.maximum(np.rint(values / quantum), 0) * quantum).astype(np.int32)


def flatten_tops(values: np.ndarray, tolerance_mm: float) -> np.ndarray:
    """Cell heights (nx, ny) float mm with every flat top given one value.

    Cells joined through 4-neighbours whose heights differ by at most ``tolerance_mm`` form a
    top; each cell within ``tolerance_mm`` of its top's median takes that median. One cell's
    median still has noise (about 0.3 mm for a 1 mm sensor), so a flat box top would otherwise
    show stray 1 mm steps where a cell rounds the other way, which a policy comparing heights
    reads as a real step; a top's median over hundreds of pixels does not. Real steps (box
    heights, tens of mm) are far above the tolerance, so tops at different heights stay apart.
    A gentle slope (a tilted box, or tilted boxes side by side) can chain many cells into one
    "top": only its cells near the median move, so no cell moves by more than the tolerance.
    """
    nx, ny = values.shape
    index = np.arange(nx * ny).reshape(nx, ny)
    pairs = [
        (index[:-1, :], index[1:, :], np.abs(values[:-1, :] - values[1:, :])),
        (index[:, :-1], index[:, 1:], np.abs(values[:, :-1] - values[:, 1:])),
    ]
    rows = np.concatenate([a[d <= tolerance_mm] for a, _, d in pairs])
    cols = np.concatenate([b[d <= tolerance_mm] for _, b, d in pairs])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(nx * ny, nx * ny))
    count, labels = connected_components(graph, directed=False)
    medians = np.asarray(ndimage.median(values.ravel(), labels, np.arange(count)))
    top = medians[labels].reshape(nx, ny)
    return np.where(np.abs(values - top) <= tolerance_mm, top, values)


def _cell_percentile_aligned(heights: np.ndarray, k: int, percentile: float):
    """Fast path when each cell is exactly k x k pixels: (values (nx, ny), has (nx, ny))."""
    nx, ny = heights.shape[0] // k, heights.shape[1] // k
    blocks = heights.reshape(nx, k, ny, k).transpose(0, 2, 1, 3).reshape(nx, ny, k * k)
    blocks = np.sort(blocks, axis=2)  # NaN (missing) sort last
    counts = np.isfinite(blocks).sum(axis=2)
    rank = np.rint(np.maximum(counts - 1, 0) * (percentile / 100.0)).astype(np.int64)
    values = np.take_along_axis(blocks, rank[..., None], axis=2)[..., 0]
    has = counts > 0
    return np.where(has, values, 0.0), has


def _cell_percentile_binned(image: DepthImage, nx: int, ny: int, cell: int, percentile: float):
    """General path: back-project, bin by cell, nearest-rank percentile per cell."""
    xs, ys = image.pixel_centres()
    zs = image.heights_mm()
    ci = np.floor(xs / cell).astype(np.int64)
    cj = np.floor(ys / cell).astype(np.int64)
    keep = np.isfinite(zs) & (ci >= 0) & (ci < nx) & (cj >= 0) & (cj < ny)
    key = (ci * ny + cj)[keep]
    z = zs[keep]
    order = np.lexsort((z, key))
    counts = np.bincount(key, minlength=nx * ny)
    starts = np.cumsum(counts) - counts
    has = counts > 0
    rank = np.rint((counts - 1) * (percentile / 100.0)).astype(np.int64)
    values = np.zeros(nx * ny, dtype=np.float64)
    values[has] = z[order][starts[has] + rank[has]]
    return values.reshape(nx, ny), has.reshape(nx, ny)


def segment_truth(image: DepthImage) -> np.ndarray:
    """Labels (nx, ny) int32 from the ground-truth ids; -1 = background or missing depth."""
    return np.where(np.isfinite(image.depth_mm), image.ids, -1).astype(np.int32)


def segment_depth(
    image: DepthImage,
    table_z_mm: float = 0.0,
    min_height_mm: float = 10.0,
    groove_mm: float = 1.5,
    step_mm: float = 2.0,
    window_px: int = 7,
    min_pixels: int = 16,
    grow_mm: float = 10.0,
) -> np.ndarray:
    """Labels (nx, ny) int32 of the boxes in a depth image, from depth alone; -1 = none.

    Foreground is every pixel more than ``min_height_mm`` above the table. Boxes that touch form
    one foreground region, so it is cut along the *grooves* between them: the rounded edges of
    two touching cartons (and any height step) leave a dip below the surrounding tops. A dip is
    where a morphological closing (max then min filter over ``window_px``, wider than a groove)
    of the lightly smoothed heights lies more than ``groove_mm`` above them; where the smoothed
    heights change by more than ``step_mm`` per pixel (a step between boxes) is cut too. The
    foreground less the cuts is opened twice (cutting bridges of one or two pixels that noise
    leaves across a groove); its 4-connected components of at least ``min_pixels`` are the box
    cores, numbered 0.. in scan order. Each core grows back over the foreground within
    ``window_px`` rings of it and ``grow_mm`` of its height (``_grow``), so a box's segment
    reaches its true edges again and no further. Missing pixels read as table: a camera that
    lost them cannot say a box is there.
    """
    heights = np.nan_to_num(image.heights_mm() - table_z_mm, nan=0.0)
    foreground = heights > min_height_mm
    smooth = ndimage.gaussian_filter(heights, 1.0)
    # The table counts as higher than any top, so a groove that runs out to a box's outer
    # edge stays a groove to its end instead of draining into the table.
    raised = np.where(foreground, smooth, smooth.max() + 2 * groove_mm)
    closed = ndimage.minimum_filter(ndimage.maximum_filter(raised, size=window_px), size=window_px)
    # A height step between touching boxes (the smoothing fills the groove beside it).
    rows, cols = np.gradient(smooth)
    cut = (closed - smooth > groove_mm) | _steeper_than(rows, cols, step_mm)
    core = _open_cross(foreground & ~cut, 2)
    labels, n = ndimage.label(core)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    keep = np.flatnonzero(sizes[1:] >= min_pixels) + 1
    remap = np.full(n + 1, -1, dtype=np.int32)
    remap[keep] = np.arange(len(keep), dtype=np.int32)
    cores = remap[labels]
    if not len(keep):
        return cores
    return _grow(cores, heights, foreground, window_px, grow_mm)


def _steeper_than(dx: np.ndarray, dy: np.ndarray, limit: float) -> np.ndarray:
    """``np.hypot(dx, dy) > limit``, element by element, with ``hypot`` (slow) taken only
    where the squared length lies within a relative 1e-9 of ``limit`` squared: elsewhere the
    squared length (a few ulps off) decides the same, and everywhere the answer is the one
    ``np.hypot`` gives. ``limit`` > 0."""
    squared = dx * dx
    squared += dy * dy
    bound = limit * limit
    steep = squared > bound * (1.0 + 1e-9)
    unsure = np.flatnonzero((squared >= bound * (1.0 - 1e-9)) & ~steep)
    if unsure.size:
        steep.ravel()[unsure] = np.hypot(dx.ravel()[unsure], dy.ravel()[unsure]) > limit
    return steep


def _open_cross(mask: np.ndarray, iterations: int) -> np.ndarray:
    """``ndimage.binary_opening(mask, iterations=...)`` (2-D bool, the 4-neighbour cross,
    nothing beyond the image): ``iterations`` erosions, then as many dilations, each a few
    whole-array shifts instead of scipy's pixel loop (a tenth of its time on buffer images)."""
    out = mask
    for _ in range(iterations):
        eroded = out.copy()
        eroded[1:, :] &= out[:-1, :]
        eroded[:-1, :] &= out[1:, :]
        eroded[:, 1:] &= out[:, :-1]
        eroded[:, :-1] &= out[:, 1:]
        eroded[0, :] = eroded[-1, :] = False  # a neighbour beyond the image is background
        eroded[:, 0] = eroded[:, -1] = False
        out = eroded
    for _ in range(iterations):
        dilated = out.copy()
        dilated[1:, :] |= out[:-1, :]
        dilated[:-1, :] |= out[1:, :]
        dilated[:, 1:] |= out[:, :-1]
        dilated[:, :-1] |= out[:, 1:]
        out = dilated
    return out


def _grow(cores, heights, foreground, steps: int, tolerance_mm: float) -> np.ndarray:
    """Grow each core back over the uncut foreground, one pixel ring per step, into pixels
    within ``tolerance_mm`` of the core's mean height (so a box does not grow over the lower
    neighbour beside a step). Where two cores reach a pixel at once the higher label takes it:
    at most one pixel of the groove between them goes the wrong way."""
    count = int(cores.max()) + 1
    inside = cores >= 0  # a core's mean height: its cut-free top, noise averaged out
    total = np.bincount(cores[inside], weights=heights[inside], minlength=count)
    level = total / np.maximum(np.bincount(cores[inside], minlength=count), 1)
    # Only foreground pixels without a label can change, a thin band along the cuts, so each
    # ring reads just their 3 x 3 neighbourhoods (the highest label among them, as a 3 x 3
    # maximum filter would give) from a copy with a border of -1 (no label beyond the image).
    nx, ny = cores.shape
    wide = ny + 2
    labelled = np.full((nx + 2, wide), -1, dtype=cores.dtype)
    labelled[1:-1, 1:-1] = cores
    flat = labelled.ravel()
    free_x, free_y = np.nonzero(foreground & ~inside)
    free = (free_x + 1) * wide + free_y + 1  # flat indices into the bordered copy
    free_heights = heights[free_x, free_y]
    ring = np.array([dx * wide + dy for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
    for _ in range(steps):
        grown = flat[free[:, None] + ring].max(axis=1)
        take = grown >= 0
        take &= np.abs(free_heights - level[np.maximum(grown, 0)]) <= tolerance_mm
        if not take.any():
            break
        flat[free[take]] = grown[take]  # every pixel of this ring read the ring before it
        free, free_heights = free[~take], free_heights[~take]
    return labelled[1:-1, 1:-1].copy()


def size_quanta(prior: SizePrior, cell_xy_mm: int, cell_z_mm: int) -> tuple[int, int]:
    """(l and w quantum, h quantum) mm the estimates snap to under the size prior
    (``core.choices.SizePrior``). ``grid`` snaps l and w to the container's horizontal cell and
    h to its height step (``_snap``: the nearest multiple, ties to even, at least one quantum),
    the grids every generated case's sizes lie on: a prior of the generator, not of real
    cartons. ``none`` assumes nothing: the raw estimates rounded to the nearest whole
    millimetre (the same rounding on a 1 mm quantum: ties to even, at least 1 mm). ValueError
    naming the prior for an unknown one."""
    if prior == "grid":
        return (cell_xy_mm, cell_z_mm)
    if prior == "none":
        return (1, 1)
    raise ValueError(f"size_prior = {prior!r}: unknown; choose one of grid, none")


@dataclass(frozen=True, slots=True)
class EstimatedBox:
    """One segmented object: its estimated size and top-face pose."""

    label: int  # the segment's label
    size_mm: tuple[int, int, int]  # (l, w, h): l along the yaw axis, snapped to the quanta
    raw_size_mm: tuple[float, float, float]  # the same before snapping
    top_centre_mm: tuple[float, float, float]  # centre of the top face, world mm
    yaw_deg: float  # angle of the l axis from world x, degrees in [-90, 90)


def estimate_objects(
    image: DepthImage,
    labels: np.ndarray,
    cell_xy_mm: int = 25,
    cell_z_mm: int = 2,
    table_z_mm: float = 0.0,
) -> list[EstimatedBox]:
    """Size, top centre and yaw of every labelled segment (labels >= 0, in increasing order).

    Height: the median of the segment's heights over the table. Footprint: the minimum-area
    rectangle of the pixel centres, its angle refined by least-squares line fits to the boundary
    pixels of its four sides, its extents from the points projected on the refined axes plus
    one pixel (pixel centres sit half a pixel inside each edge). Sizes snap to ``cell_xy_mm``
    (l, w) and ``cell_z_mm`` (h): the size grid prior by default; ``size_quanta`` gives the
    quanta of each ``SizePrior`` (1 and 1: whole millimetres, no prior).
    """
    xs, ys = image.pixel_centres()
    zs = image.heights_mm()
    out = []
    # One bounding window per label (find_objects numbers from 1), so each object costs its size.
    for index, window in enumerate(ndimage.find_objects(np.maximum(labels + 1, 0))):
        if window is None:
            continue
        mask = (labels[window] == index) & np.isfinite(zs[window])
        if mask.sum() < 3:
            continue
        out.append(
            _estimate_one(
                index,
                mask,
                xs[window],
                ys[window],
                zs[window],
                image.pixel_mm,
                (cell_xy_mm, cell_z_mm),
                table_z_mm,
            )
        )
    return out


def _estimate_one(label, mask, xs, ys, zs, pixel_mm, grid, table_z_mm) -> EstimatedBox:
    """``EstimatedBox`` of one segment given its mask and the pixel coordinates of its window."""
    height = _median_finite(zs[mask]) - table_z_mm
    boundary = _boundary(mask)
    points = np.column_stack([xs[mask], ys[mask]])
    edge_points = np.column_stack([xs[boundary], ys[boundary]])
    yaw, centre, extents = _rectangle(points, edge_points, pixel_mm)
    raw = (float(extents[0]), float(extents[1]), height)
    snapped = (_snap(raw[0], grid[0]), _snap(raw[1], grid[0]), _snap(height, grid[1]))
    top = (float(centre[0]), float(centre[1]), height + table_z_mm)
    return EstimatedBox(int(label), snapped, raw, top, float(np.degrees(yaw)))


def _boundary(mask: np.ndarray) -> np.ndarray:
    """The pixels of ``mask`` (2-D bool) with a 4-neighbour outside it, the window's border
    counting as outside: ``mask`` less its erosion by the 4-neighbour cross."""
    padded = np.pad(mask, 1)
    inner = padded[:-2, 1:-1] & padded[2:, 1:-1]
    inner &= padded[1:-1, :-2]
    inner &= padded[1:-1, 2:]
    return mask & ~inner


#: The reductions behind ``ndarray.sum`` / ``mean``, ``min`` and ``max`` (and ``np.ptp``),
#: called directly: the same sums and extremes, bit for bit, without the methods' Python layer
#: (most of the time on the few dozen points of one box side).
_sum, _least, _most = np.add.reduce, np.minimum.reduce, np.maximum.reduce


def _median_count(counts: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D integer array: the middle value, or the mean of the
    two middle ones (their sum in float64, halved), as ``np.median`` computes it."""
    ordered = np.sort(counts)
    middle = len(ordered) // 2
    if len(ordered) % 2:
        return float(ordered[middle])
    return (float(ordered[middle - 1]) + float(ordered[middle])) / 2.0


def _median_finite(values: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D float array without NaN: the middle value, or the
    two middle ones added and halved, as ``np.median`` computes it (a partition, then their
    mean)."""
    middle = len(values) // 2
    if len(values) % 2:
        return float(np.partition(values, middle)[middle])
    part = np.partition(values, (middle - 1, middle))
    return float((part[middle - 1] + part[middle]) / 2.0)


def _snap(value: float, quantum: int) -> int:
    return int(max(round(value / quantum), 1) * quantum)


def _rectangle(points: np.ndarray, edge_points: np.ndarray, pixel_mm: float):
    """(yaw rad of the long axis in [-pi/2, pi/2), centre (2,), extents (long, short)) in mm."""
    angle = min_area_rect_angle(edge_points if len(edge_points) >= 3 else points)
    for _ in range(3):  # each fit narrows the band the next one selects its points from
        angle = angle + _edge_refinement(edge_points, angle, pixel_mm)
    axes = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
    local = points @ axes.T
    lo, hi = np.transpose([_robust_span(local[:, axis], pixel_mm) for axis in (0, 1)])
    extents = hi - lo
    centre = ((lo + hi) / 2.0) @ axes
    if extents[1] > extents[0]:  # make axis 0 the long one
        extents = extents[::-1]
        angle += np.pi / 2
    yaw = (angle + np.pi / 2) % np.pi - np.pi / 2
    return yaw, centre, extents


def _robust_span(values: np.ndarray, pixel_mm: float) -> tuple[float, float]:
    """(lo, hi) mm of a segment along one of its axes, from its pixels' coordinates there.

    The coordinates are binned a pixel wide; the span runs from the first to the last bin that
    holds at least half the median count, plus half a pixel on each side (pixel centres sit
    inside the edges). A straight side fills its end bins; a few pixels a noisy or shared
    groove gave to the segment do not, so they cannot widen the box the way they widen its
    minimum-area rectangle (which the estimate used before, and which overstated sizes of
    touching boxes by up to three pixels).
    """
    start = float(_least(values))
    counts = np.bincount(np.floor((values - start) / pixel_mm).astype(np.int64))
    full = np.flatnonzero(counts >= 0.5 * _median_count(counts[counts > 0]))
    # bin i holds the pixel centres in [start + i p, start + (i + 1) p): on a grid-aligned side
    # one column, centred at start + i p
    return start + (full[0] - 0.5) * pixel_mm, start + (full[-1] + 0.5) * pixel_mm


def min_area_rect_angle(points: np.ndarray) -> float:
    """Angle (rad, in [0, pi/2)) of the minimum-area bounding rectangle of 2-D points (m, 2).

    Rotating calipers: the optimal rectangle has a side along an edge of the convex hull, so
    every hull edge's angle is tried at once. Degenerate (collinear) sets give their line's angle.
    """
    try:
        # QJ (joggle): pixel centres lie on a grid, whose many collinear points make exact
        # hulls about three times slower; a 1e-11 relative jitter moves no angle measurably
        hull = points[ConvexHull(points, qhull_options="QJ").vertices]
    except QhullError:
        spread = points - points.mean(axis=0)
        _, _, vt = np.linalg.svd(spread, full_matrices=False)
        return float(np.arctan2(vt[0, 1], vt[0, 0]) % (np.pi / 2))
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.unique(np.arctan2(edges[:, 1], edges[:, 0]) % (np.pi / 2))
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    u = c * hull[:, 0] + s * hull[:, 1]
    v = -s * hull[:, 0] + c * hull[:, 1]
    area = (u.max(axis=1) - u.min(axis=1)) * (v.max(axis=1) - v.min(axis=1))
    return float(angles[int(np.argmin(area))])


def _edge_refinement(edge_points: np.ndarray, angle: float, pixel_mm: float) -> float:
    """Angle correction (rad) from least-squares lines through the boundary pixels of each side.

    The hull's edges join pixel centres of a staircase, so their angle is off by up to a pixel
    over the side's length; a line fitted to all the side's boundary pixels averages the
    staircase out. Points within two pixels of a corner are left out (they belong to two sides).
    """
    c, s = np.cos(angle), np.sin(angle)
    u = c * edge_points[:, 0] + s * edge_points[:, 1]
    v = -s * edge_points[:, 0] + c * edge_points[:, 1]
    # Each coordinate's extremes, read once (the ufuncs' reductions: what ``min``, ``max``,
    # ``ptp`` and ``mean`` compute, without their Python wrappers).
    low, high = {0: _least(u), 1: _least(v)}, {0: _most(u), 1: _most(v)}
    corrections, weights = [], []
    for k, (along, across, sign) in enumerate(((u, v, 1.0), (v, u, -1.0))):
        inner = (along > low[k] + 2 * pixel_mm) & (along < high[k] - 2 * pixel_mm)
        band = 1.5 * pixel_mm  # a staircase's boundary pixels lie within sqrt(2) pixels
        for side in (across <= low[1 - k] + band, across >= high[1 - k] - band):
            sel = side & inner
            a, b = along[sel], across[sel]
            if len(a) < 3 or _most(a) - _least(a) <= 0:
                continue
            a = a - _sum(a) / a.size
            # least-squares line b = slope * a + c
            slope = float(a @ (b - _sum(b) / b.size) / (a @ a))
            corrections.append(sign * np.arctan(slope))
            weights.append(float(len(a)))
    if not weights:
        return 0.0
    return float(np.average(corrections, weights=weights))
