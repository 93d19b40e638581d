"""The ``plan`` policy: perfect packings of small cases, bounds, determinism, what it reads."""

from __future__ import annotations

import pytest
from layered_cases import make_layered_case

from packlab.core.errors import ConfigError
from packlab.core.types import Action, Box, Case, Container
from packlab.policies import make_policy
from packlab.sim.episode import Episode, run_episode


def _case(sizes_mm, container_mm, buffer_size, episode_id="hand") -> Case:
    boxes = tuple(Box(internal_id=i, size_mm=s, gt_index=i) for i, s in enumerate(sizes_mm))
    return Case(episode_id, Container(container_mm), buffer_size, boxes, seed=0)


def test_two_boxes_that_fit_only_side_by_side_are_packed_perfectly():
    # 100 x 50 floor: a 75 x 50 box and a 25 x 50 box tile it; a 50 x 50 first placement at
    # the centre, or the large box rotated, would leave no room for the other.
    case = _case([(25, 50, 40), (75, 50, 40)], (100, 50, 60), buffer_size=2)
    result = run_episode(case, make_policy("plan"), backend="geometric")
    assert result.metrics.overall == pytest.approx(1.0)


def test_most_small_two_layer_layouts_are_packed_perfectly_where_sdf_pack_fails():
    cases = [
        make_layered_case(seed, cells=(8, 6), layer_heights_mm=(100, 60), buffer_size=4)
        for seed in range(8)
    ]

    def perfect(name: str) -> int:
        scores = [run_episode(c, make_policy(name), backend="geometric") for c in cases]
        return sum(r.metrics.overall == pytest.approx(1.0) for r in scores)

    assert perfect("plan") >= 6 and perfect("sdf") <= 2  # measured: 6 and 1


@pytest.mark.parametrize("seed", range(4))
def test_every_action_is_in_bounds_on_generated_layouts(seed):
    case = make_layered_case(seed, buffer_size=3, pieces=5)
    result = run_episode(case, make_policy("plan", first=2), backend="geometric")
    assert all(step.valid for step in result.steps)


def _actions_with_policy_seed(case: Case, policy_seed: int, **options) -> list[Action]:
    """One episode (run seed 0: the same buffer shuffles every time) whose policy is reset with
    ``policy_seed``: the seed is all that differs between two calls. Checks that the lookahead,
    not only the completion search, took some of the decisions."""
    episode = Episode("geometric")
    observation = episode.reset(case, 0)
    policy = make_policy("plan", **options)
    policy.reset(case, policy_seed)
    actions = []
    while not episode.done:
        actions.append(policy.act(observation))
        episode.step(actions[-1])
        if not episode.done:
            observation = episode.observe()
    assert policy.decisions - policy.completed >= 3
    return actions


@pytest.mark.parametrize("options", [{}, {"complete": False, "beam": 2}])
def test_the_seed_is_ignored_same_budget_same_actions(options):
    case = make_layered_case(0, buffer_size=2, pieces=6)  # the lookahead takes 9 of 12 steps
    runs = {s: _actions_with_policy_seed(case, s, **options) for s in (0, 1, 2, 987_654_321)}
    assert len(runs[0]) == len(case.objects)
    assert all(actions == runs[0] for actions in runs.values()), runs


class _Untouchable:
    """Stands in for the case at reset: any attribute read fails the test."""

    def __getattr__(self, name):
        raise AssertionError(f"the planner read case.{name}")


def test_the_planner_reads_only_its_observation():
    case = make_layered_case(3, buffer_size=3)
    honest = run_episode(case, make_policy("plan"), backend="geometric")
    policy = make_policy("plan")
    reset = policy.reset
    policy.reset = lambda _case, seed: reset(_Untouchable(), seed)  # the case never reaches it
    blind = run_episode(case, policy, backend="geometric")
    assert [s.action for s in blind.steps] == [s.action for s in honest.steps]


@pytest.mark.parametrize(
    "options, message",
    [
        ({"width": 3}, "unknown option 'width'"),
        ({"beam": 0}, "beam = 0"),
        ({"first": 0}, "first = 0"),
        ({"depth": 1.5}, "depth = 1.5"),
        ({"time_s": 0}, "time_s = 0"),
    ],
)
def test_bad_options_are_one_line_errors(options, message):
    with pytest.raises(ConfigError, match=message):
        make_policy("plan", **options)


def test_plan_fast_is_plan_at_the_fast_budget_and_options_override_it():
    fast = make_policy("plan-fast")
    assert fast.name == "plan-fast" and (fast.budget.first, fast.budget.depth) == (2, 4)
    assert make_policy("plan-fast", first=5).budget.first == 5


def test_beam_search_gives_valid_repeatable_actions():
    case = make_layered_case(3, cells=(8, 6), layer_heights_mm=(100, 60), buffer_size=4)
    runs = [run_episode(case, make_policy("plan", beam=2), backend="geometric") for _ in range(2)]
    assert all(s.valid for s in runs[0].steps)
    assert [s.action for s in runs[0].steps] == [s.action for s in runs[1].steps]
