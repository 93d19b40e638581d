"""From a calibrated depth image to packlab's top-down view: back-projection, frames, resampling.

Conventions (docs/cell.md, "Frames"):

- **Camera frame** (OpenCV's): x to the right of the image, y down the image, z along the
  optical axis, mm. A depth image is an array (height, width): row v, column u. A pixel's depth
  is its point's z in the camera frame (not the length of its ray), as depth cameras report it.
- **Pinhole**: pixel (v, u) with depth d is the point ((u - cx) d / fx, (v - cy) d / fy, d);
  pixel centres sit at whole (u, v).
- **Orthographic** (a depth camera re-projected to a virtual top-down view, and packlab's own
  simulated cameras): pixel (v, u) with depth d is ((u - cx) p, (v - cy) p, d), p the pixel
  pitch in mm; (cx, cy) default to the image's centre, ((width - 1) / 2, (height - 1) / 2).
- **Pose**: the camera-to-frame transform, a point p_frame = R p_camera + t. The frame is the
  container's (origin at the inner floor corner of heightmap cell (0, 0), x along the
  container's first side, y along its second, z up) for the container camera, and the buffer
  table's (z up, the table's surface at z = 0) for the buffer camera.

The points then go to a top-down orthographic ``DepthImage`` (``packlab.sim.sensing.camera``),
so the heightmap and the segmentation are packlab's own functions on the image they were made
for. An orthographic camera looking straight down with packlab's axes (:data:`TOP_DOWN`: image
rows along x, columns along y) *is* such an image and is used as it is: no resampling, so a
packlab-rendered image gives exactly the simulator's perception. Any other camera's points are
binned into a virtual top-down image, each pixel the mean height of its points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from packlab.cell.errors import CellInputError
from packlab.core.types import Container
from packlab.sim.heightmap import quat_to_matrix
from packlab.sim.sensing.camera import MAX_BUFFER_PIXELS, DepthImage
from packlab.sim.sensing.perception import heightmap_from_depth

#: How far (per entry) a pose's rotation may be from orthonormal, and a quaternion's norm from 1:
#: a calibration written with 4 to 6 decimals passes, a scaled or sheared matrix does not.
RIGID_TOLERANCE = 1e-3
#: The orientation of packlab's simulated cameras (camera -> frame): looking down (-z), image
#: rows (camera y) along the frame's x, columns (camera x) along its y.
TOP_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Virtual top-down pixels per heightmap cell side: odd, so one pixel lies on each cell centre
#: (the rule of ``heightmap_from_depth``'s median, see ``packlab.sim.sensing.presets``).
PIXELS_PER_CELL = 5
#: A virtual pixel is at least this much coarser than the camera's own ground sampling, so that
#: nearly every one of them receives a point (the rest are filled from their neighbours).
RESAMPLE_MARGIN = 1.5


@dataclass(frozen=True, slots=True)
class Pinhole:
    """A pinhole camera's intrinsics (pixels), as OpenCV's camera matrix gives them."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int


@dataclass(frozen=True, slots=True)
class Orthographic:
    """An orthographic camera: parallel rays, ``pixel_mm`` apart on every plane."""

    pixel_mm: float
    width: int
    height: int
    cx: float | None = None  # None: the image's centre column, (width - 1) / 2
    cy: float | None = None  # None: the image's centre row, (height - 1) / 2

    @property
    def centre(self) -> tuple[float, float]:
        cx = (self.width - 1) / 2 if self.cx is None else self.cx
        cy = (self.height - 1) / 2 if self.cy is None else self.cy
        return cx, cy


Intrinsics = Pinhole | Orthographic


@dataclass(frozen=True, slots=True)
class Calibration:
    """One camera: its intrinsics and its pose in the frame its points are wanted in."""

    intrinsics: Intrinsics
    rotation: np.ndarray  # (3, 3) float64, camera -> frame, orthonormal with det +1
    translation_mm: np.ndarray  # (3,) float64, the camera's origin in the frame, mm

    @property
    def image_shape(self) -> tuple[int, int]:
        """The (height, width) its depth images must have."""
        return self.intrinsics.height, self.intrinsics.width


def rigid_rotation(rotation: np.ndarray, field: str) -> np.ndarray:
    """``rotation`` (3, 3) when it is a proper rotation (to :data:`RIGID_TOLERANCE`), else a
    ``CellInputError`` naming ``field``; re-orthonormalised, so rounding in a calibration file
    does not shear the points."""
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.all(np.abs(r) <= 1.0 + RIGID_TOLERANCE):  # NaN fails too
        raise CellInputError(field, r.tolist(), "not a rigid rotation (an entry beyond [-1, 1])")
    if np.abs(r.T @ r - np.eye(3)).max() > RIGID_TOLERANCE or np.linalg.det(r) < 0:
        raise CellInputError(
            field, np.round(r, 6).tolist(), "not a rigid rotation (R^T R != I or det(R) != +1)"
        )
    u, _, vt = np.linalg.svd(r)
    return u @ vt


def pose_from_matrix(matrix: np.ndarray, field: str) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, translation) of a 4 x 4 homogeneous camera-to-frame transform."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise CellInputError(field, m.tolist(), "need a finite 4 x 4 matrix")
    if np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > RIGID_TOLERANCE:
        raise CellInputError(f"{field}[3]", m[3].tolist(), "the last row must be [0, 0, 0, 1]")
    return rigid_rotation(m[:3, :3], field), m[:3, 3].copy()


def pose_from_quaternion(
    translation_mm: np.ndarray, quaternion_wxyz: np.ndarray, field: str
) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, translation) of a translation and a unit quaternion (w, x, y, z)."""
    q = np.asarray(quaternion_wxyz, dtype=np.float64)
    norm = float(np.linalg.norm(q)) if q.shape == (4,) else 0.0
    if not np.isfinite(norm) or abs(norm - 1.0) > RIGID_TOLERANCE:
        raise CellInputError(field, q.tolist(), "not a unit quaternion (w, x, y, z)")
    return quat_to_matrix(q / norm), np.asarray(translation_mm, dtype=np.float64).copy()


Points = tuple[np.ndarray, np.ndarray, np.ndarray]


def camera_points(depth_mm: np.ndarray, intrinsics: Intrinsics) -> Points:
    """Camera-frame (x, y, z) of every pixel of ``depth_mm`` (height, width), each an array of
    the image's shape, float64 mm; NaN where the pixel has no depth."""
    h, w = depth_mm.shape
    z = np.asarray(depth_mm, dtype=np.float64)
    if isinstance(intrinsics, Pinhole):
        across = (np.arange(w) - intrinsics.cx) / intrinsics.fx  # x / z per column
        down = (np.arange(h) - intrinsics.cy) / intrinsics.fy  # y / z per row
        return across[None, :] * z, down[:, None] * z, z
    cx, cy = intrinsics.centre
    p = intrinsics.pixel_mm
    x = np.broadcast_to((np.arange(w) - cx) * p, (h, w))
    y = np.broadcast_to(((np.arange(h) - cy) * p)[:, None], (h, w))
    return x, y, z


def frame_points(depth_mm: np.ndarray, calibration: Calibration) -> Points:
    """(x, y, z) in the calibration's frame of every pixel (NaN: no depth), mm.

    Written out per row of the rotation rather than as a matrix product: on a busy machine a
    BLAS call on a million points took up to 30 times longer than these nine array passes.
    """
    camera = camera_points(depth_mm, calibration.intrinsics)
    r, t = calibration.rotation, calibration.translation_mm
    out = []
    for row in range(3):
        axis = camera[0] * r[row, 0]
        axis += camera[1] * r[row, 1]
        axis += camera[2] * r[row, 2]
        axis += t[row]
        out.append(axis)
    return out[0], out[1], out[2]


def direct_image(depth_mm: np.ndarray, calibration: Calibration) -> DepthImage | None:
    """The depth image as packlab's ``DepthImage`` when the camera is orthographic and looks
    straight down with packlab's axes (:data:`TOP_DOWN`), else None (it needs resampling)."""
    intrinsics = calibration.intrinsics
    if not isinstance(intrinsics, Orthographic):
        return None
    if np.abs(calibration.rotation - TOP_DOWN).max() > 1e-9:
        return None
    cx, cy = intrinsics.centre
    p = intrinsics.pixel_mm
    tx, ty, tz = (float(v) for v in calibration.translation_mm)
    origin = (_snap(tx - (cy + 0.5) * p), _snap(ty - (cx + 0.5) * p))
    ids = np.full(depth_mm.shape, -1, dtype=np.int32)  # a real camera sees no object ids
    return DepthImage(depth_mm.astype(np.float64), ids, origin, float(p), tz)


def _snap(value: float) -> float:
    """``value``, or the whole mm within a picometre of it (float rounding of a calibration
    centred on its image): an image whose corner is the container's origin then has origin
    (0, 0) exactly, the heightmap's fast path (cells of whole pixels)."""
    whole = round(value)
    return float(whole) if abs(value - whole) < 1e-9 else value


def top_down_image(
    points: Points, extent_mm: tuple[float, float, float, float], pixel_mm: float
) -> DepthImage:
    """A virtual top-down ``DepthImage`` over ``extent_mm = (x0, y0, x1, y1)``: each pixel the
    mean height of the ``points`` (x, y, z arrays; NaN: none) over it, NaN where none fell and
    too few of its eight neighbours had one (:func:`fill_pinholes`). The virtual camera sits
    at z = 0, so a pixel's depth is minus its height."""
    x0, y0, x1, y1 = extent_mm
    nx = max(int(np.ceil((x1 - x0) / pixel_mm - 1e-9)), 1)
    ny = max(int(np.ceil((y1 - y0) / pixel_mm - 1e-9)), 1)
    xs, ys, zs = (np.ravel(a) for a in points)
    i = np.floor((xs - x0) / pixel_mm)
    j = np.floor((ys - y0) / pixel_mm)
    keep = np.isfinite(zs) & (i >= 0) & (i < nx) & (j >= 0) & (j < ny)  # NaN compares False
    key = (i[keep] * ny + j[keep]).astype(np.int64)
    # The mean, not the highest: a sensor's noise would bias a maximum upward by about a sigma.
    counts = np.bincount(key, minlength=nx * ny).reshape(nx, ny)
    sums = np.bincount(key, weights=zs[keep], minlength=nx * ny).reshape(nx, ny)
    heights = fill_pinholes(sums, counts)
    ids = np.full((nx, ny), -1, dtype=np.int32)
    return DepthImage(-heights, ids, (float(x0), float(y0)), float(pixel_mm), 0.0)


def fill_pinholes(sums: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Per-pixel means ``sums / counts`` (nx, ny); a pixel without points takes the mean of its
    3 x 3 neighbourhood's points when at least three neighbours have some. Resampling leaves
    such single empty pixels where the camera's pixels and the virtual ones beat; an occluded
    region (behind a tall box, seen slanted) stays empty but for its rim."""
    with np.errstate(invalid="ignore", divide="ignore"):
        heights = sums / counts
    empty = counts == 0
    if not empty.any():
        return heights
    near_sum = ndimage.uniform_filter(sums, size=3, mode="constant") * 9
    near_count = ndimage.uniform_filter(counts.astype(np.float64), size=3, mode="constant") * 9
    has = ndimage.uniform_filter((~empty).astype(np.float64), size=3, mode="constant") * 9
    fill = empty & (has > 2.5)
    heights[fill] = near_sum[fill] / near_count[fill]
    return heights


def ground_sampling_mm(depth_mm: np.ndarray, intrinsics: Intrinsics) -> float:
    """The camera's pixel footprint (mm) at its median depth: what a virtual pixel must exceed."""
    if isinstance(intrinsics, Orthographic):
        return float(intrinsics.pixel_mm)
    valid = depth_mm[np.isfinite(depth_mm)]
    median = float(np.median(valid)) if valid.size else 0.0
    return median / min(intrinsics.fx, intrinsics.fy)


def container_image(
    depth_mm: np.ndarray, calibration: Calibration, container: Container
) -> DepthImage:
    """The container camera's image as a top-down ``DepthImage`` of the container's frame."""
    direct = direct_image(depth_mm, calibration)
    if direct is not None:
        return direct
    x, y, _ = container.size_mm
    pixel = container.cell_xy_mm / PIXELS_PER_CELL
    return top_down_image(frame_points(depth_mm, calibration), (0.0, 0.0, x, y), pixel)


def buffer_image(depth_mm: np.ndarray, calibration: Calibration, min_pixel_mm: float) -> DepthImage:
    """The buffer camera's image as a top-down ``DepthImage`` of the table's frame: as it is
    (:func:`direct_image`), else resampled over the points' extent at the camera's own ground
    sampling (times :data:`RESAMPLE_MARGIN`, at least ``min_pixel_mm``), coarser where that would
    pass packlab's pixel budget for a buffer image (``MAX_BUFFER_PIXELS``)."""
    direct = direct_image(depth_mm, calibration)
    if direct is not None:
        return direct
    points = frame_points(depth_mm, calibration)
    if not np.isfinite(points[2]).any():
        return top_down_image(points, (0.0, 0.0, 1.0, 1.0), 1.0)
    lo = [float(np.nanmin(a)) for a in points[:2]]
    hi = [float(np.nanmax(a)) for a in points[:2]]
    area = max(hi[0] - lo[0], 1.0) * max(hi[1] - lo[1], 1.0)
    sampling = ground_sampling_mm(depth_mm, calibration.intrinsics) * RESAMPLE_MARGIN
    pixel = max(sampling, min_pixel_mm, float(np.sqrt(area / MAX_BUFFER_PIXELS)))
    return top_down_image(points, (lo[0], lo[1], hi[0] + pixel, hi[1] + pixel), pixel)


def container_heightmap(
    image: DepthImage, container: Container, flat_tolerance_mm: float
) -> tuple[np.ndarray, int]:
    """(heightmap (x_cells, y_cells) int32 mm, cells no pixel saw) from a top-down image of the
    container: packlab's ``heightmap_from_depth`` (the median per cell, unseen cells from their
    nearest seen one, flat tops flattened)."""
    heightmap = heightmap_from_depth(image, container, flat_tolerance_mm=flat_tolerance_mm)
    return heightmap, unseen_cells(image, container)


def unseen_cells(image: DepthImage, container: Container) -> int:
    """How many heightmap cells have no valid pixel over them (their height is a neighbour's)."""
    nx, ny = container.cells
    k = container.cell_xy_mm / image.pixel_mm
    if image.origin_mm == (0.0, 0.0) and k == int(k) and image.shape == (nx * k, ny * k):
        # Cells of whole pixels (packlab's own cameras): a block reduction, no binning.
        k = int(k)
        valid = np.isfinite(image.depth_mm).reshape(nx, k, ny, k)
        return int(np.count_nonzero(~valid.any(axis=(1, 3))))
    xs, ys = image.pixel_centres()
    ci = np.floor(xs / container.cell_xy_mm).astype(np.int64)
    cj = np.floor(ys / container.cell_xy_mm).astype(np.int64)
    keep = np.isfinite(image.depth_mm) & (ci >= 0) & (ci < nx) & (cj >= 0) & (cj < ny)
    seen = np.bincount((ci * ny + cj)[keep], minlength=nx * ny)
    return int(np.count_nonzero(seen == 0))


__all__ = [
    "PIXELS_PER_CELL",
    "RIGID_TOLERANCE",
    "TOP_DOWN",
    "Calibration",
    "Intrinsics",
    "Orthographic",
    "Pinhole",
    "buffer_image",
    "camera_points",
    "container_heightmap",
    "container_image",
    "direct_image",
    "fill_pinholes",
    "frame_points",
    "ground_sampling_mm",
    "pose_from_matrix",
    "pose_from_quaternion",
    "rigid_rotation",
    "top_down_image",
    "unseen_cells",
]
