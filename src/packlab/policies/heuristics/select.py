"""Choosing one candidate from a heuristic's keys, with the rim rule every heuristic shares.

A *scorer* maps a :class:`CandidateSet` to a tuple of per-candidate key arrays, most significant
first, lower is better (keys outside the pool of step 1 are never read, so a scorer may leave
them at +inf rather than compute them). Selection is then:

1. The pool is the candidates whose top stays within the rim (top <= container height). When
   none does, the pool is the candidates with the lowest top: the box that sticks out least.
2. Keys filter the pool in turn, keeping only the candidates at each key's minimum (exact
   equality, so scorers return integers or values rounded to a fixed quantum).
3. Whatever still ties is settled by the *tie-break rule*, an option of every heuristic
   (:data:`TieBreak`):

   - ``"larger_volume"`` (the default, the literature's rule: DBLF and its relatives pack the
     larger item first when placements are equally good). Shown objects are ranked by volume,
     larger first; equal volumes by footprint area (l * w), larger first; then by (l, w),
     larger first, which leaves only boxes of identical size tied; those go by ``internal_id``,
     smaller first. The candidate of the best-ranked object wins, and within that object
     rotation 0 before 1, then smaller x, then smaller y. Nothing here reads the shown order,
     which is shuffled every step, so an episode does not depend on the run seed. Ids decide
     only between identical boxes, which are interchangeable (same placements, same buffer
     left behind), so they cannot hint at a layout (in the reference's files ids number the
     objects in the perfect plan's order, which is why they are not used any earlier); they
     only fix which of the identical bodies the physics engine moves, since its contact
     solver is not indifferent to that.
   - ``"shown_order"``: plain scan order (shown object, rotation 0 before 1, x, y), the first.
     The shown order is shuffled every step, so ties go to a random object; kept to reproduce
     earlier runs and as the ablation of the rule.

Filtering in turn costs one pass per key over the pool, cheaper than a full lexicographic sort,
and step 3 makes every choice deterministic.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import get_args

import numpy as np

from packlab.core.choices import TieBreak
from packlab.core.errors import ConfigError
from packlab.core.feasibility import CandidateSet
from packlab.core.types import Action

Keys = tuple[np.ndarray, ...]
Scorer = Callable[[CandidateSet], Keys]

#: The choices of :data:`TieBreak`, in the order error messages list them.
TIE_BREAKS: tuple[TieBreak, ...] = get_args(TieBreak)
#: The literature's rule: equally good placements go to the larger object.
DEFAULT_TIE_BREAK: TieBreak = "larger_volume"

#: Float scores are rounded to this many decimals before comparison, so near-equal placements
#: computed along different float paths still tie exactly and fall to the documented tie-break.
FLOAT_DECIMALS = 6


def quantise(values: np.ndarray) -> np.ndarray:
    """Round float keys so equality-based tie-breaking is stable."""
    return np.round(np.asarray(values, dtype=np.float64), FLOAT_DECIMALS)


def rim_pool(cands: CandidateSet) -> np.ndarray:
    """Indices (scan order) of the candidates a heuristic may choose from (step 1 above)."""
    pool = np.flatnonzero(cands.fits_in_rim)
    if pool.size == 0 and len(cands) > 0:
        pool = np.flatnonzero(cands.top == cands.top.min())
    return pool


def check_tie_break(value: object, policy: str = "heuristic") -> TieBreak:
    """``value`` as a :data:`TieBreak`, or a ConfigError naming it and the choices."""
    if isinstance(value, str) and value in TIE_BREAKS:
        return value
    raise ConfigError(
        f"policy-arg {policy}:tie_break = {value!r}: unknown tie-break rule; "
        f"choose one of {', '.join(TIE_BREAKS)}"
    )


def object_rank(shown_sizes_mm: np.ndarray, id_order: np.ndarray) -> np.ndarray:
    """(k,) int64 rank of each shown object under ``larger_volume``, 0 = taken first.

    Order: volume, then footprint area (l * w), then l, then w, each larger first; identical
    sizes by ``id_order`` (:attr:`CandidateSet.shown_id_order`), smaller first.
    """
    sizes = np.asarray(shown_sizes_mm, dtype=np.int64).reshape(-1, 3)
    l, w, h = sizes[:, 0], sizes[:, 1], sizes[:, 2]
    # np.lexsort sorts by its last key first.
    order = np.lexsort((np.asarray(id_order), -w, -l, -(l * w), -(l * w * h)))
    rank = np.empty(order.size, dtype=np.int64)
    rank[order] = np.arange(order.size)
    return rank


def first_object(cands: CandidateSet, tie_break: TieBreak) -> int:
    """Shown index of the object the tie-break rule takes first (0 when nothing is shown)."""
    if tie_break == "shown_order" or cands.buffer_size == 0:
        return 0
    return int(np.argmin(object_rank(cands.shown_sizes_mm, cands.shown_id_order)))


def _settle_ties(cands: CandidateSet, pool: np.ndarray, tie_break: TieBreak) -> int:
    """The one candidate of a non-empty ``pool`` (scan order) that the tie-break rule picks."""
    if tie_break == "larger_volume" and pool.size > 1:
        # Within one object the pool is already in (rotation, x, y) order, so keeping the
        # best-ranked object's candidates and taking the first is the whole rule.
        ranks = object_rank(cands.shown_sizes_mm, cands.shown_id_order)[cands.obj[pool]]
        pool = pool[ranks == ranks.min()]
    return int(pool[0])


def choose(cands: CandidateSet, keys: Keys, tie_break: TieBreak = DEFAULT_TIE_BREAK) -> int | None:
    """Index of the chosen candidate, or None when there is no candidate at all."""
    pool = rim_pool(cands)
    if pool.size == 0:
        return None
    for key in keys:
        if pool.size == 1:
            break
        values = np.asarray(key)[pool]
        pool = pool[values == values.min()]
    return _settle_ties(cands, pool, tie_break)


def ranked(
    cands: CandidateSet,
    keys: Keys,
    pool: np.ndarray | None = None,
    tie_break: TieBreak = DEFAULT_TIE_BREAK,
) -> np.ndarray:
    """``pool`` (candidate indices; default the rim pool of step 1) sorted best first by the
    rule :func:`choose` applies: the keys in turn, then the tie-break rule, then scan order.

    So ``ranked(cands, keys)[0] == choose(cands, keys, tie_break)`` whenever there is a
    candidate; the rest of the order is what the same rule would pick with the better ones gone.
    """
    pool = rim_pool(cands) if pool is None else np.asarray(pool, dtype=np.int64)
    if pool.size == 0:
        return pool
    # np.lexsort sorts by its last key first; the candidate index itself is the scan order.
    order: list[np.ndarray] = [pool]
    if tie_break == "larger_volume":
        ranks = object_rank(cands.shown_sizes_mm, cands.shown_id_order)
        order.append(ranks[cands.obj[pool]])
    order += [np.asarray(key)[pool] for key in reversed(keys)]
    return pool[np.lexsort(tuple(order))]


def to_action(cands: CandidateSet, index: int) -> Action:
    """The action of candidate ``index``."""
    return Action(
        object_id=int(cands.obj[index]),
        rotation=int(cands.rotation[index]),
        x=int(cands.x[index]),
        y=int(cands.y[index]),
    )


def per_group(
    cands: CandidateSet, fn: Callable[..., np.ndarray], dtype: type = np.int64
) -> np.ndarray:
    """Flat (n,) array built by ``fn(group) -> grid`` for each candidate group (scan order)."""
    out: np.ndarray = np.empty(len(cands), dtype=dtype)
    for g in cands.groups:
        out[g.offset : g.offset + g.size] = np.asarray(fn(g)).ravel()
    return out
