"""The overflow rule: what a policy does when no shown box fits under the rim."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Action, Box, Case, Container, HistoryEntry, Observation, ShownItem
from packlab.policies import make_policy
from packlab.policies.overflow import (
    last_box_raises_top,
    overflow_action,
    overflow_decision,
    overflowing,
    packed_inside_volume,
)
from packlab.sim.episode import run_episode

CONTAINER = Container((100, 100, 100))  # 4 x 4 cells of 25 mm, rim at 100 mm


def _case(sizes_mm, buffer_size=1, container=CONTAINER) -> Case:
    boxes = tuple(Box(internal_id=i, size_mm=s, gt_index=i) for i, s in enumerate(sizes_mm))
    return Case("overflow", container, buffer_size, boxes, seed=0)


def _item(index: int, size_mm: tuple[int, int, int]) -> ShownItem:
    cells = (size_mm[0] // 25, size_mm[1] // 25, size_mm[2] // CONTAINER.cell_z_mm)
    return ShownItem(index, index, size_mm, cells)


def _observation(heightmap, shown, history=(), remaining=1) -> Observation:
    return Observation(
        0,
        CONTAINER,
        np.asarray(heightmap, dtype=np.int32),
        tuple(shown),
        tuple(history),
        remaining,
    )


def _full_floor_history(height_mm: int) -> HistoryEntry:
    """One past step that put a box of the whole floor and ``height_mm`` on the empty floor."""
    floor = _item(0, (100, 100, height_mm))
    return HistoryEntry(np.zeros((4, 4), np.int32), (floor,), Action(0, 0, 0, 0), True)


def test_a_box_whose_centre_would_leave_the_container_is_set_aside():
    # Floor at 90 mm, a 50 mm box: its centre would be at 115 mm, above the rim. Placing it
    # adds nothing packed and raises the highest cell to 140 mm.
    obs = _observation(np.full((4, 4), 90), [_item(0, (100, 100, 50))], [_full_floor_history(90)])
    cands = observation_candidates(obs)
    assert overflowing(cands)
    assert overflow_action(obs, cands) == Action.set_aside(0)


def test_a_large_box_that_sticks_out_a_little_is_placed():
    # Floor at 60 mm and a 100 x 100 x 60 box: top 120 mm, centre 90 mm (inside). V goes from
    # 60 to 120 mm x floor area while H goes from 60 to 120 mm: (2V)^2 / 2H > V^2 / H.
    obs = _observation(np.full((4, 4), 60), [_item(0, (100, 100, 60))], [_full_floor_history(60)])
    cands = observation_candidates(obs)
    assert overflowing(cands)
    assert overflow_action(obs, cands) == Action(0, 0, 0, 0)


def test_a_small_box_that_raises_the_top_a_lot_is_set_aside():
    # Floor at 90 mm, a 25 x 25 x 20 box: centre 100 mm (inside, just), top 110 mm. It adds
    # 1/16 of a layer of 20 mm to 90 mm of packed boxes but raises H by 20 mm: not worth it.
    obs = _observation(np.full((4, 4), 90), [_item(0, (25, 25, 20))], [_full_floor_history(90)])
    cands = observation_candidates(obs)
    assert overflow_action(obs, cands) == Action.set_aside(0)


def test_the_box_set_aside_is_the_one_that_would_stick_out_most():
    shown = [_item(0, (25, 25, 20)), _item(1, (25, 25, 80))]
    obs = _observation(np.full((4, 4), 90), shown, [_full_floor_history(90)])
    assert overflow_action(obs, observation_candidates(obs)) == Action.set_aside(1)


def test_not_overflowing_while_some_box_fits_under_the_rim():
    hm = np.full((4, 4), 90)
    hm[0, 0] = 0
    obs = _observation(hm, [_item(0, (25, 25, 20))])
    assert not overflowing(observation_candidates(obs))


def test_packed_volume_counts_only_boxes_whose_centre_stayed_inside():
    inside = _full_floor_history(90)
    # A 25 x 25 x 40 box dropped on the 90 mm floor: centre at 110 mm, outside.
    outside = HistoryEntry(
        np.full((4, 4), 90, np.int32), (_item(0, (25, 25, 40)),), Action(0, 0, 1, 1), True
    )
    invalid = HistoryEntry(
        np.full((4, 4), 130, np.int32), (_item(0, (25, 25, 40)),), Action(0, 0, 9, 9), False
    )
    obs = _observation(np.full((4, 4), 130), [], [inside, outside, invalid])
    assert packed_inside_volume(obs) == 100 * 100 * 90


def test_set_aside_steps_are_recorded_as_such_and_count_as_unpacked():
    case = _case([(100, 100, 90), (100, 100, 50)])
    result = run_episode(case, make_policy("plan-fast"), backend="geometric")
    assert [s.reason for s in result.steps] == ["", "set_aside"]
    assert result.metrics.invalid_by_reason == {"set_aside": 1}
    assert result.metrics.n_set_aside == 1


@pytest.mark.parametrize("policy", ["plan-fast", "sdf", "irbpp", "tapnet", "proposer", "vlm"])
def test_the_score_rule_beats_placing_the_box_that_sticks_out_least(policy):
    # The second box cannot stay under the rim; placed on top, its centre is outside (it adds
    # nothing) and the highest cell rises from 90 to 140 mm.
    case = _case([(100, 100, 90), (100, 100, 50)])
    placed = run_episode(case, make_policy(policy, overflow="place"), backend="geometric")
    scored = run_episode(case, make_policy(policy, overflow="score"), backend="geometric")
    assert placed.metrics.max_height_mm == 140 and scored.metrics.max_height_mm == 90
    assert scored.metrics.overall == pytest.approx(90 / 140)
    assert placed.metrics.overall == pytest.approx((90 / 140) ** 2)


@pytest.mark.parametrize("policy", ["plan", "plan-fast", "irbpp", "tapnet", "proposer", "vlm"])
def test_the_projects_own_policies_score_by_default(policy):
    assert make_policy(policy).overflow == "score"


@pytest.mark.parametrize("policy", ["dblf", "hm", "mta", "ffp", "sdf"])
def test_the_literature_heuristics_place_by_default(policy):
    assert make_policy(policy).overflow == "place"


@pytest.mark.parametrize("policy", ["plan", "dblf", "irbpp", "proposer", "vlm"])
def test_an_unknown_overflow_rule_is_refused_by_name(policy):
    with pytest.raises(ConfigError, match="overflow = 'later'"):
        make_policy(policy, overflow="later")


def test_online_the_arriving_box_is_placed_not_set_aside():
    from packlab.core.packing_protocol import PackingProtocol

    case = _case([(100, 100, 60), (100, 100, 60)])
    result = run_episode(
        case,
        make_policy("plan-fast"),
        backend="geometric",
        protocol=PackingProtocol("online", 1),
    )
    assert all(s.reason != "set_aside" for s in result.steps)


def test_a_data_engine_teacher_places_rather_than_sets_aside():
    # A dataset's actions are placements: the planner teaches the rim rule they can hold.
    from packlab.datagen.validate import replay

    trajectory = replay(
        _case([(100, 100, 90), (100, 100, 50)]), backend="geometric", teacher="plan"
    )
    assert trajectory.reasons == ("", "")


def _three_quarter_floor_history(height_mm: int) -> HistoryEntry:
    """One past step that put a 100 x 75 mm box of ``height_mm`` on the empty floor."""
    box = _item(0, (100, 75, height_mm))
    return HistoryEntry(np.zeros((4, 4), np.int32), (box,), Action(0, 0, 0, 0), True)


def _layer_with_a_gap(gap_cells: int) -> np.ndarray:
    """A closed layer at 40 mm but the last ``gap_cells`` rows of y (a gap 25 mm deep each)."""
    hm = np.full((4, 4), 40, np.int32)
    hm[:, 4 - gap_cells :] = 0
    return hm


def test_the_last_box_is_set_aside_rather_than_stacked_on_its_layer():
    # The layer is 3/4 closed at 40 mm; the last box (50 x 50 mm, a quarter of the floor)
    # does not fit the 25 mm gap. Stacked, it doubles the highest cell for a third more
    # volume: (4/3)^2 / 2 < 1. It is set aside.
    hm = _layer_with_a_gap(1)
    obs = _observation(hm, [_item(0, (50, 50, 40))], [_three_quarter_floor_history(40)])
    cands = observation_candidates(obs)
    assert not overflowing(cands)  # it fits under the rim, on top of the layer
    assert last_box_raises_top(obs, cands)
    assert overflow_decision(obs, cands, "score") == Action.set_aside(0)
    assert overflow_decision(obs, cands, "place") is None


def test_a_last_box_that_fits_the_gap_is_left_to_the_policy():
    hm = _layer_with_a_gap(1)
    obs = _observation(hm, [_item(0, (100, 25, 40))], [_three_quarter_floor_history(40)])
    cands = observation_candidates(obs)
    assert not last_box_raises_top(obs, cands)
    assert overflow_decision(obs, cands, "score") is None


def test_the_rule_is_exact_only_for_the_last_box_and_needs_the_count():
    hm = _layer_with_a_gap(1)
    history = [_three_quarter_floor_history(40)]
    shown = [_item(0, (50, 50, 40))]
    for remaining in (2, None):  # more boxes may fill under a raised top; or nothing is known
        obs = _observation(hm, shown, history, remaining=remaining)
        cands = observation_candidates(obs)
        assert not last_box_raises_top(obs, cands)
        assert overflow_decision(obs, cands, "score") is None


def test_a_large_last_box_that_raises_the_top_a_little_is_placed():
    # A closed layer at 40 mm and a last box of the whole floor, 20 mm: V x 1.5 for H x 1.5.
    hm = np.full((4, 4), 40, np.int32)
    floor = HistoryEntry(
        np.zeros((4, 4), np.int32), (_item(0, (100, 100, 40)),), Action(0, 0, 0, 0), True
    )
    obs = _observation(hm, [_item(0, (100, 100, 20))], [floor])
    cands = observation_candidates(obs)
    assert last_box_raises_top(obs, cands)
    assert overflow_decision(obs, cands, "score") == Action(0, 0, 0, 0)


@pytest.mark.parametrize("policy", ["plan", "plan-fast", "irbpp", "tapnet", "proposer", "vlm"])
def test_the_last_box_of_a_layer_that_does_not_fit_is_set_aside_in_play(policy):
    # 100 x 75 x 40 fills 3/4 of the floor; the last box, 50 x 50 x 40, fits only on top.
    case = _case([(100, 75, 40), (50, 50, 40)])
    scored = run_episode(case, make_policy(policy), backend="geometric")
    placed = run_episode(case, make_policy(policy, overflow="place"), backend="geometric")
    assert placed.metrics.max_height_mm == 80 and scored.metrics.max_height_mm == 40
    assert [s.reason for s in scored.steps] == ["", "set_aside"]
    assert scored.metrics.overall > placed.metrics.overall
