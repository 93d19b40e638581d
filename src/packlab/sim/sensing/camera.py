"""Top-down depth cameras by vectorised ray casting against posed boxes (no OpenGL).

The camera is orthographic: one vertical ray per pixel, pointing down (-z) from the camera plane
at ``camera_z_mm``. Intrinsics are therefore the pixel pitch on the ground (``pixel_mm``) and the
imaged rectangle (``origin_mm`` and the image shape); pixel (i, j) looks at the world point
``origin + ((i + 0.5) * pixel_mm, (j + 0.5) * pixel_mm)``. Image axes follow the heightmap's
convention: axis 0 is world x, axis 1 is world y. An orthographic model is what a calibrated
top-down depth camera delivers after the usual re-projection to a virtual orthographic view
(the "orthographic heightmap" of bin-picking pipelines), and it sees only upward-facing
surfaces, so box sides cannot leak into the heightmap. Rays that hit no box see the floor or
table at z = 0; the container walls lie outside the imaged rectangle (its interior).

Each box is tested only against the pixels under its planar extent, with the same exact slab test
the rasteriser uses (``packlab.sim.heightmap.box_top_over_cells``), so tilted boxes are exact too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.types import Container
from packlab.sim.heightmap import box_top_over_cells, quat_to_matrix
from packlab.sim.sensing.presets import SensorPreset


@dataclass(frozen=True, slots=True)
class DepthImage:
    """A top-down orthographic depth image with per-pixel ground-truth object ids."""

    depth_mm: np.ndarray  # (nx, ny) float64 mm below the camera plane; NaN = missing pixel
    ids: np.ndarray  # (nx, ny) int32 index of the box seen (its row in the scene), -1 floor/table
    origin_mm: tuple[float, float]  # world (x, y) of the outer corner of pixel (0, 0)
    pixel_mm: float  # pixel pitch on the ground, both axes
    camera_z_mm: float  # world z of the camera plane

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth_mm.shape  # type: ignore[return-value]

    def pixel_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """World x and y (mm) of every pixel's ray, each (nx, ny) float64."""
        nx, ny = self.shape
        xs = self.origin_mm[0] + (np.arange(nx) + 0.5) * self.pixel_mm
        ys = self.origin_mm[1] + (np.arange(ny) + 0.5) * self.pixel_mm
        return np.meshgrid(xs, ys, indexing="ij")

    def heights_mm(self) -> np.ndarray:
        """World z (mm) of each pixel's surface point (back-projection), (nx, ny); NaN missing."""
        return self.camera_z_mm - self.depth_mm


def render_depth(
    sizes_mm: np.ndarray,
    positions_mm: np.ndarray,
    quaternions: np.ndarray,
    extent_mm: tuple[float, float, float, float],
    pixel_mm: float,
    camera_z_mm: float,
    bevel_mm: float = 0.0,
) -> DepthImage:
    """Ray-cast a noise-free depth image of posed boxes over ``extent_mm = (x0, y0, x1, y1)``.

    ``sizes_mm`` (n, 3) are the boxes' own (l, w, h), ``positions_mm`` (n, 3) their centres and
    ``quaternions`` (n, 4) (w, x, y, z): the arrays ``backend.poses()`` returns. Rows with a NaN
    position (boxes not placed yet) are skipped. The image covers the extent with square pixels
    of ``pixel_mm`` (the count rounds up). ``bevel_mm`` > 0 rounds the top edges of upright
    boxes (a 45-degree chamfer that deep and wide): a carton's folded edges, which is what makes
    the seam between two touching boxes of one height visible to a depth camera.
    """
    x0, y0, x1, y1 = extent_mm
    nx = max(int(np.ceil((x1 - x0) / pixel_mm - 1e-9)), 1)
    ny = max(int(np.ceil((y1 - y0) / pixel_mm - 1e-9)), 1)
    top = np.zeros((nx, ny), dtype=np.float64)  # the floor / table plane is z = 0
    ids = np.full((nx, ny), -1, dtype=np.int32)
    for index, (size, position, quat) in enumerate(zip(sizes_mm, positions_mm, quaternions)):
        if not np.all(np.isfinite(position)):
            continue
        _cast_box(
            top,
            ids,
            index,
            np.asarray(size, float),
            np.asarray(position, float),
            quat,
            (x0, y0),
            pixel_mm,
            bevel_mm,
        )
    return DepthImage(camera_z_mm - top, ids, (float(x0), float(y0)), float(pixel_mm), camera_z_mm)


def _cast_box(top, ids, index, size, position, quat, origin, pixel_mm, bevel_mm=0.0) -> None:
    """Raise ``top`` (and set ``ids``) in place where this box's top is the highest surface."""
    nx, ny = top.shape
    rot = quat_to_matrix(quat)
    half = size / 2.0
    extent = np.abs(rot[:2, :]) @ half
    i0 = max(int(np.floor((position[0] - extent[0] - origin[0]) / pixel_mm)), 0)
    i1 = min(int(np.ceil((position[0] + extent[0] - origin[0]) / pixel_mm)), nx)
    j0 = max(int(np.floor((position[1] - extent[1] - origin[1]) / pixel_mm)), 0)
    j1 = min(int(np.ceil((position[1] + extent[1] - origin[1]) / pixel_mm)), ny)
    if i0 >= i1 or j0 >= j1:
        return
    gx = origin[0] + (np.arange(i0, i1) + 0.5)[:, None] * pixel_mm  # (wx, 1)
    gy = origin[1] + (np.arange(j0, j1) + 0.5)[None, :] * pixel_mm  # (1, wy)
    if rot[2, 2] > 1.0 - 1e-12:  # upright (yaw only): the top is flat, a rectangle test will do
        u = rot[0, 0] * (gx - position[0]) + rot[1, 0] * (gy - position[1])
        v = rot[0, 1] * (gx - position[0]) + rot[1, 1] * (gy - position[1])
        inside = (np.abs(u) <= half[0]) & (np.abs(v) <= half[1])
        hit = np.where(inside, position[2] + half[2], np.nan)
        if bevel_mm > 0:  # depth below the top: bevel minus the distance to the nearest edge
            edge = np.minimum(half[0] - np.abs(u), half[1] - np.abs(v))
            hit = hit - np.clip(bevel_mm - edge, 0.0, bevel_mm)
    else:
        gx, gy = np.broadcast_arrays(gx, gy)
        hit = box_top_over_cells(position, rot, half, gx, gy)
    window = top[i0:i1, j0:j1]
    higher = hit > window  # NaN (a miss) compares False
    window[higher] = hit[higher]
    ids[i0:i1, j0:j1][higher] = index


def container_camera(
    container: Container,
    sizes_mm: np.ndarray,
    positions_mm: np.ndarray,
    quaternions: np.ndarray,
    preset: SensorPreset,
) -> DepthImage:
    """The noise-free depth image over the container's interior, camera above the rim."""
    x, y, z = container.size_mm
    return render_depth(
        sizes_mm,
        positions_mm,
        quaternions,
        (0.0, 0.0, float(x), float(y)),
        preset.pixel_mm,
        float(z) + preset.camera_height_mm,
    )


def depth_edges(image: DepthImage) -> np.ndarray:
    """(nx, ny) bool: pixels with a 4-neighbour that sees another surface (box or floor).

    These are the pixels real sensors lose: mixed depths across the discontinuity, projector
    shadows (structured light) and failed matches in one view's occlusion (stereo). A box's own
    top is continuous, so a change of id is a change of surface.
    """
    ids = image.ids
    edge = np.zeros(ids.shape, dtype=bool)
    jump = ids[1:, :] != ids[:-1, :]
    edge[1:, :] |= jump
    edge[:-1, :] |= jump
    jump = ids[:, 1:] != ids[:, :-1]
    edge[:, 1:] |= jump
    edge[:, :-1] |= jump
    return edge


def add_sensor_noise(
    image: DepthImage, preset: SensorPreset, rng: np.random.Generator
) -> DepthImage:
    """The image as the preset's sensor returns it: Gaussian noise, edge dropout, quantisation.

    The random draws do not depend on the preset (one standard normal per pixel, one uniform
    per edge pixel), so on one seed a larger preset is the same noise scaled and drops a
    superset of the pixels: errors grow monotonically. A noise-free preset draws nothing. The
    ids (ground-truth masks) are left as they are.
    """
    if preset.depth_noise_mm == 0 and preset.edge_dropout == 0 and preset.quantisation_mm == 0:
        return image  # noise-free: nothing to draw (callers give each image its own rng)
    normal = rng.standard_normal(image.shape, dtype=np.float32)
    edges = np.flatnonzero(depth_edges(image))
    uniform = rng.random(len(edges), dtype=np.float32)
    depth = image.depth_mm + preset.depth_noise_mm * normal
    if preset.quantisation_mm > 0:
        depth = np.round(depth / preset.quantisation_mm) * preset.quantisation_mm
    depth.ravel()[edges[uniform < preset.edge_dropout]] = np.nan
    return replace(image, depth_mm=depth)


#: Depth and width (mm) of the rounded top edges of the cartons on the buffer (``render_depth``'s
#: ``bevel_mm``): a folded carton edge is a few mm round, which leaves a groove of about twice
#: this width between two touching boxes. The container image leaves it out: its heightmap
#: takes each 25 mm cell's median, which a few mm of rounded edge do not move.
CARTON_BEVEL_MM = 6.0


@dataclass(frozen=True, slots=True)
class BufferScene:
    """Shown objects lying on a table (z = 0) at random positions and yaws."""

    positions_mm: np.ndarray  # (k, 3) float64 box centres, mm
    quaternions: np.ndarray  # (k, 4) float64 (w, x, y, z), yaw only
    yaws_rad: np.ndarray  # (k,) float64 yaw of each box's l axis from world x, radians
    extent_mm: tuple[float, float, float, float]  # the table (x0, y0, x1, y1), mm


def layout_buffer(
    sizes_mm: np.ndarray, rng: np.random.Generator, arrangement: str = "touching"
) -> BufferScene:
    """Lay the shown boxes on a table, resting on their bottom face.

    ``touching`` (the default, what a robot cell meets): the boxes lie against each other as in
    a tote or on an accumulating conveyor, square to its sides within a few degrees, so the
    segmentation has to split them (``_touching_centres``). ``apart``: each box in its own slot
    at a random yaw, at least 40 mm from the next (the easy case, kept as an ablation).
    """
    sizes = np.asarray(sizes_mm, dtype=np.float64).reshape(-1, 3)
    if arrangement == "touching":
        centres, yaws, extent = _touching_centres(sizes, rng)
    elif arrangement == "apart":
        centres, yaws, extent = _apart_centres(sizes, rng, gap_mm=40.0)
    else:
        raise ConfigError(f"buffer arrangement = {arrangement!r}: choose touching or apart")
    k = len(sizes)
    positions = np.column_stack([centres, sizes[:, 2] / 2.0])
    quats = np.column_stack([np.cos(yaws / 2), np.zeros(k), np.zeros(k), np.sin(yaws / 2)])
    return BufferScene(positions, quats, yaws, extent)


def _touching_centres(sizes: np.ndarray, rng: np.random.Generator):
    """(centres (k, 2), yaws (k,), extent) of boxes pushed together in a tote.

    Each box is turned 0 or 90 degrees plus a small error (sigma 2, at most 6 degrees) and
    placed in a random order left to right, each against the one before it; a row that would
    pass the tote's width starts again at the left, and every box slides down (-y) until it
    meets a box of an earlier row (a 1-D skyline), so boxes touch in x and in y.
    """
    k = len(sizes)
    turn = rng.integers(0, 2, size=k) * (np.pi / 2)
    yaws = turn + np.clip(rng.normal(0.0, np.radians(2.0), size=k), -np.radians(6), np.radians(6))
    c, s = np.abs(np.cos(yaws)), np.abs(np.sin(yaws))
    l, w = sizes[:, 0], sizes[:, 1]
    extents = np.column_stack([c * l + s * w, s * l + c * w])
    widest = float(extents[:, 0].max(initial=0.0))
    width = max(float(np.sqrt(np.sum(extents[:, 0] * extents[:, 1]))), widest)
    centres = np.zeros((k, 2))
    placed: list[tuple[float, float, float]] = []  # (x0, x1, top y) of each box so far
    x = 0.0
    for i in rng.permutation(k):
        if x > 0 and x + extents[i, 0] > width + 1e-9:
            x = 0.0
        x1 = x + extents[i, 0]
        y = max((top for a, b, top in placed if a < x1 - 1e-6 and b > x + 1e-6), default=0.0)
        centres[i] = (x + extents[i, 0] / 2, y + extents[i, 1] / 2)
        placed.append((x, x1, y + extents[i, 1]))
        x = x1
    far = np.max(centres + extents / 2, axis=0) if k else np.ones(2)
    return centres, yaws, (0.0, 0.0, max(float(far[0]), 1.0), max(float(far[1]), 1.0))


def _apart_centres(sizes: np.ndarray, rng: np.random.Generator, gap_mm: float):
    """(centres (k, 2), yaws (k,), extent) of boxes in separate slots, ``gap_mm`` apart or more.

    Each box gets a square slot of its footprint diagonal plus ``2 * gap_mm`` (room for any
    yaw); slots are shelved in a random order, left to right in rows about as wide as the table
    is deep, and each box is shifted by up to ``gap_mm / 2`` inside its slot.
    """
    k = len(sizes)
    slots = np.hypot(sizes[:, 0], sizes[:, 1]) + 2 * gap_mm
    row_width = max(float(np.sqrt(np.sum(slots**2))), float(slots.max(initial=0.0)))
    centres = np.zeros((k, 2))
    x = y = row_depth = width = 0.0
    for i in rng.permutation(k):
        if x > 0 and x + slots[i] > row_width:
            x, y, row_depth = 0.0, y + row_depth, 0.0
        centres[i] = (x + slots[i] / 2, y + slots[i] / 2)
        x += slots[i]
        row_depth = max(row_depth, slots[i])
        width = max(width, x)
    yaws = rng.uniform(-np.pi, np.pi, size=k)
    centres += rng.uniform(-gap_mm / 2, gap_mm / 2, size=(k, 2))
    return centres, yaws, (0.0, 0.0, max(width, 1.0), max(y + row_depth, 1.0))


#: The buffer camera's pixel budget: a tote of large boxes is imaged at a coarser pitch than
#: the preset's finest, so that one look costs about the same whatever the boxes' sizes.
MAX_BUFFER_PIXELS = 80_000


def buffer_pixel_mm(scene: BufferScene, preset: SensorPreset) -> float:
    """The buffer camera's pitch: the preset's ``buffer_pixel_mm``, coarser for a large tote."""
    x0, y0, x1, y1 = scene.extent_mm
    return max(preset.buffer_pixel_mm, float(np.sqrt((x1 - x0) * (y1 - y0) / MAX_BUFFER_PIXELS)))


def buffer_camera(sizes_mm: np.ndarray, scene: BufferScene, preset: SensorPreset) -> DepthImage:
    """The noise-free depth image of the whole buffer table (pitch ``buffer_pixel_mm``), with a
    margin of table around the boxes and their edges rounded (``CARTON_BEVEL_MM``)."""
    x0, y0, x1, y1 = scene.extent_mm
    pixel = buffer_pixel_mm(scene, preset)
    margin = 4 * pixel
    return render_depth(
        np.asarray(sizes_mm, dtype=np.float64).reshape(-1, 3),
        scene.positions_mm,
        scene.quaternions,
        (x0 - margin, y0 - margin, x1 + margin, y1 + margin),
        pixel,
        preset.camera_height_mm,
        bevel_mm=CARTON_BEVEL_MM,
    )
