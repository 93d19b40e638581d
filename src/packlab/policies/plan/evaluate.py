"""The planner's state evaluation: an estimate of the volume a state has already lost.

A leaf's cost is a weighted sum of documented terms, all in cell-millimetres (so the weights
are plain ratios): the space trapped under boxes placed along the path, the pits no known box
can reach (:func:`.surface.unreachable_volume`), the open space below the highest column, the
area of the steps between columns, the volume above the rim, and where the episode's volumes
are known, how far from a perfect packing it would end if the boxes still to come settled level
(:func:`.outlook.final_shortfall`). A perfect layout's state that lost nothing can still be
completed perfectly; on boxes with no perfect packing the final height is what is left to
lose. Default weights come from sweeps on generated training cases (docs/planner.md, "How the
defaults were chosen"), never on a suite; ``benchmarks/plan_sweep.py`` re-measures them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.policies.plan.outlook import Outlook, final_shortfall
from packlab.policies.plan.surface import open_volume, step_area, unreachable_volume


@dataclass(frozen=True, slots=True)
class Weights:
    """Weights of the cost terms (cost = sum of weight x term, lower is better)."""

    trapped: float = 1.0
    unreachable: float = 1.0
    open: float = 0.1
    steps: float = 0.1
    over_rim: float = 10.0
    final: float = 1.0  # the final-height shortfall (:func:`.outlook.final_shortfall`)


@dataclass(frozen=True, slots=True)
class PathLoss:
    """What the placements along a search path lost, cell-mm."""

    trapped: int = 0
    over_rim: int = 0

    def plus(self, trapped: int, over_rim: int) -> PathLoss:
        return PathLoss(self.trapped + trapped, self.over_rim + over_rim)


def state_cost(
    heightmap: np.ndarray,
    path: PathLoss,
    footprints: tuple[tuple[int, int], ...],
    weights: Weights,
    outlook: Outlook | None = None,
) -> float:
    """The cost of reaching ``heightmap`` along a path that lost ``path`` (pure); with an
    ``outlook`` (the state's volumes, :mod:`.outlook`) also its final-height shortfall."""
    shortfall = 0.0 if outlook is None or not weights.final else final_shortfall(heightmap, outlook)
    return (
        weights.final * shortfall
        + weights.trapped * path.trapped
        + weights.over_rim * path.over_rim
        + weights.unreachable * unreachable_volume(heightmap, footprints)
        + weights.open * open_volume(heightmap)
        + weights.steps * step_area(heightmap)
    )


def smallest_footprints(
    sizes_cells: list[tuple[int, int]], keep: int = 2
) -> tuple[tuple[int, int], ...]:
    """The ``keep`` smallest distinct footprints (by area, then shape) of the boxes seen so far,
    each in both rotations: what the unknown boxes still to come are assumed to be at least."""
    distinct = sorted(
        {(min(a, b), max(a, b)) for a, b in sizes_cells}, key=lambda f: (f[0] * f[1], f)
    )
    out: list[tuple[int, int]] = []
    for a, b in distinct[:keep]:
        out += [(a, b)] if a == b else [(a, b), (b, a)]
    return tuple(out)
