"""packlab.policies.windows.ring4 against scipy's dilation it replaces."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from packlab.policies.windows import ring4


def test_ring4_is_the_cross_dilation_less_the_mask():
    cross = ndimage.generate_binary_structure(2, 1)
    rng = np.random.default_rng(0)
    masks = [rng.random((9, 7)) < p for p in (0.05, 0.3, 0.7)]
    rect = np.zeros((9, 7), dtype=bool)
    rect[0:3, 4:7] = True  # touching two walls: the ring is clipped, never wrapped
    masks += [rect, np.ones((9, 7), dtype=bool), np.zeros((9, 7), dtype=bool)]
    for mask in masks:
        expected = ndimage.binary_dilation(mask, structure=cross) & ~mask
        assert np.array_equal(ring4(mask), expected)
    assert ring4(rect).sum() == 3 + 3  # below and beside it, no corner cell
