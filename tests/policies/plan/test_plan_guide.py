"""``plan``'s ``guide``: a trained agent's preferred placements rolled out by the lookahead."""

from __future__ import annotations

import pytest

from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Action
from packlab.datagen import generate_cases
from packlab.datagen.config import CaseConfig
from packlab.policies import make_policy
from packlab.policies.overflow import overflow_decision
from packlab.policies.plan import policy as plan_policy
from packlab.policies.plan.guide import AgentGuide
from packlab.sim.episode import Episode


@pytest.fixture(scope="module")
def observations():
    """Observations along the proposer's episode on a case of independently drawn boxes (no
    tiling exists, so the lookahead decides)."""
    case = generate_cases("medium", 1, 11, False, config=CaseConfig(layout="random"))[0]
    episode, proposer = Episode("geometric"), make_policy("proposer")
    observation = episode.reset(case, 0)
    proposer.reset(case, 0)
    out = []
    while not episode.done and len(out) < 12:
        out.append(observation)
        episode.step(proposer.act(observation))
        if not episode.done:
            observation = episode.observe()
    return out


def _action(cands, i: int) -> Action:
    return Action(int(cands.obj[i]), int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i]))


def test_the_guides_first_placement_is_the_agents_own_action(observations):
    guide, agent = AgentGuide("irbpp", first=3), make_policy("irbpp")
    checked = 0
    for observation in observations:
        cands = observation_candidates(observation)
        if overflow_decision(observation, cands, "score") is not None:
            continue  # there the agent's rule decides, not its network
        placements = guide.placements(observation, cands)
        assert 1 <= len(placements) <= 3 and len(set(placements)) == len(placements)
        assert _action(cands, placements[0]) == agent.act(observation)
        checked += 1
    assert checked >= 5


def test_the_lookahead_rolls_out_the_guides_placements_besides_its_own(observations, monkeypatch):
    seen: list[list[int] | None] = []
    search = plan_policy.search

    def spy(heightmap, problem, budget, check_support=False, firsts=None, candidates=None):
        seen.append(None if firsts is None else list(firsts))
        return search(heightmap, problem, budget, check_support, firsts, candidates)

    monkeypatch.setattr(plan_policy, "search", spy)
    # The endplay off: its simulated plays search too, and this spy reads the last search.
    plain = make_policy("plan", endplay=0)
    guided = make_policy("plan", guide="irbpp", guide_first=2, endplay=0)
    for observation in observations:
        plain.decide(observation)
        mark = len(seen)
        guided.decide(observation)
        if len(seen) == mark:
            continue  # decided before the lookahead (overflow rule)
        cands = observation_candidates(observation)
        own = plan_policy.first_placements(cands, plain.budget.first, plain.budget.listed)
        agent = guided.guide.placements(observation, cands)
        assert seen[-1] == own + [i for i in agent if i not in own]
        assert seen[-2] is None  # without a guide the search proposes its own
    assert any(s is not None for s in seen)


@pytest.mark.parametrize(
    "options, message",
    [
        ({"guide": "sdf"}, "guide = 'sdf'"),
        ({"guide": "irbpp", "guide_first": -1}, "guide_first = -1"),
        ({"guide_model": "runs/x"}, "needs guide"),
    ],
)
def test_bad_guide_options_are_one_line_errors(options, message):
    with pytest.raises(ConfigError, match=message):
        make_policy("plan", **options)


def test_guide_first_zero_or_none_asks_no_agent():
    assert not AgentGuide("irbpp", first=0).active and not AgentGuide().active
    assert AgentGuide().placements(None, None) == []  # type: ignore[arg-type]
