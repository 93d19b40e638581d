"""The lookahead's outlook: the episode's volumes and the final-height shortfall."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.types import Action, Container, HistoryEntry, Observation, ShownItem
from packlab.policies.plan.evaluate import PathLoss, Weights, state_cost
from packlab.policies.plan.outlook import Outlook, final_shortfall, observation_outlook
from packlab.policies.plan.surface import water_level

CONTAINER = Container((100, 100, 200))  # 4 x 4 cells of 25 mm, lid at 200 mm


def _item(index: int, size_mm: tuple[int, int, int]) -> ShownItem:
    cells = (size_mm[0] // 25, size_mm[1] // 25, size_mm[2] // CONTAINER.cell_z_mm)
    return ShownItem(index, index, size_mm, cells)


def _observation(shown, history=(), remaining: int | None = 5) -> Observation:
    return Observation(
        0, CONTAINER, np.zeros((4, 4), np.int32), tuple(shown), tuple(history), remaining
    )


def test_water_level_fills_the_lowest_cells_first():
    hm = np.array([[0, 10], [20, 30]])
    assert water_level(hm, 0) == 0
    assert water_level(hm, 10) == pytest.approx(10)  # the lowest cell up to its neighbour
    assert water_level(hm, 20) == pytest.approx(15)  # two cells share the next 10
    assert water_level(hm, 60) == pytest.approx(30)  # everything level with the top
    assert water_level(hm, 100) == pytest.approx(40)


def test_a_tower_falls_shorter_than_a_level_top_with_the_same_volume():
    # The same 800 cell-mm placed, 400 still to come, 1200 in all, on 16 cells under a 200 lid.
    outlook = Outlook(placed=800, to_come=400, total=1200, lid_mm=200)
    level = np.full((4, 4), 50)
    tower = np.zeros((4, 4), np.int64)
    tower[:2, :2] = 200  # four cells up to the lid
    # Level: the 400 to come raise it to 75, nothing open: a perfect packing's shortfall, 0.
    assert final_shortfall(level, outlook) == pytest.approx(16 * 75 - 1200**2 / 1200)
    assert final_shortfall(level, outlook) == pytest.approx(0)
    # Tower: the top stays at 200 whatever comes; 16 x 200 - 1200 open at the end.
    assert final_shortfall(tower, outlook) == pytest.approx(16 * 200 - 1200)
    # Without an outlook the lookahead's cost cannot tell them apart by final height; with one
    # it charges the tower its shortfall (weight ``final``, the other terms unchanged).
    weights = Weights()
    no_final = Weights(final=0.0)
    for hm in (level, tower):
        with_outlook = state_cost(hm, PathLoss(), (), weights, outlook)
        without = state_cost(hm, PathLoss(), (), no_final, outlook)
        assert with_outlook - without == pytest.approx(final_shortfall(hm, outlook))
    assert state_cost(tower, PathLoss(), (), weights, None) == state_cost(
        tower, PathLoss(), (), no_final, outlook
    )


def test_a_box_that_does_not_fit_costs_more_than_its_volume():
    # Everything placed; 100 cell-mm more in the whole than inside: the box set aside.
    hm = np.full((4, 4), 50)
    kept = Outlook(placed=800, to_come=0, total=800, lid_mm=200)
    lost = Outlook(placed=800, to_come=0, total=900, lid_mm=200)
    assert final_shortfall(hm, lost) - final_shortfall(hm, kept) > 0
    # Still to come but more than fits under the lid: only what fits counts inside.
    over = Outlook(placed=800, to_come=10_000, total=10_800, lid_mm=200)
    assert final_shortfall(hm, over) == pytest.approx(16 * 200 - 3200**2 / 10_800)


def test_the_observation_outlook_reads_history_shown_and_remaining():
    floor = _item(0, (100, 100, 50))  # 16 cells x 50 mm = 800 cell-mm, placed
    aside = _item(0, (50, 50, 25))  # 4 x 25 = 100, set aside
    history = (
        HistoryEntry(np.zeros((4, 4), np.int32), (floor,), Action(0, 0, 0, 0), True),
        HistoryEntry(np.full((4, 4), 50, np.int32), (aside,), Action.set_aside(0), False),
    )
    shown = [_item(0, (50, 50, 50)), _item(1, (50, 50, 50))]  # 200 cell-mm each
    outlook = observation_outlook(_observation(shown, history, remaining=5))
    assert outlook is not None
    assert outlook.placed == 800
    # 3 boxes not yet shown, each at the mean of the four seen (800 + 100 + 200 + 200) / 4.
    assert outlook.to_come == 3 * 325
    assert outlook.total == 1300 + 3 * 325
    assert outlook.lid_mm == 200


def test_no_outlook_when_remaining_is_hidden_or_the_order_overfills_the_container():
    shown = [_item(0, (50, 50, 50))]
    assert observation_outlook(_observation(shown, remaining=None)) is None
    # 16 cells x 200 mm hold 3200 cell-mm; 20 boxes of 200 would need 4000: it ends full.
    assert observation_outlook(_observation(shown, remaining=20)) is None
    assert observation_outlook(_observation(shown, remaining=10)) is not None
