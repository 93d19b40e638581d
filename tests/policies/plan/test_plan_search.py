"""The lookahead's rollouts over one or several base policies."""

from __future__ import annotations

import pytest
from layered_cases import make_layered_case

from packlab.core.choices import RolloutBase, choices
from packlab.core.errors import ConfigError
from packlab.core.types import Observation
from packlab.policies import make_policy
from packlab.policies.plan.evaluate import Weights
from packlab.policies.plan.policy import observation_problem
from packlab.policies.plan.search import Budget, search
from packlab.sim.episode import Episode, run_episode


def _mid_episode_observations(steps: int = 8):
    """Observations of a layered case with a buffer of 4, the first ``steps`` decided by SDF-Pack
    (so the heightmaps are uneven, where the bases disagree)."""
    case = make_layered_case(0, cells=(12, 10), layer_heights_mm=(100, 75, 50), buffer_size=4)
    episode = Episode("geometric")
    observation = episode.reset(case, 0)
    sdf = make_policy("sdf")
    out = []
    for _ in range(steps):
        out.append(observation)
        episode.step(sdf.act(observation))
        observation = episode.observe()
    return out


def test_several_bases_cost_the_cheapest_of_each_base_alone():
    # A first placement costs the cheapest of its rollouts, and the decision takes the cheapest
    # first placement: so with several bases the decision's cost is the least of the decisions'
    # costs with each base alone (the minimum over placements and bases commutes).

    def cost(observation: Observation, rollout: RolloutBase) -> float:
        problem = observation_problem(observation, Weights())
        return search(observation.heightmap, problem, Budget(rollout=rollout)).cost

    cheaper = {"sdf": 0, "lowest": 0}
    for observation in _mid_episode_observations():
        alone = {base: cost(observation, base) for base in cheaper}
        assert cost(observation, "sdf+lowest") == pytest.approx(min(alone.values()))
        for base, other in (("sdf", "lowest"), ("lowest", "sdf")):
            cheaper[base] += alone[base] < alone[other]
    # Each base alone is the cheaper one somewhere on this case (measured: 4 and 2 of 8 states),
    # so a union that ignored either would fail above.
    assert cheaper["sdf"] > 0 and cheaper["lowest"] > 0, cheaper


@pytest.mark.parametrize("rollout", choices(RolloutBase))
def test_every_rollout_base_plays_valid_repeatable_episodes(rollout):
    case = make_layered_case(2, cells=(10, 8), layer_heights_mm=(100, 60), buffer_size=3)
    runs = [
        run_episode(case, make_policy("plan", rollout=rollout, complete=False), backend="geometric")
        for _ in range(2)
    ]
    assert all(step.valid for step in runs[0].steps)
    assert [s.action for s in runs[0].steps] == [s.action for s in runs[1].steps]


def test_an_unknown_rollout_base_is_a_one_line_error():
    with pytest.raises(ConfigError, match="rollout = 'greedy'"):
        make_policy("plan", rollout="greedy")
