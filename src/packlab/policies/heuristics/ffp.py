"""FFP, First Feasible Placement: the first candidate, object by object, that stays within the rim.

Rule: walk the candidates object by object, in the order of the tie-break rule
(:mod:`packlab.policies.heuristics.select`; by default larger volume first, with
``tie_break="shown_order"`` the shown order), each in rotation 0 then 1, x then y, and take the
first whose top (z + h, z from paper Eq. 2) is at most the container height. Nothing is
scored, so FFP is the baseline that shows what ordering alone achieves: it tends to pack the
first object of that order near cell (0, 0) and stack there.

When no candidate stays within the rim, the shared rim rule takes the lowest-top candidates and
FFP again takes the first of those in the same order. There are no weights and no other ties.
"""

from __future__ import annotations

from packlab.core.feasibility import CandidateSet
from packlab.policies.heuristics.select import Keys

NAME = "ffp"


def score(cands: CandidateSet) -> Keys:
    """No keys: the shared selection falls straight to the tie-break rule."""
    return ()
