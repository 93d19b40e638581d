"""The planner's proposer: SDF-Pack's ranking starts with SDF-Pack's own choice, on many states."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.cases import load_cases
from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates, search_candidates
from packlab.core.types import ShownItem
from packlab.datagen.generator import generate_cases
from packlab.policies import make_policy
from packlab.policies.candidates import ProposerConfig, propose_from, proposed_indices
from packlab.policies.heuristics import sdf
from packlab.policies.heuristics.select import TIE_BREAKS, choose, rim_pool
from packlab.policies.listed import flat_index
from packlab.policies.plan.proposer import by_sdf, first_placements
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import Episode, policy_start


def _played_states(cases, seeds, policies=("random", "sdf")):
    """Every observation met while ``policies`` play ``cases`` on the geometric backend."""
    for case in cases:
        for seed in seeds:
            for name in policies:
                policy = make_policy(name)
                episode = Episode("geometric")
                observation = episode.reset(case, seed)
                policy.reset(policy_start(policy, case, seed), seed)
                while not episode.done:
                    yield observation
                    episode.step(policy.act(observation))
                    if not episode.done:
                        observation = episode.observe()


@pytest.fixture(scope="module")
def states():
    demo = load_cases(demo_cases_path())
    generated = generate_cases("easy", 3, seed=5, validate=False, domain="train")
    generated += generate_cases("medium", 2, seed=5, validate=False, domain="train")
    return list(_played_states(demo, range(4))) + list(_played_states(generated, range(2)))


def test_by_sdf_starts_with_sdf_packs_choice_on_generated_states(states) -> None:
    assert len(states) > 300
    checked = 0
    for observation in states:
        cands = observation_candidates(observation)
        pool = rim_pool(cands)
        if pool.size == 0:
            continue
        keys = sdf.score(cands)
        for tie in TIE_BREAKS:
            ranked = by_sdf(cands, pool, tie)
            assert sorted(ranked.tolist()) == pool.tolist()  # a permutation of the pool
            assert int(ranked[0]) == choose(cands, keys, tie)
        assert first_placements(cands, 2)[0] == choose(cands, keys)
        checked += 1
    assert checked > 300


def test_identical_boxes_tie_to_the_smaller_id_not_the_first_shown() -> None:
    # Two identical boxes: every key ties between them, so SDF-Pack's tie-break rule takes the
    # smaller internal_id (shown second here); the shown order must not decide.
    size_mm, size_cells = (50, 50, 40), (2, 2, 20)
    shown = [ShownItem(0, 7, size_mm, size_cells), ShownItem(1, 3, size_mm, size_cells)]
    cands = search_candidates(np.zeros((4, 4), dtype=np.int32), shown, 100, 25)
    pool = rim_pool(cands)
    best = choose(cands, sdf.score(cands))
    assert int(cands.obj[best]) == 1
    assert int(by_sdf(cands, pool)[0]) == best
    assert int(cands.obj[by_sdf(cands, pool, "shown_order")[0]]) == 0


def test_listed_proposals_follow_the_two_rankings_and_are_the_students_list(states) -> None:
    # Item 3 of the proposer: the students' listed placements are appended after the two
    # rankings (which stay first and unchanged), each once, and they are exactly what
    # ``propose_from`` lists for a student (one implementation of the list).
    grew = 0
    for observation in states[::5]:
        cands = observation_candidates(observation)
        base = first_placements(cands, 2)
        wide = first_placements(cands, 2, listed=4)
        listed = proposed_indices(cands, ProposerConfig(k=4))
        assert wide[: len(base)] == base
        assert len(set(wide)) == len(wide)
        assert set(wide) == set(base) | set(listed)
        students = propose_from(cands, ProposerConfig(k=4))
        assert [flat_index(cands, c) for c in students] == listed
        grew += len(wide) > len(base)
    assert grew > 20  # the list adds placements the two rankings did not propose


def test_plan_refuses_a_negative_listed_count() -> None:
    with pytest.raises(ConfigError, match="listed"):
        make_policy("plan", listed=-1)
    assert make_policy("plan", listed=0).budget.listed == 0
    assert make_policy("plan").budget.listed == 4
    assert make_policy("plan-fast").budget.listed == 2
    assert make_policy("plan-fast", listed=4).budget.listed == 4
