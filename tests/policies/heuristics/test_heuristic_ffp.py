"""FFP on hand-made states."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np

from packlab.core.feasibility import search_candidates
from packlab.core.types import Action
from packlab.policies.heuristics import ffp
from packlab.policies.heuristics.select import choose, to_action


def pick(hm, shown, rim=100) -> Action:
    c = search_candidates(np.asarray(hm, dtype=np.int32), shown, rim)
    return to_action(c, choose(c, ffp.score(c)))


def test_first_in_scan_order_ignores_height() -> None:
    # (0, 0) is 80 mm up but still within the rim with a 10 mm box: it is first, so it is taken.
    assert pick([[80, 0], [0, 0]], [ref.shown_item(0, 1, 1, 10)]) == Action(0, 0, 0, 0)


def test_skips_objects_that_never_stay_within_the_rim() -> None:
    shown = [ref.shown_item(0, 1, 1, 150), ref.shown_item(1, 2, 1, 50)]
    assert pick(np.zeros((2, 2)), shown) == Action(1, 0, 0, 0)


def test_rotation_1_when_rotation_0_does_not_fit_the_floor() -> None:
    # 3 x 1 cells on a 2 x 3 floor: only the yawed footprint (1 x 3) fits.
    assert pick(np.zeros((2, 3)), [ref.shown_item(0, 3, 1, 10)]) == Action(0, 1, 0, 0)


def test_first_in_rim_cell_after_taller_ones() -> None:
    # A 40 mm box on a 100 mm rim: cells at 70 mm are out, the first in scan order at 60 is (1, 0).
    hm = [[70, 70], [60, 0]]
    assert pick(hm, [ref.shown_item(0, 1, 1, 40)]) == Action(0, 0, 1, 0)


def test_all_over_the_rim_takes_the_lowest_top() -> None:
    hm = [[90, 95], [80, 99]]
    assert pick(hm, [ref.shown_item(0, 1, 1, 40)]) == Action(0, 0, 1, 0)
