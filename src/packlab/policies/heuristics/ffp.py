"""FFP, First Feasible Placement: the first candidate in scan order that stays within the rim.

Rule: walk the candidates in the fixed scan order (shown object order, rotation 0 then 1, x
then y) and take the first whose top (z + h, z from paper Eq. 2) is at most the container
height. Nothing is scored, so FFP is the baseline that shows what ordering alone achieves: it
tends to pack the first shown object near cell (0, 0) and stack there.

When no candidate stays within the rim, the shared rim rule takes the lowest-top candidates and
FFP again takes the first of those in scan order. There are no weights and no other ties.
"""

from __future__ import annotations

from packlab.policies.heuristics.candidates import CandidateSet
from packlab.policies.heuristics.select import Keys

NAME = "ffp"


def score(cands: CandidateSet) -> Keys:
    """No keys: the shared selection falls straight to scan order."""
    return ()
