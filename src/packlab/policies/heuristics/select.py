"""Choosing one candidate from a heuristic's keys, with the rim rule every heuristic shares.

A *scorer* maps a :class:`CandidateSet` to a tuple of per-candidate key arrays, most significant
first, lower is better (keys outside the pool of step 1 are never read, so a scorer may leave
them at +inf rather than compute them). Selection is then:

1. The pool is the candidates whose top stays within the rim (top <= container height). When
   none does, the pool is the candidates with the lowest top: the box that sticks out least.
2. Keys filter the pool in turn, keeping only the candidates at each key's minimum (exact
   equality, so scorers return integers or values rounded to a fixed quantum).
3. Whatever still ties goes to scan order (shown object, rotation 0 before 1, x, y): the first.

Filtering in turn costs one pass per key over the pool, cheaper than a full lexicographic sort,
and step 3 makes every choice deterministic.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from packlab.policies.heuristics.candidates import CandidateSet
from packlab.types import Action

Keys = tuple[np.ndarray, ...]
Scorer = Callable[[CandidateSet], Keys]

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


def choose(cands: CandidateSet, keys: Keys) -> int | None:
    """Index of the chosen candidate, or None when there is no candidate at all."""
    pool = rim_pool(cands)
    if pool.size == 0:
        return None
    for key in keys:
        if pool.size == 1:
            break
        values = np.asarray(key)[pool]
        pool = pool[values == values.min()]
    return int(pool[0])


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
    out = np.empty(len(cands), dtype=dtype)
    for g in cands.groups:
        out[g.offset : g.offset + g.size] = np.asarray(fn(g)).ravel()
    return out
