"""HM on hand-made states, and its heightmap increase against hand-computed values."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np

from packlab.core.feasibility import search_candidates
from packlab.core.types import Action
from packlab.policies.heuristics import dblf, hm
from packlab.policies.heuristics.select import choose, to_action

CELL_AREA = 25 * 25


def cands(heights, shown, rim=200):
    return search_candidates(np.asarray(heights, dtype=np.int32), shown, rim)


def test_increase_is_volume_plus_sealed_space() -> None:
    # 3 x 1 floor with heights (0, 40, 40); a 2 x 1 box 50 mm tall.
    c = cands([[0], [40], [40]], [ref.shown_item(0, 2, 1, 50)])
    # x = 0: rests at 40, top 90: (90 - 0) + (90 - 40) = 140 mm over one cell each.
    # x = 1: rests at 40, top 90: (90 - 40) * 2 = 100.
    assert hm.heightmap_increase_mm3(c).tolist() == [140 * CELL_AREA, 100 * CELL_AREA]


def test_picks_the_smallest_increase_where_dblf_would_not() -> None:
    c = cands([[0], [40], [40]], [ref.shown_item(0, 2, 1, 50)])
    assert to_action(c, choose(c, hm.score(c))) == Action(0, 0, 1, 0)
    assert to_action(c, choose(c, dblf.score(c))) == Action(0, 0, 0, 0)


def test_chooses_the_object_jointly() -> None:
    # Adding a 1 x 1 box: on the floor at x = 0 it adds only its own 50 mm column.
    c = cands([[0], [40], [40]], [ref.shown_item(0, 2, 1, 50), ref.shown_item(1, 1, 1, 50)])
    assert to_action(c, choose(c, hm.score(c))) == Action(1, 0, 0, 0)


def test_equal_increase_ties_go_bottom_first() -> None:
    # A 50 mm box adds 50 mm of column on either cell; the floor cell (lower z) wins.
    c = cands([[20], [0]], [ref.shown_item(0, 1, 1, 50)])
    assert hm.heightmap_increase_mm3(c).tolist() == [50 * CELL_AREA] * 4
    assert to_action(c, choose(c, hm.score(c))) == Action(0, 0, 1, 0)
