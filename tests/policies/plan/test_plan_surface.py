"""The planner's surface measures on small hand-made heightmaps."""

from __future__ import annotations

import numpy as np

from packlab.policies.plan.evaluate import smallest_footprints
from packlab.policies.plan.surface import (
    open_volume,
    reachable_floor,
    step_area,
    unreachable_volume,
)


def test_a_pit_narrower_than_the_footprint_is_unreachable_and_a_wide_one_is_not():
    hm = np.full((6, 4), 100, dtype=np.int32)
    hm[2, :] = 40  # a one-cell-wide trench across the map, 60 mm deep
    assert (reachable_floor(hm, 2, 2)[2] == 100).all()
    assert unreachable_volume(hm, ((2, 2),)) == 60 * 4
    assert unreachable_volume(hm, ((1, 4),)) == 0  # a 1 x 4 box drops into it
    hm[2:4, :] = 40  # now two cells wide: a 2 x 2 box reaches the bottom
    assert unreachable_volume(hm, ((2, 2),)) == 0


def test_cells_by_the_walls_take_their_minimum_over_the_windows_that_exist():
    hm = np.zeros((3, 3), dtype=np.int32)
    hm[1, 1] = 50
    assert (reachable_floor(hm, 3, 3) == 50).all()  # the one window covers everything
    assert unreachable_volume(hm, ((3, 3),)) == 8 * 50


def test_open_volume_and_steps_vanish_on_a_level_surface():
    level = np.full((4, 5), 70, dtype=np.int32)
    assert open_volume(level) == 0 and step_area(level) == 0
    ragged = level.copy()
    ragged[0, 0] = 100
    assert open_volume(ragged) == 19 * 30
    assert step_area(ragged) == 2 * 30


def test_smallest_footprints_keep_both_rotations_of_the_smallest_seen():
    assert smallest_footprints([(4, 4), (2, 3), (3, 2), (5, 1)], keep=2) == (
        (1, 5),
        (5, 1),
        (2, 3),
        (3, 2),
    )
