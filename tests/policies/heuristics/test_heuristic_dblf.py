"""DBLF on hand-made states."""

from __future__ import annotations

import heuristics_reference as ref
import numpy as np

from packlab.core.feasibility import search_candidates
from packlab.core.types import Action, ShownItem
from packlab.policies.heuristics import dblf
from packlab.policies.heuristics.select import choose, to_action


def pick(hm, shown, rim=200) -> Action:
    c = search_candidates(np.asarray(hm, dtype=np.int32), shown, rim)
    return to_action(c, choose(c, dblf.score(c)))


def test_height_dominates_then_depth_then_left() -> None:
    hm = [[30, 30, 0], [30, 30, 0], [0, 0, 0]]
    # Object 0 (2 x 2) rests at 30 mm wherever it goes. Object 1 (1 x 2) reaches the floor at
    # rotation 0 on x = 2 (y = 0 or 1) and at rotation 1 on y = 2 (x = 0 or 1): the deepest
    # (smallest x) of those is rotation 1 at (0, 2), even though object 0 comes first.
    shown = [ref.shown_item(0, 2, 2, 50), ref.shown_item(1, 1, 2, 20)]
    assert pick(hm, shown) == Action(1, 1, 0, 2)


def test_depth_before_left() -> None:
    # Floor cells (1, 0) and (0, 1): x decides before y, so (0, 1).
    hm = [[40, 0], [0, 40]]
    assert pick(hm, [ref.shown_item(0, 1, 1, 10)]) == Action(0, 0, 0, 1)


def test_tie_between_identical_objects_and_rotations() -> None:
    # Two equal square boxes on an empty floor: both objects and both rotations tie at
    # (z, x, y) = (0, 0, 0). Rotation 0 wins; of the identical boxes the default takes the
    # smaller id (shown second here), shown_order the first shown.
    shown = [ShownItem(0, 9, (25, 25, 30), (1, 1, 15)), ShownItem(1, 4, (25, 25, 30), (1, 1, 15))]
    c = search_candidates(np.zeros((2, 2), dtype=np.int32), shown, 200)
    assert to_action(c, choose(c, dblf.score(c))) == Action(1, 0, 0, 0)
    assert to_action(c, choose(c, dblf.score(c), "shown_order")) == Action(0, 0, 0, 0)
