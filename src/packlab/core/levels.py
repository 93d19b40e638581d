"""When two heights are "the same level": the one definition the planner, the placement
features, level fit, the stability test and the place skill's seat sides share.

Heights are whole millimetres (the heightmap's z grid). Box heights come in whole centimetres,
so two different levels of a layered packing are at least 10 mm apart, and two readings of one
level differ only by measurement error. On an exact observation that error is 0; settled tops in
MuJoCo carry sub-millimetre sag that the heightmap rounds to the z grid; a perceived heightmap
carries per-top error: after ``flatten_tops`` (:mod:`packlab.sim.sensing.perception`) each
connected top takes the median of its cells, so two tops of one level that do not touch (or the
same top seen before and after a neighbour lands) differ by the error of that median, about a
millimetre under the structured-light preset and 1-3 mm under the stereo preset (6 mm per-cell
noise, 2 mm quantisation; its ``flat_tolerance_mm`` is 7.5). Cells that ``flatten_tops`` leaves
alone are off their top by more than that preset tolerance, which no level tolerance below half
a box-height step can absorb.

:data:`LEVEL_TOLERANCE_MM` is therefore the largest whole-mm tolerance that still keeps levels
one box-height step (10 mm) apart distinct when both readings err by up to 2 mm toward each
other (4 + 2 * 2 < 10), and absorbs the same 2 mm of error on either side of one level
(2 * 2 <= 4). It was chosen on generated training cases (never on a bench suite); the measured
comparison is in the commit that introduced it.

A different question, "does this column rise clearly above that level?", has its own constant,
:data:`FACE_RISE_MM`: it must lie beyond the per-cell error that ``flatten_tops`` leaves
(not the per-top error), so it is larger; see its comment.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

#: Two heights (mm) within this of each other are one level; see the module docstring for why 4.
LEVEL_TOLERANCE_MM = 4

#: A neighbour column is a face to push a box against (the place skill's seat sides,
#: ``packlab.sim.execution.seat_sides``) only when it rises at least this far (mm) above the
#: box's bottom. Not a same-level test, and larger than :data:`LEVEL_TOLERANCE_MM` on purpose:
#: a single cell that ``flatten_tops`` left unflattened beside a neighbour level with the
#: support reads off by more than the stereo preset's 7.5 mm ``flat_tolerance_mm``, and pushing
#: toward a face that is not there shoves the box off plan, so this must clear the per-cell
#: error, not the per-top one; a real neighbour box standing on the support rises by its own
#: height (80 mm or more in packlab-bench-v1), far above it.
FACE_RISE_MM = 10


def same_level(a: ArrayLike, b: ArrayLike, tolerance_mm: int = LEVEL_TOLERANCE_MM) -> np.ndarray:
    """Whether heights ``a`` and ``b`` (mm, broadcast) are one level: ``|a - b| <= tolerance``.

    Element-wise bool array (a 0-d array for two scalars; ``bool(...)`` it where one answer is
    wanted). Differences are taken in int64 so unsigned or int32 heightmaps cannot wrap.
    """
    diff = np.asarray(a, dtype=np.int64) - np.asarray(b, dtype=np.int64)
    return np.abs(diff) <= tolerance_mm


def at_or_below(
    heights: ArrayLike, level: ArrayLike, tolerance_mm: int = LEVEL_TOLERANCE_MM
) -> np.ndarray:
    """Whether each height is at ``level`` (:func:`same_level`) or below it: the cells a box
    resting at ``level`` could cover or leave open beside it (the level's free floor)."""
    return np.asarray(heights, dtype=np.int64) <= np.asarray(level, dtype=np.int64) + tolerance_mm


def above_level(
    heights: ArrayLike, level: ArrayLike, tolerance_mm: int = LEVEL_TOLERANCE_MM
) -> np.ndarray:
    """Whether each height stands above ``level`` and is not the same level: the complement of
    :func:`at_or_below` (a column a box's side at ``level`` can touch)."""
    return ~at_or_below(heights, level, tolerance_mm)


__all__ = ["FACE_RISE_MM", "LEVEL_TOLERANCE_MM", "above_level", "at_or_below", "same_level"]
