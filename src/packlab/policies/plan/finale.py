"""The last boxes: with every remaining box in view, set one aside where that ends higher (pure).

When the observation's ``remaining`` equals the number of boxes shown, nothing else will come:
the episode's end is computable under the planner's model (the geometric backend's: a box
rests at Eq. 2's height). Overall is proportional to V**2 / H (:mod:`packlab.policies.overflow`:
V the volume packed inside, H the highest cell). A layer that could not be closed (a guess about
unseen boxes that turned out wrong) leaves boxes that no longer fit in it; the lookahead then
stacks one on top, and a box of an eighth of the volume stacked on one closed layer halves
compactness, where setting it aside costs an eighth of the Success Ratio.

The overflow rule already decides this for the episode's very last box. Here the same
comparison covers the last boxes together: when the planner's placement raises the highest
cell, each alternative (that placement, or setting one shown box aside) is followed by greedy
plays of the other boxes (:func:`greedy_end`, in each of :data:`GREEDY_ORDERS`) and scored by
the best final V**2 / H among them; the best end wins, ties to the planner's placement. A
greedy play places, among the placements that keep the top (within the one same-level
tolerance), the one its order ranks first; where every placement raises the top it places the
one with the best V**2 / H if that beats V**2 / H now, and otherwise ends (the boxes left are
set aside). Alternatives that place are judged with what the
other boxes can then fill under the raised top, which the one-box rule cannot see.

Nothing is known of the order's length when a run hides ``remaining``, and under the online
protocol the arriving box must be placed: the rule stays out of both. It also stays out while
more than ``max_boxes`` boxes are in view (:data:`FINALE_BOXES`): a greedy play is a fair
model of the planner's last few placements, not of a long future. With every box of an order
in view from the start (``--protocol offline``) the rule would otherwise decide from the first
step: on 60 generated random-box training cases it set boxes aside early on such estimates,
and `plan-fast` scored 0.600 there against 0.626 shown three to ten boxes at a time
(docs/history/planner.md, "The finale").

It belongs to the planner (``plan``'s option ``finale``) and follows its ``overflow`` rule:
``score`` only. The learned policies and the proposer do not take it: measured for IR-BPP on
generated training cases it added +0.0006 [-0.0026, +0.0037] on 420 fresh ones and nearly
doubled its mean decision time on the hard level (docs/history/planner.md, "The finale").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from packlab.core.choices import OverflowRule
from packlab.core.feasibility import CandidateSet, search_candidates
from packlab.core.types import Action, Observation, ShownItem
from packlab.policies.features import LEVEL_TOLERANCE_MM
from packlab.policies.heuristics import sdf
from packlab.policies.overflow import packed_inside_volume
from packlab.sim.heightmap import place_box


def everything_in_view(observation: Observation) -> bool:
    """Whether every box still to come is shown now (``remaining`` known and equal)."""
    return (
        observation.remaining is not None
        and not observation.must_place_first
        and observation.remaining == len(observation.shown)
    )


def end_ratio(volume: float, height: int) -> float:
    """V**2 / H, to which Overall is proportional once every volume is fixed (module docstring)."""
    return volume * volume / max(height, 1)


#: The greedy play's orders among the placements that keep the top: SDF-Pack's keys (score, z,
#: x, y); the lowest resting place (z, x, y); the largest box first, then lowest. Each branch
#: ends as the best of the three: one greedy order is a noisy model of the planner that will
#: play on, and a branch should not lose for an order that suits it badly.
GREEDY_ORDERS = ("sdf", "lowest", "largest")


def _keeping_order(cands: CandidateSet, keeps: np.ndarray, order: str) -> int:
    """The candidate (an index into ``cands``) the greedy ``order`` takes among ``keeps``."""
    if order == "sdf":
        keys = tuple(np.asarray(k)[keeps] for k in sdf.score(cands))
    elif order == "lowest":
        keys = (cands.z[keeps], cands.x[keeps], cands.y[keeps])
    else:
        volume = np.prod(cands.shown_sizes_mm[cands.obj[keeps]], axis=1)
        keys = (-volume, cands.z[keeps], cands.x[keeps], cands.y[keeps])
    return int(keeps[np.lexsort(tuple(reversed(keys)))[0]])


@dataclass(frozen=True, slots=True)
class Pile:
    """What the rule scores a state by: the heightmap (mm), V (mm^3 packed inside the rim) and
    H (mm, the highest cell), in a container of ``rim_mm`` and ``cell_mm`` cells."""

    heightmap: np.ndarray
    volume: float
    height: int
    rim_mm: int
    cell_mm: int


def greedy_end(pile: Pile, items: Sequence[ShownItem], order: str = "sdf") -> tuple[float, int]:
    """(V, H) after the greedy play of ``items`` in ``order`` (module docstring) from ``pile``."""
    hm, volume, height = pile.heightmap, pile.volume, pile.height
    rim_mm, cell_mm = pile.rim_mm, pile.cell_mm
    left = list(items)
    while left:
        cands = search_candidates(hm, left, rim_mm, cell_mm)
        if len(cands) == 0:
            break  # nothing fits the floor: the boxes left are lost either way
        box_volume = np.prod(cands.shown_sizes_mm[cands.obj], axis=1).astype(np.float64)
        inside = 2 * cands.z + cands.h <= 2 * rim_mm
        keeps = np.flatnonzero(cands.top <= height + LEVEL_TOLERANCE_MM)
        if keeps.size:
            i = _keeping_order(cands, keeps, order)
        else:
            after = (volume + box_volume * inside) ** 2 / np.maximum(height, cands.top)
            i = int(np.argmax(after))
            if after[i] <= end_ratio(volume, height):
                break  # no box is worth raising the top for: the rest is set aside
        x, y, fx, fy, top = (int(a[i]) for a in (cands.x, cands.y, cands.fx, cands.fy, cands.top))
        hm = place_box(hm, x, y, fx, fy, top)
        volume += float(box_volume[i]) * bool(inside[i])
        height = max(height, top)
        left.pop(int(cands.obj[i]))
    return volume, height


def best_end(pile: Pile, items: Sequence[ShownItem]) -> float:
    """The best V**2 / H over the :data:`GREEDY_ORDERS` of :func:`greedy_end`."""
    ends = (greedy_end(pile, items, order) for order in GREEDY_ORDERS)
    return max(end_ratio(v, h) for v, h in ends)


#: The most boxes in view for which the rule decides (module docstring). Chosen on generated
#: training cases of five families (docs/history/planner.md): 8 against 3, 5 and no limit.
FINALE_BOXES = 8


def finale_decision(
    observation: Observation, action: Action, max_boxes: int = FINALE_BOXES
) -> Action | None:
    """A set-aside that ends the episode higher than ``action`` (the planner's placement), or
    None: keep ``action``. Only where :func:`everything_in_view` holds with at most
    ``max_boxes`` boxes shown and ``action`` raises the highest cell."""
    if not everything_in_view(observation) or action.sets_aside:
        return None
    if len(observation.shown) > max_boxes:
        return None
    rim = observation.container.height_mm
    cell = observation.container.cell_xy_mm
    hm = np.asarray(observation.heightmap).astype(np.int64)
    height = max(int(hm.max()), 1)
    shown = list(observation.shown)
    chosen = search_candidates(hm, [shown[action.object_id]], rim, cell)
    match = np.flatnonzero(
        (chosen.rotation == action.rotation) & (chosen.x == action.x) & (chosen.y == action.y)
    )
    if match.size == 0:
        return None
    i = int(match[0])
    top = int(chosen.top[i])
    if top <= height + LEVEL_TOLERANCE_MM:
        return None  # keeps the top: nothing to weigh
    volume = float(packed_inside_volume(observation))
    inside = 2 * int(chosen.z[i]) + int(chosen.h[i]) <= 2 * rim
    x, y, fx, fy = (int(a[i]) for a in (chosen.x, chosen.y, chosen.fx, chosen.fy))
    placed = place_box(hm, x, y, fx, fy, top)
    others = shown[: action.object_id] + shown[action.object_id + 1 :]
    box = float(np.prod(shown[action.object_id].size_mm)) * inside
    best = best_end(Pile(placed, volume + box, max(height, top), rim, cell), others)
    now = Pile(hm, volume, height, rim, cell)
    aside = None
    for k in range(len(shown)):
        end = best_end(now, shown[:k] + shown[k + 1 :])
        if end > best * (1 + 1e-9):  # strictly better: ties keep the placement
            best, aside = end, k
    return None if aside is None else Action.set_aside(aside)


def with_finale(
    observation: Observation, action: Action, rule: OverflowRule, max_boxes: int = FINALE_BOXES
) -> Action:
    """``action``, or the set-aside :func:`finale_decision` prefers to it under rule ``score``."""
    if rule != "score":
        return action
    aside = finale_decision(observation, action, max_boxes)
    return action if aside is None else aside
