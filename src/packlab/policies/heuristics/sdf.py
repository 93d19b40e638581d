"""SDF-Pack: low resting height plus a snug fit, measured on a distance field of the occupancy.

Score of a candidate (lower is better), all terms in mm:

    z  +  SDF_WEIGHT * mean_gap  +  SIZE_PENALTY_MM * (1 - volume / largest shown volume)

- z is the resting height (paper Eq. 2).
- mean_gap is the mean, over the box's surface voxels, of the truncated distance to the nearest
  occupied surface. The occupancy is a voxel grid of the current state with cubic voxels of the
  horizontal cell size: heightmap columns (a voxel is solid when its centre is below the column
  top), the floor, and the four walls up to the container height. A Euclidean distance
  transform of that occupancy gives, for every free voxel, the distance between voxel centres
  to the nearest solid one (what scipy.ndimage.distance_transform_edt returns; the column
  structure lets :func:`gap_field` compute it separably and faster); the gap is that minus one
  voxel (adjacent voxels touch: gap 0), truncated at TRUNCATION_MM so surfaces farther than
  that count alike.
  The box occupies the layers whose centres lie in [z, z + h). Its surface voxels are its bottom
  layer and its four side faces; the top face is left out because nothing can be above a box
  that is just being placed, so its distance says nothing about fit. Sums over any box come
  from one 3-D summed-volume table, so all candidates are scored with a few gathers.
  This is the positive (outside) branch of a signed distance field: by Eq. 2 a candidate never
  intersects the occupancy, so the negative branch is never sampled.
- The size term is a small penalty, at most SIZE_PENALTY_MM, that prefers the larger shown
  objects when placements are otherwise about equal (packing big boxes first leaves small ones
  to fill gaps later).

Weights, and why: SDF_WEIGHT = 1 compares a millimetre of average gap around the box with a
millimetre of extra height one to one, since both are lengths and neither is privileged. The
truncation (100 mm, four cells) is about the smallest box side: a gap wider than that can take
another box, so it is no longer "a gap". The size penalty (10 mm) is a fraction of a cell, so it
decides between near-equal placements only. These were set from those arguments, not tuned.

Ties (exact after rounding scores to 1e-6 mm): the DBLF order, lower z, then smaller x, then
smaller y; then the tie-break rule (default: the larger object; ``tie_break="shown_order"``:
the first shown). The shared rim rule of :mod:`packlab.policies.heuristics.select`
applies first.
"""

from __future__ import annotations

import numpy as np

from packlab.core.feasibility import CandidateSet
from packlab.policies.heuristics.select import Keys, quantise, rim_pool

NAME = "sdf"

#: mm of score per mm of mean gap between the box's surface and the occupancy.
SDF_WEIGHT = 1.0
#: Distances beyond this (mm) count as this much: far surfaces are all "not touching".
TRUNCATION_MM = 100.0
#: Largest size penalty (mm), for the smallest shown object relative to the largest.
SIZE_PENALTY_MM = 10.0


def voxel_layers(
    lo_mm: np.ndarray, hi_mm: np.ndarray, voxel_mm: int
) -> tuple[np.ndarray, np.ndarray]:
    """[k0, k1) of the voxel layers whose centres (k + 0.5) * voxel lie in [lo, hi); >= 1 layer."""
    # ceil((2 * lo - v) / (2 * v)) in integers, exact for negative numerators too.
    k0 = -((voxel_mm - 2 * lo_mm) // (2 * voxel_mm))
    k1 = -((voxel_mm - 2 * hi_mm) // (2 * voxel_mm))
    return k0, np.maximum(k1, k0 + 1)


def solid_layers(heights_mm: np.ndarray | int, voxel_mm: int) -> np.ndarray:
    """Number of voxel layers of a column of each height: those whose centre is below its top."""
    # (k + 0.5) * v < H  <=>  k < H / v - 0.5; count = ceil(H / v - 0.5), clipped at 0.
    heights = np.asarray(heights_mm, dtype=np.int64)
    return np.maximum(-((voxel_mm - 2 * heights) // (2 * voxel_mm)), 0)


def _min_plus_parabola(d2: np.ndarray, axis: int, reach: int) -> np.ndarray:
    """out[i] = min over |d| <= reach of d2[i + d] + d^2 along ``axis`` (out of grid: ignored)."""
    out = d2.copy()
    a = np.moveaxis(d2, axis, 0)
    o = np.moveaxis(out, axis, 0)
    for d in range(1, min(reach, a.shape[0] - 1) + 1):
        np.minimum(o[d:], a[:-d] + d * d, out=o[d:])
        np.minimum(o[:-d], a[d:] + d * d, out=o[:-d])
    return out


def gap_field(heightmap: np.ndarray, wall_mm: int, voxel_mm: int, layers: int) -> np.ndarray:
    """Truncated gap (mm) from each voxel to the nearest solid one, (X + 2, Y + 2, layers + 1).

    Index [i + 1, j + 1, k + 1] is cell (i, j), layer k (centre at (k + 0.5) * voxel mm);
    index 0 along z is the floor and the outer ring along x and y the walls, which are solid up
    to the container height. Every column of this grid is solid from the floor up to some layer
    and free above it, so the exact Euclidean transform separates: the distance along z to the
    nearest solid voxel of a column is just the height above that column's top; two 1-D
    min-plus-parabola passes along y and x finish it (Felzenszwalb-Huttenlocher). Only
    distances up to the truncation matter, so offsets and the z term stop at ``reach`` voxels:
    a true distance beyond it still comes out at least ``reach`` and clips to the same value.
    Equal to ``scipy.ndimage.distance_transform_edt`` on the same occupancy after truncation
    (tested), at a fraction of its cost.
    """
    v = voxel_mm
    reach = int(np.ceil(TRUNCATION_MM / v)) + 1  # voxels of centre distance that map below cap
    # Per padded column, the index of its highest solid voxel (the floor is index 0, so that is
    # its count of solid layers above the floor). Everything after runs in int16, which holds
    # every squared distance (at most 3 * reach^2), for half the memory traffic of int32.
    tops = np.pad(solid_layers(heightmap, v), 1, constant_values=int(solid_layers(wall_mm, v)))
    tops = np.minimum(tops, layers + 1).astype(np.int16)
    p = np.arange(layers + 1, dtype=np.int16)
    dz = np.clip(p[None, None, :] - tops[:, :, None], 0, reach).astype(np.int16)
    d2 = _min_plus_parabola(_min_plus_parabola(dz * dz, axis=1, reach=reach), axis=0, reach=reach)
    # d2 is a small integer: map it through a table instead of sqrt/clip over the whole grid.
    table = np.clip((np.sqrt(np.arange(3 * reach * reach + 1)) - 1.0) * v, 0.0, TRUNCATION_MM)
    return table[d2]


def _summed_volume(field: np.ndarray) -> np.ndarray:
    """S with a zero front pad: S[a, b, c] = field[:a, :b, :c].sum()."""
    s = np.zeros(tuple(d + 1 for d in field.shape), dtype=np.float64)
    s[1:, 1:, 1:] = field
    for axis in (2, 1, 0):  # in place: no temporaries of the whole volume
        np.add.accumulate(s, axis=axis, out=s)
    return s


def _box_sums(s: np.ndarray, lo: tuple[np.ndarray, ...], hi: tuple[np.ndarray, ...]) -> np.ndarray:
    """Sums of the field over boxes [lo, hi) (per axis, vectorised); empty ranges give 0."""
    hi = tuple(np.maximum(h, l) for l, h in zip(lo, hi))
    _, nb, nc = s.shape
    flat = s.ravel()
    # Flat indices of the eight corners: one gather each instead of 3-D fancy indexing.
    a0, a1 = lo[0] * (nb * nc), hi[0] * (nb * nc)
    b0, b1 = lo[1] * nc, hi[1] * nc
    c0, c1 = lo[2], hi[2]
    return (
        flat[a1 + b1 + c1]
        - flat[a0 + b1 + c1]
        - flat[a1 + b0 + c1]
        - flat[a1 + b1 + c0]
        + flat[a0 + b0 + c1]
        + flat[a0 + b1 + c0]
        + flat[a1 + b0 + c0]
        - flat[a0 + b0 + c0]
    )


def mean_surface_gap_mm(cands: CandidateSet, index: np.ndarray | None = None) -> np.ndarray:
    """Mean truncated gap over each candidate box's bottom and side voxels, float64 mm.

    For all candidates (n,), or only those at ``index`` (m,) int: the field is then built only
    as high as those boxes reach.
    """
    sel = np.arange(len(cands)) if index is None else np.asarray(index, dtype=np.int64)
    if sel.size == 0:
        return np.zeros(0)
    v = cands.cell_mm
    fx, fy = cands.fx[sel], cands.fy[sel]
    k0, k1 = voxel_layers(cands.z[sel], cands.top[sel], v)
    layers = int(max(k1.max(), -(-cands.container_height_mm // v))) + 1
    s = _summed_volume(gap_field(cands.heightmap, cands.container_height_mm, v, layers))
    # Padded solid index = cell index + 1 (walls/floor); s adds one more front pad, which the
    # half-open [lo, hi) convention absorbs: voxel p is s-range [p, p + 1).
    x0, y0, z0 = cands.x[sel] + 1, cands.y[sel] + 1, k0 + 1
    x1, y1, z1 = x0 + fx, y0 + fy, k1 + 1
    whole = _box_sums(s, (x0, y0, z0), (x1, y1, z1))
    # The core left out: inside the side faces, above the bottom layer (includes the top face).
    core = _box_sums(s, (x0 + 1, y0 + 1, z0 + 1), (x1 - 1, y1 - 1, z1))
    nl = k1 - k0
    count_core = np.maximum(fx - 2, 0) * np.maximum(fy - 2, 0) * (nl - 1)
    count = fx * fy * nl - count_core
    return (whole - core) / count


def size_penalty_mm(cands: CandidateSet) -> np.ndarray:
    """(n,) float64: SIZE_PENALTY_MM * (1 - object volume / largest shown volume)."""
    volumes = cands.shown_sizes_mm.prod(axis=1).astype(np.float64)
    if volumes.size == 0 or volumes.max() <= 0:
        return np.zeros(len(cands))
    return SIZE_PENALTY_MM * (1.0 - volumes[cands.obj] / volumes.max())


def sdf_score(cands: CandidateSet, index: np.ndarray | None = None) -> np.ndarray:
    """Score in mm (see module docstring), lower is better; all candidates or those at ``index``."""
    sel = np.arange(len(cands)) if index is None else np.asarray(index, dtype=np.int64)
    gap = mean_surface_gap_mm(cands, sel)
    return cands.z[sel] + SDF_WEIGHT * gap + size_penalty_mm(cands)[sel]


def score(cands: CandidateSet) -> Keys:
    """Keys (score rounded to 1e-6 mm, z, x, y), lower is better.

    Only the rim pool is scored (the others stay +inf): selection never reads outside it, and
    skipping boxes that stick out above the rim keeps the distance field rim-high.
    """
    pool = rim_pool(cands)
    key = np.full(len(cands), np.inf)
    key[pool] = quantise(sdf_score(cands, pool))
    return (key, cands.z, cands.x, cands.y)
