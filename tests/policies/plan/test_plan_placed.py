"""The planner reads its own placements back into the heightmap it completes."""

from __future__ import annotations

import numpy as np

from packlab.core.types import Action, Container, HistoryEntry, Observation, ShownItem
from packlab.policies.plan.complete import find_completion
from packlab.policies.plan.placed import with_own_placements

CONTAINER = Container((250, 150, 300))  # 10 x 6 cells of 25 mm
CARTON = ShownItem(0, 0, (140, 140, 100), (6, 6, 50))  # 10 mm short of its 6 cells


def _observation(now: np.ndarray, action: Action) -> Observation:
    """One past step that put ``CARTON`` with ``action`` on the empty floor; ``now`` is the
    heightmap seen after it."""
    before = np.zeros((10, 6), np.int32)
    step = HistoryEntry(before, (CARTON,), action, True)
    rest = ShownItem(0, 1, (100, 150, 100), (4, 6, 50))
    return Observation(1, CONTAINER, now, (rest,), (step,), remaining=1)


def _carton_at_corner(missing_column: bool) -> np.ndarray:
    hm = np.zeros((10, 6), np.int32)
    hm[0:6, :] = 100
    if missing_column:
        hm[5, :] = 0  # the carton's last column: its edge missed the cell centres
    return hm


def test_a_border_column_a_carton_left_showing_is_read_as_its_top():
    seen = _carton_at_corner(missing_column=True)
    observation = _observation(seen, Action(0, 0, 0, 0))
    read = with_own_placements(observation)
    assert (read == _carton_at_corner(missing_column=False)).all()
    assert (observation.heightmap == seen).all()  # the observation itself is left alone
    # With the column read back, the rest of the floor is exactly the next box's 4 x 6 cells.
    assert find_completion(seen, observation.shown, 300, 0, 3) is None
    found = find_completion(read, observation.shown, 300, 0, 3)
    assert found is not None and [(s.x, s.y) for s in found.slots] == [(6, 0)]


def test_a_box_that_is_not_where_it_was_put_is_read_as_seen():
    seen = np.zeros((10, 6), np.int32)
    seen[0:6, 0:3] = 100  # half the footprint: the box toppled, or went elsewhere
    assert (with_own_placements(_observation(seen, Action(0, 0, 0, 0))) == seen).all()
    aside = _observation(_carton_at_corner(missing_column=True), Action.set_aside(0))
    assert (with_own_placements(aside) == aside.heightmap).all()


def test_a_placement_whose_footprint_shows_it_whole_changes_nothing():
    seen = _carton_at_corner(missing_column=False)
    observation = _observation(seen, Action(0, 0, 0, 0))
    assert with_own_placements(observation) is observation.heightmap
