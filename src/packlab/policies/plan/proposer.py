"""The planner's proposer: the few first placements worth a rollout, from the shared search.

Every floor-fitting placement of every shown object in both rotations comes from
:func:`packlab.core.feasibility.search_candidates` (restricted to the rim pool, as for the
heuristics). The proposer keeps the union, in this order and without duplicates, of

1. SDF-Pack's best ``per_ranking`` placements, in SDF-Pack's own order (its keys score, z,
   x, y, then its tie-break rule, :func:`~packlab.policies.heuristics.select.ranked`), so the
   first is always the placement SDF-Pack itself would choose, and
2. the flush/contact ranking's best ``per_ranking``: less space trapped under the box first,
   then more contact area with floor, walls and boxes (MTA's measure), then lower top, then
   scan order. Both measures are the shared placement features (:mod:`packlab.policies.features`).
3. the students' proposer's first ``listed`` placements (:mod:`packlab.policies.candidates`:
   each distinct shape's lowest, most enclosed resting place, lowest first). SDF-Pack and the
   flush ranking both favour the box that fills most, so without it every proposal may be the
   same one or two boxes; on boxes of independent sizes, where no exact tiling exists and the
   lookahead decides most steps, the proposer's own first pick did as well as the planner
   (docs/planner.md, "How the defaults were chosen").

None of them reads anything but the candidate set, so the proposer sees only what the policy
observes.
"""

from __future__ import annotations

import numpy as np

from packlab.core.choices import TieBreak
from packlab.core.feasibility import CandidateSet
from packlab.policies.candidates import ProposerConfig, proposed_indices
from packlab.policies.features import contact_area_mm2, space_under
from packlab.policies.heuristics import sdf
from packlab.policies.heuristics.select import DEFAULT_TIE_BREAK, ranked, rim_pool


def by_sdf(
    cands: CandidateSet, pool: np.ndarray, tie_break: TieBreak = DEFAULT_TIE_BREAK
) -> np.ndarray:
    """``pool`` (candidate indices) in SDF-Pack's order, best first: its keys score, z, x, y,
    then its tie-break rule, so ``by_sdf(cands, rim_pool(cands))[0]`` is SDF-Pack's choice."""
    return ranked(cands, sdf.score(cands), pool, tie_break)


def by_flush(cands: CandidateSet, pool: np.ndarray) -> np.ndarray:
    """``pool`` (candidate indices) in the flush/contact ranking's order, best first (item 2 of
    the module docstring)."""
    trapped = space_under(cands)[pool]
    contact = contact_area_mm2(cands)[pool]
    return pool[np.lexsort((pool, cands.top[pool], -contact, trapped))]


def first_placements(cands: CandidateSet, per_ranking: int, listed: int = 0) -> list[int]:
    """Candidate indices to roll out (see the module docstring): ``per_ranking`` from each of
    the two rankings, then ``listed`` from the students' proposer; empty when nothing fits."""
    pool = rim_pool(cands)
    if pool.size == 0:
        return []
    sdf_ranked = by_sdf(cands, pool)
    flush_ranked = by_flush(cands, pool)
    rankings = [sdf_ranked[:per_ranking].tolist(), flush_ranked[:per_ranking].tolist()]
    if listed > 0:
        rankings.append(proposed_indices(cands, ProposerConfig(k=listed)))
    out: list[int] = []
    for ranking in rankings:
        out += [i for i in ranking if i not in out]
    return out
