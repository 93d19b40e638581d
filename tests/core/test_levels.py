"""The one "same level" definition (packlab.core.levels, re-exported by policies.features)."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core import levels
from packlab.policies import features


def test_features_re_exports_the_one_definition() -> None:
    assert features.same_level is levels.same_level
    assert features.LEVEL_TOLERANCE_MM == levels.LEVEL_TOLERANCE_MM == 4


@pytest.mark.parametrize(
    "a, b, same",
    [
        (300, 300, True),
        (300, 304, True),  # per-top error of a perceived map, either side
        (304, 300, True),
        (300, 305, False),
        (300, 310, False),  # one box-height step: always two levels
        (0, -4, True),
    ],
)
def test_same_level_of_two_scalars(a, b, same) -> None:
    assert bool(levels.same_level(a, b)) is same


def test_same_level_is_vectorised_and_broadcasts() -> None:
    tops = np.array([[296, 300, 303], [305, 310, 0]], dtype=np.int32)
    assert levels.same_level(tops, 300).tolist() == [[True, True, True], [False, False, False]]
    assert levels.same_level(tops, np.array([[300], [310]])).tolist() == [
        [True, True, True],
        [False, True, False],
    ]


def test_unsigned_heights_do_not_wrap() -> None:
    a = np.array([0, 10], dtype=np.uint16)
    assert levels.same_level(a, np.uint16(2)).tolist() == [True, False]


def test_a_tolerance_of_zero_is_exact_equality() -> None:
    assert levels.same_level([299, 300, 301], 300, tolerance_mm=0).tolist() == [False, True, False]


def test_at_or_below_and_above_level_split_every_height() -> None:
    heights = np.arange(280, 321)
    below = levels.at_or_below(heights, 300)
    above = levels.above_level(heights, 300)
    assert np.array_equal(below, heights <= 304)
    assert np.array_equal(above, ~below)
    # Every height the same level as 300 is at-or-below it; none of them is above it.
    same = levels.same_level(heights, 300)
    assert not np.any(same & above) and np.all(below[same])


def test_a_face_rises_clearly_beyond_the_level_band() -> None:
    # Not the same level, and beyond it by more than the band's width: the two questions differ.
    assert levels.FACE_RISE_MM > 2 * levels.LEVEL_TOLERANCE_MM
    assert not levels.same_level(0, levels.FACE_RISE_MM)
