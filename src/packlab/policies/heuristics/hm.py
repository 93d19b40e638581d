"""HM, Heightmap Minimization: the placement that raises the whole heightmap's sum the least.

Rule (lower is better, compared in this order):

1. The increase of the heightmap's sum, as a volume in mm^3. Placing a box with footprint F at
   resting height z (paper Eq. 2) and height h sets every cell of F to top = z + h, so the
   increase is ``sum over F of (top - hm[c])`` times the cell area: the box's own volume plus the
   space it seals off underneath (cells of F lower than z), the shared placement feature
   :func:`packlab.policies.features.space_under_grid` (one summed-area table per orientation).
2. Ties "bottom-left": the DBLF order, lower z, then smaller x, then smaller y. Equal increases
   are common (a box fits flush in several places); preferring the lowest, deepest one keeps
   HM's packing order as predictable as DBLF's.
3. The tie-break rule of :mod:`packlab.policies.heuristics.select` (default: the larger
   object, then rotation 0 before 1; ``tie_break="shown_order"``: the first shown object).

The object is chosen jointly with the placement, so on an even surface HM favours the smallest
shown object (its own volume is part of the increase): that is the rule as stated, not tuned.
No weights. The shared rim rule of :mod:`packlab.policies.heuristics.select` applies first.
"""

from __future__ import annotations

import numpy as np

from packlab.core.feasibility import CandidateSet, Orientation
from packlab.policies.features import space_under_grid
from packlab.policies.heuristics.select import Keys, per_group

NAME = "hm"


def heightmap_increase_mm3(cands: CandidateSet) -> np.ndarray:
    """(n,) int64: increase of the heightmap's sum (mm^3) if each candidate were placed."""
    hm = cands.heightmap
    cell_area = cands.cell_mm * cands.cell_mm

    def group_increase(g: Orientation) -> np.ndarray:
        own = g.fx * g.fy * g.height_mm
        return (own + space_under_grid(hm, g.fx, g.fy, g.z)) * cell_area

    return per_group(cands, group_increase)


def score(cands: CandidateSet) -> Keys:
    """Keys (heightmap increase, z, x, y), lower is better."""
    return (heightmap_increase_mm3(cands), cands.z, cands.x, cands.y)
