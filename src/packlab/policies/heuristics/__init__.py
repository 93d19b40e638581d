"""The five packing heuristics: pure scorers over one shared, vectorised candidate search.

Importing this package registers the policies "dblf", "hm", "mta", "ffp" and "sdf".

- :mod:`.candidates`: the candidate search (object x rotation x cell, Eq. 2 heights), the dense
  action mask, for heuristics, ``random`` and RL alike.
- :mod:`.select`: the rim rule, lexicographic key filtering and the tie-break rule shared by
  every heuristic (``tie_break``: ``"larger_volume"``, the default, or ``"shown_order"``).
- :mod:`.dblf`, :mod:`.hm`, :mod:`.mta`, :mod:`.ffp`, :mod:`.sdf`: one scorer each.
- :mod:`.policy`: HeuristicPolicy and the registrations.
"""

from packlab.core.feasibility import (
    CandidateSet,
    Orientation,
    action_mask,
    observation_candidates,
    scatter,
    search_candidates,
)
from packlab.policies.heuristics.policy import (
    SCORERS,
    HeuristicPolicy,
    decide,
    make_heuristic,
)
from packlab.policies.heuristics.select import (
    DEFAULT_TIE_BREAK,
    TIE_BREAKS,
    Keys,
    Scorer,
    TieBreak,
    choose,
    rim_pool,
    to_action,
)

__all__ = [
    "DEFAULT_TIE_BREAK",
    "SCORERS",
    "TIE_BREAKS",
    "CandidateSet",
    "HeuristicPolicy",
    "Keys",
    "Orientation",
    "Scorer",
    "TieBreak",
    "action_mask",
    "choose",
    "decide",
    "make_heuristic",
    "observation_candidates",
    "rim_pool",
    "scatter",
    "search_candidates",
    "to_action",
]
