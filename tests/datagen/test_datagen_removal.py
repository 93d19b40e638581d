"""Reverse removal yields supported placement orders that honour the anchor."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from packlab.datagen.config import CORNERS, AnchorConfig, CaseConfig
from packlab.datagen.generator import draw_blueprint
from packlab.datagen.layout import Layout, LayoutBox
from packlab.datagen.removal import FREE_ANCHOR, order_problems, resting_on, reverse_removal
from packlab.datagen.seeds import case_seed


@pytest.mark.parametrize("family", ["layered", "stepped"])
@pytest.mark.parametrize("difficulty", ["easy", "medium", "hard"])
def test_every_object_is_fully_supported_when_placed(difficulty, family):
    for slot in range(40):
        bp = draw_blueprint(
            case_seed(11, "train", difficulty, slot), difficulty, CaseConfig(layout=family)
        )
        assert order_problems(bp.layout, bp.order.order) == []
        # Independently: everything an object rests on comes earlier in the order.
        position = {box: i for i, box in enumerate(bp.order.order)}
        for j, supports in enumerate(resting_on(bp.layout.boxes)):
            assert all(position[i] < position[j] for i in supports)


def test_anchor_corner_is_placed_first():
    cfg = CaseConfig(anchor=AnchorConfig(corner_prob=1.0))
    for slot in range(60):
        bp = draw_blueprint(case_seed(2, "train", "medium", slot), "medium", cfg)
        first = bp.layout.boxes[bp.order.order[0]]
        hx, hy = CORNERS[bp.order.anchor]
        nx, ny = bp.layout.cells
        cx, cy = (nx - 1 if hx else 0), (ny - 1 if hy else 0)
        assert (
            first.z == 0
            and first.x <= cx < first.x + first.dx
            and first.y <= cy < first.y + first.dy
        )


def test_anchor_mix_follows_corner_prob():
    counts = Counter()
    for slot in range(400):
        bp = draw_blueprint(case_seed(4, "train", "easy", slot), "easy", CaseConfig())
        counts[bp.order.anchor] += 1
        assert bp.layout.boxes[bp.order.order[0]].z == 0
    corner_share = 1 - counts[FREE_ANCHOR] / 400
    assert 0.72 < corner_share < 0.88  # configured 0.8
    assert all(counts[c] > 40 for c in CORNERS)  # corners drawn uniformly


def test_order_is_randomised_but_deterministic():
    layout = Layout(
        (6, 6), 2, tuple(LayoutBox(x, y, 0, 3, 3, 2, 0) for x in (0, 3) for y in (0, 3)), "layered"
    )
    orders = {
        reverse_removal(layout, AnchorConfig(), np.random.default_rng(s)).order for s in range(30)
    }
    assert len(orders) > 5
    a = reverse_removal(layout, AnchorConfig(), np.random.default_rng(9))
    assert a == reverse_removal(layout, AnchorConfig(), np.random.default_rng(9))


def test_order_problems_catches_unsupported_orders():
    layout = Layout(
        (4, 4), 2, (LayoutBox(0, 0, 0, 4, 4, 1, 0), LayoutBox(0, 0, 1, 4, 4, 1, 1)), "layered"
    )
    assert order_problems(layout, (0, 1)) == []
    assert order_problems(layout, (1, 0))
