"""Completion: fill the lowest open part of the container exactly with the boxes in view (pure).

Every box of a perfect layout rests flush on what is under it, so a perfect packing is built
from the bottom up by closing the lowest free region without waste. This module looks at the
lowest level of the heightmap (the cells the same level as its minimum or below, split into
4-connected components) and asks, for each component, whether the shown boxes of one height
tile it exactly (:func:`.cover.exact_cover`). When they do, the completion is certain to leave
no gap at that level, and the planner commits its first box.

Boxes of one height: a component closed with one height gets a flat top, the state a layered
layout goes through; heights are tried in order of how well they continue the neighbours (a
height that brings the component level with the columns around it first), then by the area
shown in that height. "One height" is one height class (:func:`height_classes`): heights within
the level tolerance of the class's tallest, so cartons a few mm lower than their slots still
close a layer (to a top as uneven as the class, which :func:`lowest_level_top` reads as one
level); heights in whole centimetres each make their own class.

When no exact tiling exists and boxes are still to come, a *guess* may leave up to
``max_jokers`` rectangles for them (:class:`.cover.CoverRules`), for the component's likeliest
height only and only when that height has been seen ``joker_min_seen`` times. A guess is not
certain: the unseen boxes may not fill its rectangles. Where neither exists the planner's
lookahead decides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from packlab.core.choices import CommitRule
from packlab.core.types import ShownItem
from packlab.policies.features import LEVEL_TOLERANCE_MM, same_level
from packlab.policies.plan.cover import JOKER, CoverResult, CoverRules, Piece, Slot, exact_cover
from packlab.policies.windows import ring4

#: 4-connectivity: two cells of a level belong together only when they share a side.
_FOUR = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True, slots=True)
class CompletionConfig:
    """How the completion search reads the heightmap and how much it may search."""

    #: Cells within this of the minimum count as one level: the planner's one "same level"
    #: tolerance (:data:`packlab.policies.features.LEVEL_TOLERANCE_MM`, where the value is
    #: argued); a field only so a test can vary it.
    tolerance_mm: int = LEVEL_TOLERANCE_MM
    #: Node budget of one exact-cover search (one component and one height).
    max_nodes: int = 100_000
    #: Node budget of all the searches of one decision together: a decision runs up to one
    #: search per stage, component and height, and a few that each ran out of ``max_nodes``
    #: made the planner's rare slow steps (27 s once on a medium case under stereo noise).
    #: At about 4 us per node (benchmarks/maintainers/cover_speed.py) this caps a decision's
    #: completion near 1 s on one core; the searches it cuts short are those that were failing
    #: anyway.
    decision_nodes: int = 250_000
    #: A guess with jokers needs at least this many boxes of the height seen so far (history
    #: included): a height seen once says nothing about a layer of that height (boxes of
    #: independent sizes rarely share one).
    joker_min_seen: int = 3
    #: The smallest box side (mm) the planner expects among boxes it has not seen: a joker or
    #: a free strip narrower than min(this, the smallest side seen) cannot be filled. The
    #: default is the data engine's smallest side (7.5 cm).
    smallest_side_mm: int = 75
    #: At most this many rectangles left for unseen boxes in one guess (0: exact tilings only).
    max_jokers: int = 3
    #: Tilings a guess looks at before keeping the one whose narrowest rectangle is widest.
    guesses: int = 32
    #: Which box of a guess to place now (:func:`commit_of`): ``enclosed`` (the default) or
    #: ``first`` (its first real box in scan order).
    commit: CommitRule = "enclosed"
    #: Last stage: tile a lowest component with shown boxes of any heights (and jokers), for
    #: perfect packings not built in flat layers (cut layouts: the floor is tiled by boxes of
    #: many heights). Tried only after every one-height stage failed.
    mixed: bool = True
    #: At most this many rectangles for unseen boxes in a mixed-height tiling (also capped by
    #: ``max_jokers``; 0: exact mixed tilings only). Unlike a one-height guess (made only for
    #: a height seen ``joker_min_seen`` times) a mixed-height guess asks for no evidence, and on
    #: boxes of independent sizes ten shown boxes plus rectangles "tile" almost any floor:
    #: there 0 scored higher (+0.012 to +0.016 on generated random-box cases), on cut layouts
    #: the guesses win and lose by turns (docs/history/planner.md, "The mixed-height stage"),
    #: so the default keeps them.
    mixed_jokers: int = 3
    #: A mixed-height tiling may leave rectangles for unseen boxes only when at least this
    #: share of the boxes seen so far (each once) repeats the exact height of another seen box
    #: (:func:`repeated_height_share`); exact mixed tilings are always tried. Boxes cut from
    #: one perfect layout repeat heights (a cut leaves two pieces of one height); boxes drawn
    #: independently rarely do, and there a guess that unseen boxes will fill the rest of the
    #: floor is usually wrong. 0: no evidence asked.
    mixed_evidence: float = 0.0

    @property
    def stages(self) -> tuple[tuple[int, bool], ...]:
        """Searches in order, as (jokers, every shown box of the height used): an exact tiling
        by shown boxes alone, then all of them plus 1, 2, ... rectangles for boxes not yet seen
        (a guillotine layer's unseen part is often one or two rectangles), then a subset of
        them plus 2, 3, ... rectangles."""
        with_all = [(j, True) for j in range(1, self.max_jokers + 1)]
        subset = [(j, False) for j in range(2, self.max_jokers + 1)]
        return ((0, False), *with_all, *subset)


@dataclass(frozen=True, slots=True)
class Completion:
    """A tiling of one lowest component by shown boxes of one height (and jokers, if a guess),
    or of mixed heights (``height_mm`` 0)."""

    slots: tuple[Slot, ...]  # Slot.key indexes the shown buffer (JOKER: left for unseen boxes)
    z_mm: int  # the level the boxes rest at
    height_mm: int  # the height of every box of the tiling; 0 when their heights differ
    nodes: int
    jokers: int  # rectangles of the tiling left for boxes not yet seen
    #: The box to place now (:func:`commit_of`): a real box of ``slots`` or, for a guess, of
    #: another tiling the guess enumerated.
    commit: Slot


def enclosed_sides(region: np.ndarray, slot: Slot) -> int:
    """How many of ``slot``'s four sides lie along a wall or cells outside ``region`` (0-4)."""
    nx, ny = region.shape
    x0, y0, x1, y1 = slot.x, slot.y, slot.x + slot.fx, slot.y + slot.fy
    return (
        int(x0 == 0 or not region[x0 - 1, y0:y1].any())
        + int(x1 == nx or not region[x1, y0:y1].any())
        + int(y0 == 0 or not region[x0:x1, y0 - 1].any())
        + int(y1 == ny or not region[x0:x1, y1].any())
    )


def commit_of(result: CoverResult, region: np.ndarray, rule: CommitRule = "enclosed") -> Slot:
    """The box a tiling commits now. An exact tiling: its first real box in scan order (every
    box of it is certain). A guess: the same, unless a real box of the tilings the guess
    enumerated is enclosed on more sides (walls, or cells outside the region: placed boxes);
    then the most enclosed, the one most tilings share among equals. Why: a box the guess
    places against its rectangles for unseen boxes has its place set by their guessed sizes;
    one closed in by what is already there does not. On generated layered training cases a
    guess's commit was fatal (the layer no longer closable by the boxes really to come, a
    diagnostic that read the cases) for 1 % of commits closed in on three sides, 7 % on two
    and 16 % on one (docs/history/planner.md, "The commit of a guess")."""
    assert result.slots is not None
    first = next(s for s in result.slots if s.key != JOKER)
    guess = any(s.key == JOKER for s in result.slots)
    if rule == "first" or not guess or not result.tilings:
        return first
    count: dict[tuple[int, int, int, int], int] = {}
    slot_of: dict[tuple[int, int, int, int], Slot] = {}
    for tiling in result.tilings:
        for s in tiling:
            if s.key != JOKER:
                key = (s.key, s.rotation, s.x, s.y)
                count[key] = count.get(key, 0) + 1
                slot_of.setdefault(key, s)
    best = max(count, key=lambda k: (enclosed_sides(region, slot_of[k]), count[k]))
    chosen = slot_of[best]
    return chosen if enclosed_sides(region, chosen) > enclosed_sides(region, first) else first


def lowest_level_top(hm: np.ndarray, tolerance_mm: int, spread_mm: int = 0) -> int:
    """The highest height (mm) of the lowest level: ``tolerance_mm`` over the minimum, and with
    boxes whose heights spread (``spread_mm`` > 0: the widest height class seen, tallest minus
    lowest, see :func:`height_classes`) the heights reached from the minimum in steps of at
    most the tolerance, up to ``tolerance_mm + 2 * spread_mm`` over it. A layer of boxes a few
    mm apart in height leaves its top that uneven, and the next layer on it more so (two
    layers' spread: chosen on generated off-grid training cases, where 8 and 12 mm of reach
    scored alike); levels of boxes whose heights come in whole centimetres (no spread) read as
    the same-level tolerance alone reads them."""
    z0 = int(hm.min())
    if spread_mm <= 0:
        return z0 + tolerance_mm
    reach, top = z0 + tolerance_mm + 2 * spread_mm, z0
    for v in np.unique(hm)[1:]:
        if v - top > tolerance_mm or v > reach:
            break
        top = int(v)
    return max(top, z0 + tolerance_mm)


def lowest_components(
    heightmap: np.ndarray, tolerance_mm: int = LEVEL_TOLERANCE_MM, spread_mm: int = 0
) -> tuple[int, list[np.ndarray]]:
    """(the lowest level in mm, its 4-connected components as bool masks, smallest first);
    ``spread_mm``: see :func:`lowest_level_top`."""
    hm = np.asarray(heightmap)
    z0 = int(hm.min())
    labels, n = ndimage.label(hm <= lowest_level_top(hm, tolerance_mm, spread_mm), structure=_FOUR)
    masks = [labels == k for k in range(1, n + 1)]
    masks.sort(key=lambda m: (int(m.sum()), int(np.argmax(m.ravel()))))
    return z0, masks


def rim_heights(heightmap: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Heights (mm) of the cells just outside ``mask`` (4-neighbours), walls excluded."""
    return np.asarray(heightmap)[ring4(mask)]


def height_classes(
    heights: Sequence[int], tolerance_mm: int = LEVEL_TOLERANCE_MM
) -> dict[int, int]:
    """Each height (mm) mapped to its class: the tallest height not yet in a class takes every
    height down to ``tolerance_mm`` below it, and so on down. Boxes of one class close a
    component to a top level within the tolerance (what the lowest level reads as one level
    next): cartons made a few mm lower than their slot, or heights a sensor measured to a few
    mm, still make one layer. Heights on the generator's grid (whole centimetres) each make
    their own class."""
    classes: dict[int, int] = {}
    top: int | None = None
    for h in sorted(set(heights), reverse=True):
        if top is None or h < top - tolerance_mm:
            top = h
        classes[h] = top
    return classes


def height_order(
    heightmap: np.ndarray,
    mask: np.ndarray,
    z0: int,
    shown: Sequence[ShownItem],
    tolerance_mm: int = LEVEL_TOLERANCE_MM,
    class_of: dict[int, int] | None = None,
) -> list[int]:
    """The shown boxes' height classes (``class_of``, by default :func:`height_classes` of
    the shown heights; each named by its tallest height, mm) in the order to try them for
    ``mask`` (module docstring)."""
    rim = rim_heights(heightmap, mask) - z0
    if class_of is None:
        class_of = height_classes([s.size_mm[2] for s in shown], tolerance_mm)
    area: dict[int, int] = {}
    for s in shown:
        h = class_of[s.size_mm[2]]
        area[h] = area.get(h, 0) + s.size_cells[0] * s.size_cells[1]

    def key(h: int) -> tuple[int, int, int]:
        level_with = int(np.count_nonzero(same_level(rim, h, tolerance_mm)))
        return (-level_with, -area[h], h)

    return sorted(area, key=key)


def find_completion(
    heightmap: np.ndarray,
    shown: Sequence[ShownItem],
    container_height_mm: int,
    unseen: int,
    smallest_side: int,
    seen_heights: Sequence[int] = (),
    config: CompletionConfig = CompletionConfig(),
) -> Completion | None:
    """A tiling of one lowest component by shown boxes of one height, and with ``unseen`` > 0
    (boxes still to come) up to the configured jokers for them; None when no stage finds one."""
    # One set of classes for the shown boxes and the heights seen (a guess counts its class's).
    class_of = height_classes(
        [s.size_mm[2] for s in shown] + list(seen_heights), config.tolerance_mm
    )
    spread = max((top - h for h, top in class_of.items()), default=0)  # the widest class
    z0, masks = lowest_components(heightmap, config.tolerance_mm, spread)
    spent = 0  # nodes of this decision's searches so far (CompletionConfig.decision_nodes)
    orders = [
        height_order(heightmap, mask, z0, shown, config.tolerance_mm, class_of) for mask in masks
    ]
    for jokers, use_all in config.stages:
        if jokers > unseen:
            continue
        for mask, heights in zip(masks, orders):
            area = int(mask.sum())
            # Jokers only with the height most likely to be this level's: a guess about unseen
            # boxes is worth making for the layer under way, not for a box of another layer.
            for h in heights if not jokers else heights[:1]:
                if z0 + h > container_height_mm:
                    continue
                pieces = [
                    Piece(s.shown_index, s.size_cells[0], s.size_cells[1])
                    for s in shown
                    if class_of[s.size_mm[2]] == h
                ]
                if not jokers and sum(p.area for p in pieces) < area:
                    continue
                seen = sum(class_of[g] == h for g in seen_heights)
                if jokers and seen < config.joker_min_seen:
                    continue
                budget = min(config.max_nodes, config.decision_nodes - spent)
                if budget <= 0:
                    return None
                rules = CoverRules(jokers, use_all, smallest_side, config.guesses)
                result: CoverResult = exact_cover(mask, pieces, budget, rules)
                spent += result.nodes
                if result.slots and any(s.key != JOKER for s in result.slots):
                    n = sum(s.key == JOKER for s in result.slots)
                    commit = commit_of(result, mask, config.commit)
                    return Completion(result.slots, z0, h, result.nodes, n, commit)
    if config.mixed:
        return _mixed_completion(
            masks,
            z0,
            shown,
            container_height_mm,
            unseen,
            smallest_side,
            config,
            config.decision_nodes - spent,
            seen_heights,
        )
    return None


def repeated_height_share(seen_heights: Sequence[int]) -> float:
    """The share of ``seen_heights`` (one entry per box seen) equal to another entry; 0.0 for
    none seen."""
    if not seen_heights:
        return 0.0
    _, inverse, counts = np.unique(
        np.asarray(seen_heights), return_inverse=True, return_counts=True
    )
    return float(np.count_nonzero(counts[inverse] >= 2)) / len(seen_heights)


def _mixed_completion(
    masks: Sequence[np.ndarray],
    z0: int,
    shown: Sequence[ShownItem],
    container_height_mm: int,
    unseen: int,
    smallest_side: int,
    config: CompletionConfig,
    budget_left: int,
    seen_heights: Sequence[int],
) -> Completion | None:
    """A tiling of one lowest component by shown boxes of any heights that fit under the lid,
    exact first, then with up to ``config.mixed_jokers`` rectangles for boxes still to come when
    the share of ``seen_heights`` repeating another (:func:`repeated_height_share`) reaches
    ``config.mixed_evidence``."""
    pieces = [
        Piece(s.shown_index, s.size_cells[0], s.size_cells[1])
        for s in shown
        if z0 + s.size_mm[2] <= container_height_mm
    ]
    if not pieces:
        return None
    # The share is only read when the gate is on (mixed_evidence 0 asks for no evidence).
    evident = not config.mixed_evidence or (
        repeated_height_share(seen_heights) >= config.mixed_evidence
    )
    guesses = config.mixed_jokers if evident else 0
    for jokers in range(min(guesses, config.max_jokers, unseen) + 1):
        for mask in masks:
            budget = min(config.max_nodes, budget_left)
            if budget <= 0:
                return None
            rules = CoverRules(jokers, False, smallest_side, config.guesses)
            result = exact_cover(mask, pieces, budget, rules)
            budget_left -= result.nodes
            if result.slots and any(s.key != JOKER for s in result.slots):
                n = sum(s.key == JOKER for s in result.slots)
                return Completion(
                    result.slots, z0, 0, result.nodes, n, commit_of(result, mask, config.commit)
                )
    return None
