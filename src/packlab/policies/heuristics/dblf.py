"""DBLF, Deepest-Bottom-Left-Fill: the lowest resting place, then the deepest, then the leftmost.

Rule (lower is better, compared in this order):

1. z, the resting height from paper Eq. 2 (mm). Height dominates: a placement 2 mm lower wins
   over any x or y, because filling from the bottom keeps the surface flat for later boxes.
2. x, the footprint's minimum cell along the container's first axis ("deepest": the far end of
   the container is x = 0, so boxes are pushed against the back wall first).
3. y, the minimum cell along the second axis ("leftmost").

The object is chosen jointly with the placement: every shown object in both rotations competes
on the same keys. Remaining ties (equal z, x, y for several objects or both rotations) go to the
heuristic's tie-break rule (:mod:`packlab.policies.heuristics.select`): by default the larger
object, as in the literature's DBLF, then rotation 0 before 1; with ``tie_break="shown_order"``
the first shown object. There are no weights. The rim rule of
:mod:`packlab.policies.heuristics.select` applies first (in-rim candidates only, else the
lowest-top ones).
"""

from __future__ import annotations

from packlab.core.feasibility import CandidateSet
from packlab.policies.heuristics.select import Keys

NAME = "dblf"


def score(cands: CandidateSet) -> Keys:
    """Keys (z, x, y), lower is better."""
    return (cands.z, cands.x, cands.y)
