"""MTA, Maximum Touching Area: the placement whose box touches the most floor, wall and boxes.

Contact area of a box with footprint F (fx by fy cells of side c mm), resting at z (paper Eq. 2)
with top t = z + h, read from the heightmap (each column taken as solid from 0 up to its
height, the only thing a heightmap can say):

- Support (bottom face): the cells of F whose height equals z, each c^2 mm^2. On the empty
  floor z = 0 and all of F counts (floor contact).
- Side faces: for each cell edge of F's boundary, the column just across it has height H (a
  wall counts as a column of the container's height). The face and that column overlap in z
  over ``max(0, min(t, H) - z)`` mm, times c mm of edge. Diagonal neighbours touch only along a
  line and count nothing.

Support uses exact equality with z, as stated: on physics heightmaps (settled poses rounded to
whole mm) a top 1 mm lower does not count as support. Both terms are vectorised over every
minimum cell of an orientation: the support count is a separable "how many cells reach the
window max" pass, the side terms one strided view per pair of opposite faces.

Rule (lower is better, compared in this order):

1. minus the contact area (so the largest contact wins), in integer mm^2 so ties are exact;
   :func:`contact_area_cm2` gives the same in cm^2.
2. Ties: the DBLF order, lower z, then smaller x, then smaller y (equal contact often happens
   in mirror-image corners; the lowest, deepest one keeps the order predictable).
3. The tie-break rule of :mod:`packlab.policies.heuristics.select` (default: the larger
   object, then rotation 0 before 1; ``tie_break="shown_order"``: the first shown object).

The object is chosen jointly with the placement; larger boxes have larger faces, so MTA tends
to take big objects first. No weights: floor, wall and box contact count alike, per mm^2. The
shared rim rule of :mod:`packlab.policies.heuristics.select` applies first.
"""

from __future__ import annotations

import numpy as np

from packlab.core.feasibility import CandidateSet, Orientation
from packlab.policies.heuristics.select import Keys, per_group
from packlab.policies.heuristics.windows import padded, side_neighbours, window_count_of_max

NAME = "mta"


def _faces_overlap_mm(neighbours: np.ndarray, z: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Sum over two opposite faces' cells of the z-overlap (mm) of [z, top] with columns [0, H].

    ``neighbours`` is (2, X', Y', f) from :func:`side_neighbours`; ``z``, ``top`` are (X', Y').
    """
    # min(max(H, z), top) - z == max(0, min(top, H) - z) since top > z; two ufuncs with an
    # output buffer are cheaper than np.clip with broadcast bounds.
    clipped = np.maximum(neighbours, z[..., None])
    np.minimum(clipped, top[..., None], out=clipped)
    cells = neighbours.shape[0] * neighbours.shape[-1]
    return clipped.sum(axis=(0, -1), dtype=np.int64) - cells * z


def contact_area_mm2(cands: CandidateSet) -> np.ndarray:
    """(n,) int64: contact area (mm^2) of each candidate with floor, walls and boxes."""
    hm = cands.heightmap.astype(np.int32, copy=False)
    walled = padded(hm, cands.container_height_mm).astype(np.int32)
    c = cands.cell_mm
    # Equal boxes and square footprints repeat an orientation: compute each shape once.
    support: dict[tuple[int, int], np.ndarray] = {}
    contact: dict[tuple[int, int, int], np.ndarray] = {}

    def group_contact(g: Orientation) -> np.ndarray:
        key = (g.fx, g.fy, g.height_mm)
        if key not in contact:
            if key[:2] not in support:
                support[key[:2]] = window_count_of_max(hm, g.fx, g.fy)[1]
            z = g.z.astype(np.int32, copy=False)
            top = z + np.int32(g.height_mm)
            x_faces, y_faces = side_neighbours(walled, g.fx, g.fy)
            side_mm = _faces_overlap_mm(x_faces, z, top) + _faces_overlap_mm(y_faces, z, top)
            contact[key] = support[key[:2]] * (c * c) + side_mm * c
        return contact[key]

    return per_group(cands, group_contact)


def contact_area_cm2(cands: CandidateSet) -> np.ndarray:
    """(n,) float64: :func:`contact_area_mm2` in cm^2."""
    return contact_area_mm2(cands) / 100.0


def score(cands: CandidateSet) -> Keys:
    """Keys (-contact area, z, x, y), lower is better."""
    return (-contact_area_mm2(cands), cands.z, cands.x, cands.y)
