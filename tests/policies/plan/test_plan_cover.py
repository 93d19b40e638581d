"""Exact rectangle cover: tilings are exact, found whenever one exists, refused when none can."""

from __future__ import annotations

import numpy as np
import pytest
from layered_cases import _split

from packlab.policies.plan.cover import (
    JOKER,
    CoverRules,
    Piece,
    coverable_by_squares,
    exact_cover,
    subset_sums,
)


def _check_tiling(region: np.ndarray, slots) -> None:
    """Every slot inside the region, no cell covered twice, every region cell covered."""
    count = np.zeros(region.shape, dtype=int)
    for s in slots:
        count[s.x : s.x + s.fx, s.y : s.y + s.fy] += 1
    assert count.max() <= 1, "two slots overlap"
    assert np.array_equal(count == 1, region), "the slots do not cover the region exactly"


@pytest.mark.parametrize("seed", range(12))
def test_a_shuffled_guillotine_partition_is_found_again(seed):
    rng = np.random.default_rng(seed)
    nx, ny = int(rng.integers(10, 30)), int(rng.integers(10, 30))
    rects = _split(rng, nx, ny, int(rng.integers(3, 10)), 3)
    pieces = [
        Piece(i, dy, dx) if rng.random() < 0.5 else Piece(i, dx, dy)
        for i, (_, _, dx, dy) in enumerate(rects)
    ]
    rng.shuffle(pieces)
    result = exact_cover(np.ones((nx, ny), bool), pieces, max_nodes=200_000)
    assert result.slots is not None and not result.exhausted
    _check_tiling(np.ones((nx, ny), bool), result.slots)
    assert sorted(s.key for s in result.slots) == list(range(len(rects)))  # area forces all


def test_a_region_with_a_hole_is_tiled_around_it():
    region = np.ones((6, 6), bool)
    region[2:4, 2:4] = False  # a 2 x 2 column in the middle
    pieces = [Piece(0, 2, 4), Piece(1, 4, 2), Piece(2, 2, 4), Piece(3, 4, 2)]
    result = exact_cover(region, pieces)
    assert result.slots is not None
    _check_tiling(region, result.slots)


def test_the_first_slot_covers_the_first_cell_of_the_region():
    region = np.zeros((8, 8), bool)
    region[3:8, 2:6] = True
    result = exact_cover(region, [Piece(0, 5, 2), Piece(1, 2, 5)])
    assert result.slots is not None
    assert (result.slots[0].x, result.slots[0].y) == (3, 2)


def test_no_tiling_is_answered_without_running_out_of_budget():
    # 5 x 5 cannot be cut into 3 x 2 rectangles (25 is not a multiple of 6)...
    result = exact_cover(np.ones((5, 5), bool), [Piece(i, 3, 2) for i in range(6)])
    assert result.slots is None and not result.exhausted
    # ...while 6 x 5, the area of five of them, is tiled (columns of 2 + 3).
    result = exact_cover(np.ones((6, 5), bool), [Piece(i, 3, 2) for i in range(5)])
    assert result.slots is not None
    _check_tiling(np.ones((6, 5), bool), result.slots)
    # A sliver: a 4-wide strip cannot take 3-wide pieces, whatever their number.
    result = exact_cover(np.ones((4, 9), bool), [Piece(i, 3, 3) for i in range(4)])
    assert result.slots is None and not result.exhausted


def test_a_tiny_budget_says_it_ran_out():
    rng = np.random.default_rng(3)
    rects = _split(rng, 24, 20, 9, 3)
    pieces = [Piece(i, dx, dy) for i, (_, _, dx, dy) in enumerate(rects)]
    result = exact_cover(np.ones((24, 20), bool), pieces, max_nodes=2)
    assert result.slots is None and result.exhausted


def test_one_joker_fills_exactly_what_every_piece_leaves():
    region = np.ones((10, 6), bool)
    rules = CoverRules(jokers=1, use_all=True, joker_side=3)
    result = exact_cover(region, [Piece(0, 4, 6)], rules=rules)
    assert result.slots is not None
    _check_tiling(region, result.slots)
    jokers = [s for s in result.slots if s.key == JOKER]
    assert len(jokers) == 1 and jokers[0].fx * jokers[0].fy == 60 - 24


def test_use_all_refuses_a_tiling_that_leaves_a_piece_out():
    region = np.ones((4, 4), bool)
    pieces = [Piece(0, 4, 4), Piece(1, 2, 2)]
    assert exact_cover(region, pieces).slots is not None  # the big piece alone
    rules = CoverRules(jokers=1, use_all=True, joker_side=2)
    assert exact_cover(region, pieces, rules=rules).slots is None


def test_jokers_are_never_narrower_than_their_side():
    region = np.ones((7, 6), bool)
    rules = CoverRules(jokers=2, use_all=True, joker_side=3)
    # a 5 x 6 piece leaves a 2 x 6 strip: narrower than a joker may be
    assert exact_cover(region, [Piece(0, 5, 6)], rules=rules).slots is None
    result = exact_cover(region, [Piece(0, 4, 6)], rules=rules)
    assert result.slots is not None
    assert all(min(s.fx, s.fy) >= 3 for s in result.slots if s.key == JOKER)


def test_subset_sums_and_square_coverage():
    reach = subset_sums([3, 5])
    assert [s for s in range(10) if (reach >> s) & 1] == [0, 3, 5, 8]
    l_shape = np.ones((6, 6), bool)
    l_shape[3:, 3:] = False
    assert coverable_by_squares(l_shape, 3)
    l_shape[0:2, :] = False  # rows 2 and 3..5 left: a 1-cell-thick row of the upper arm
    assert not coverable_by_squares(l_shape, 3)


def test_a_guess_keeps_the_tiling_whose_narrowest_joker_is_widest():
    # 10 x 9 with one 4 x 5 box and two jokers: the first tiling in search order leaves a
    # 4-wide strip; among the first 32 there is one whose jokers are all at least 5 wide.
    region = np.ones((10, 9), bool)
    pieces = [Piece(0, 4, 5)]

    def narrowest(tilings: int) -> int:
        rules = CoverRules(jokers=2, use_all=True, joker_side=3, tilings=tilings)
        result = exact_cover(region, pieces, rules=rules)
        assert result.slots is not None
        _check_tiling(region, result.slots)
        return min(min(s.fx, s.fy) for s in result.slots if s.key == JOKER)

    assert narrowest(1) == 4 and narrowest(32) == 5
