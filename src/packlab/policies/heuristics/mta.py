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
whole mm) a top 1 mm lower does not count as support. The measure is
:func:`packlab.policies.features.contact_area_mm2`, the placement feature the proposer and the
planner share, asked for exact support (``tolerance_mm=0``) where the planner counts support
within the shared "same level" tolerance; both terms are vectorised over every minimum cell of
an orientation there.

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

from packlab.core.feasibility import CandidateSet
from packlab.policies import features
from packlab.policies.heuristics.select import Keys

NAME = "mta"

__all__ = ["NAME", "contact_area_cm2", "contact_area_mm2", "score"]


def contact_area_mm2(cands: CandidateSet) -> np.ndarray:
    """(n,) int64 mm^2: MTA's contact area, support by exact equality with z (as published)."""
    return features.contact_area_mm2(cands, tolerance_mm=0)


def contact_area_cm2(cands: CandidateSet) -> np.ndarray:
    """(n,) float64: :func:`contact_area_mm2` in cm^2."""
    return contact_area_mm2(cands) / 100.0


def score(cands: CandidateSet) -> Keys:
    """Keys (-contact area, z, x, y), lower is better."""
    return (-contact_area_mm2(cands), cands.z, cands.x, cands.y)
