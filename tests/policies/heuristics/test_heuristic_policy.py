"""HeuristicPolicy: registration, the Policy protocol, whole episodes on the geometric backend."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.core.types import Action, Container, Observation, ShownItem
from packlab.policies import Policy, available_policies, make_policy
from packlab.policies.heuristics import SCORERS, HeuristicPolicy
from packlab.policies.heuristics.policy import NO_CANDIDATE_ACTION
from packlab.sim.episode import run_episode

NAMES = ("dblf", "hm", "mta", "ffp", "sdf")


def test_all_five_are_registered() -> None:
    assert set(NAMES) <= set(available_policies())
    assert set(SCORERS) == set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_policy_protocol_and_a_decision(name: str) -> None:
    policy = make_policy(name)
    assert isinstance(policy, HeuristicPolicy) and isinstance(policy, Policy)
    assert policy.name == name
    container = Container((100, 75, 100))  # 4 x 3 cells
    shown = (ShownItem(0, 7, (50, 25, 40), (2, 1, 20)), ShownItem(1, 8, (25, 25, 30), (1, 1, 15)))
    obs = Observation(0, container, np.zeros((4, 3), dtype=np.int32), shown)
    policy.reset(None, 0)  # type: ignore[arg-type]  (heuristics keep no state)
    action = policy.act(obs)
    assert isinstance(action, Action)
    assert action.object_id in (0, 1) and action.rotation in (0, 1)


@pytest.mark.parametrize("name", NAMES)
def test_nothing_fits_gives_the_documented_fallback(name: str) -> None:
    container = Container((50, 50, 100))
    shown = (ShownItem(0, 7, (75, 75, 40), (3, 3, 20)),)
    obs = Observation(0, container, np.zeros((2, 2), dtype=np.int32), shown)
    assert make_policy(name).act(obs) == NO_CANDIDATE_ACTION


@pytest.mark.parametrize("name", NAMES)
def test_a_whole_geometric_episode_places_every_object_validly(name: str, layered_case) -> None:
    result = run_episode(layered_case, make_policy(name), seed=0, backend="geometric")
    assert all(step.valid for step in result.steps)
    assert len(result.steps) == len(layered_case.objects)
    assert 0.0 < result.metrics.overall <= 1.0
