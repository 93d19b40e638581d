"""The endplay: with every remaining box in view, other first actions played out by the planner."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Container, HistoryEntry, Observation, ShownItem
from packlab.datagen.config import CaseConfig
from packlab.datagen.generator import generate_cases
from packlab.policies import make_policy
from packlab.policies.plan.endplay import (
    Endplay,
    EndplayConfig,
    beam_firsts,
    played_value,
    step,
)
from packlab.sim.episode import run_episode

CONTAINER = Container((100, 100, 100))  # 4 x 4 cells of 25 mm, rim at 100 mm


def _item(index: int, size_mm: tuple[int, int, int]) -> ShownItem:
    cells = (size_mm[0] // 25, size_mm[1] // 25, size_mm[2] // CONTAINER.cell_z_mm)
    return ShownItem(index, 10 + index, size_mm, cells)


def _observation(heightmap, shown, remaining, history=()) -> Observation:
    return Observation(
        3, CONTAINER, np.asarray(heightmap, np.int32), tuple(shown), tuple(history), remaining
    )


def test_a_step_rests_the_box_on_the_heightmap_and_takes_it_from_the_buffer():
    hm = np.zeros((4, 4), np.int32)
    hm[0, 0] = 30
    obs = _observation(hm, [_item(0, (50, 50, 40)), _item(1, (25, 25, 20))], remaining=2)
    moved = step(obs, Action(0, 0, 0, 0))
    after = moved.observation
    assert moved.top == 70  # rests on the 30 mm cell under its footprint
    assert moved.packed == 50 * 50 * 40
    assert after.heightmap[:2, :2].tolist() == [[70, 70], [70, 70]]
    assert after.heightmap[2:, :].max() == 0
    assert [s.size_mm for s in after.shown] == [(25, 25, 20)]
    assert after.shown[0].shown_index == 0
    assert after.remaining == 1 and after.step_index == 4
    assert after.history[-1].action == Action(0, 0, 0, 0)


def test_a_set_aside_packs_nothing_and_leaves_the_heightmap():
    obs = _observation(np.zeros((4, 4)), [_item(0, (50, 50, 40)), _item(1, (25, 25, 20))], 2)
    moved = step(obs, Action.set_aside(1))
    assert (moved.packed, moved.top) == (0.0, 0)
    assert not moved.observation.heightmap.any()
    assert [s.size_mm for s in moved.observation.shown] == [(50, 50, 40)]


def test_a_box_sticking_out_over_the_rim_is_not_packed():
    hm = np.full((4, 4), 80, np.int32)
    obs = _observation(hm, [_item(0, (50, 50, 60)), _item(1, (25, 25, 20))], remaining=2)
    moved = step(obs, Action(0, 0, 0, 0))
    assert moved.top == 140 and moved.packed == 0.0  # centre at 110 mm, over the 100 mm rim


def test_played_value_scores_the_end_and_remembers_every_state_on_the_way():
    # Two boxes that together close the floor at 40 mm: placing one, then the other, ends at
    # V^2 / H = (100 x 100 x 40)^2 / 40.
    shown = [_item(0, (100, 50, 40)), _item(1, (100, 50, 40))]
    obs = _observation(np.zeros((4, 4)), shown, remaining=2)
    memo: dict = {}
    calls = []

    def player(o: Observation) -> Action:
        calls.append(o.step_index)
        return Action(0, 0, 0, 2)

    value = played_value(obs, Action(0, 0, 0, 0), player, memo)
    assert value == pytest.approx((100 * 100 * 40) ** 2 / 40)
    assert len(memo) == 1 and calls == [4]
    # The same first action again: its next state is remembered, the player is not asked.
    assert played_value(obs, Action(0, 0, 0, 0), player, memo) == value
    assert calls == [4]


def test_the_beam_proposes_the_placement_that_closes_the_floor_first():
    # A 100 x 50 box and a 50 x 50 one on an empty floor, both 40 mm: the beam's best play
    # packs both under a 40 mm top, whatever it sets aside never beats that.
    shown = [_item(0, (100, 50, 40)), _item(1, (50, 50, 40))]
    obs = _observation(np.zeros((4, 4)), shown, remaining=2)
    firsts = beam_firsts(obs, EndplayConfig())
    assert firsts and not firsts[0].sets_aside
    assert all(isinstance(a, Action) for a in firsts)


def test_the_rule_stays_out_unless_every_remaining_box_is_in_view():
    shown = [_item(0, (100, 50, 40)), _item(1, (50, 50, 40))]
    rule = Endplay()
    assert rule.applies(_observation(np.zeros((4, 4)), shown, remaining=2))
    assert not rule.applies(_observation(np.zeros((4, 4)), shown, remaining=3))
    assert not rule.applies(_observation(np.zeros((4, 4)), shown, remaining=None))
    assert not rule.applies(_observation(np.zeros((4, 4)), shown[:1], remaining=1))
    assert not Endplay(EndplayConfig(max_boxes=1)).applies(
        _observation(np.zeros((4, 4)), shown, remaining=2)
    )
    assert not Endplay(EndplayConfig(alternatives=0)).applies(
        _observation(np.zeros((4, 4)), shown, remaining=2)
    )
    past = HistoryEntry(np.zeros((4, 4), np.int32), tuple(shown), Action(0, 0, 0, 0), True)
    online = Observation(
        1, CONTAINER, np.zeros((4, 4), np.int32), tuple(shown), (past,), 2, must_place_first=True
    )
    assert not rule.applies(online)


@pytest.mark.parametrize(
    ("option", "value"),
    [("endplay", -1), ("endplay", 1.5), ("endplay_boxes", 0), ("endplay", True)],
)
def test_bad_options_name_the_option_and_value(option, value):
    with pytest.raises(ConfigError, match=f"{option.split('_')[-1]}.*{value!r}"):
        make_policy("plan", **{option: value})


def test_plan_plays_the_last_boxes_out_and_plan_fast_does_not_unless_asked():
    assert make_policy("plan").endplay.config == EndplayConfig()
    assert make_policy("plan", endplay=0).endplay.config.alternatives == 0
    assert make_policy("plan-fast").endplay.config.alternatives == 0
    assert make_policy("plan-fast", endplay=2).endplay.config.alternatives == 2


def test_on_the_geometric_backend_it_ends_higher_where_it_changes_a_decision():
    # A generated random-box case (test seed, not a suite) where the planner's own last plays
    # leave room: another first action, played on by the planner, ends higher (measured
    # 0.622 -> 0.662). On the geometric backend the model is exact, so it can never end lower.
    case = generate_cases(
        "medium", 3, 6102, False, config=CaseConfig(layout="random"), domain="train"
    )[2]
    before = run_episode(case, make_policy("plan", endplay=0), seed=0, backend="geometric")
    policy = make_policy("plan")
    after = run_episode(case, policy, seed=0, backend="geometric")
    assert policy.endplays >= 1
    assert after.metrics.overall > before.metrics.overall + 0.01


def test_a_play_that_reaches_the_bound_is_kept_without_searching(monkeypatch):
    # Two boxes that close the floor at 40 mm: the planner's play packs everything under the
    # lowest top there can be, so no other first action is tried (the beam is never asked).
    from packlab.policies.plan import endplay as module

    shown = [_item(0, (100, 50, 40)), _item(1, (100, 50, 40))]
    obs = _observation(np.zeros((4, 4)), shown, remaining=2)
    assert module.best_end_bound(obs) == pytest.approx((100 * 100 * 40) ** 2 / 40)

    def no_beam(*_args, **_kwargs):
        raise AssertionError("the beam was asked")

    monkeypatch.setattr(module, "beam_firsts", no_beam)
    planned = Action(0, 0, 0, 0)
    chosen = Endplay().decide(obs, planned, lambda: lambda _o: Action(0, 0, 0, 2))
    assert chosen == planned


def _lowest(observation: Observation) -> Action:
    """A base player: the first shown box at its lowest resting place (then lowest x, y)."""
    from packlab.core.feasibility import search_candidates

    cands = search_candidates(observation.heightmap, observation.shown[:1], 100, 25)
    i = int(np.lexsort((cands.y, cands.x, cands.z))[0])
    return Action(0, int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i]))


def test_a_better_first_action_replaces_the_planned_one():
    # The planner puts the 20 mm box in the middle of the floor, so the 40 mm one can only rest
    # on it (a 60 mm top); a first placement in a corner lets the same player put the other
    # box beside it, and the episode ends at 40 mm with the same volume.
    shown = [_item(0, (50, 50, 20)), _item(1, (50, 50, 40))]
    obs = _observation(np.zeros((4, 4)), shown, remaining=2)
    planned = Action(0, 0, 1, 1)
    chosen = Endplay().decide(obs, planned, lambda: _lowest)
    assert chosen != planned
    volume = 50 * 50 * 60
    assert played_value(obs, planned, _lowest, {}) == pytest.approx(volume**2 / 60)
    assert played_value(obs, chosen, _lowest, {}) == pytest.approx(volume**2 / 40)
