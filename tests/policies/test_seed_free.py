"""Every policy that claims to be free of the run seed plays the same episode for every seed.

A claim (``packlab.policies.registry.seed_free_modes``) lets the bench play one seed and copy
the episode to the others (``packlab.bench.reuse``). The check is the strongest one available:
two seeds are played on generated cases, and the copy the bench would write for the second
seed must equal the record its own play wrote, times aside (``reuse.timeless``). A policy that
claims too much fails it: the seed-reading and order-reading fakes below show that it does.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from test_registry_plugin import PLUGIN_POLICY, installed_plugin  # noqa: F401 (a fixture)

from packlab.bench.reuse import copyable, reused_record, timeless
from packlab.bench.task import run_task
from packlab.core.feasibility import observation_candidates
from packlab.core.packing_protocol import PackingProtocol
from packlab.core.records import EpisodeOk
from packlab.core.types import Action, Case, Observation
from packlab.datagen.generator import generate_cases
from packlab.policies.registry import (
    SeedFreeMode,
    available_policies,
    declare_seed_free,
    register_policy,
    seed_free_always,
    seed_free_modes,
    unregister_policy,
)
from packlab.sim.modes import EXACT_MODES, EpisodeModes

#: The two run seeds compared (the bench plays the lowest and copies it).
SEEDS = (0, 7)
#: The online protocol's window in the "arrival" checks: several boxes, so order matters.
LOOKAHEAD = 3


@cache
def cases() -> tuple[Case, ...]:
    """Two generated cases per difficulty (no validation replay: only the plan checks)."""
    return tuple(c for d in ("easy", "medium", "hard") for c in generate_cases(d, 2, 5, False))


def modes_of(mode: SeedFreeMode) -> EpisodeModes:
    """The exact modes with the protocol a seed-free mode stands for."""
    if mode == "arrival":
        return EpisodeModes(protocol=PackingProtocol("online", LOOKAHEAD))
    return EXACT_MODES


def seed_mismatches(
    policy: str,
    mode: SeedFreeMode,
    backend: str = "geometric",
    options: dict | None = None,
    chosen: tuple[Case, ...] | None = None,
) -> list[str]:
    """The cases on which the bench's copy of the first seed's episode differs from what
    playing the second seed records; each named with the first field that differs."""
    found = []
    for case in cases() if chosen is None else chosen:
        lead, other = (
            run_task(case, policy, seed, backend, policy_kwargs=options, modes=modes_of(mode))
            for seed in SEEDS
        )
        assert isinstance(lead, EpisodeOk), getattr(lead, "traceback", lead)
        assert isinstance(other, EpisodeOk), getattr(other, "traceback", other)
        if not copyable(lead, mode):
            found.append(f"{case.episode_id}: the lead drew a box from the seed")
            continue
        copy, played = timeless(reused_record(lead, case, SEEDS[1], mode)), timeless(other)
        if copy != played:
            first = next(k for k in played if copy.get(k) != played[k])
            found.append(f"{case.episode_id}: {first}")
    return found


def claims() -> list[tuple[str, SeedFreeMode]]:
    """Every (policy, mode) a registered policy claims with its default options."""
    return [(p, m) for p in available_policies() for m in sorted(seed_free_modes(p))]


#: Heuristic options that change the claim: only arrival order is left to them.
ORDER_READING_OPTIONS = (
    ("dblf", {"tie_break": "shown_order"}),
    ("sdf", {"overflow": "score"}),
)


def test_the_claims_are_the_documented_ones():
    claimed = {p: seed_free_modes(p) for p in available_policies()}
    both = {"shuffled", "arrival"}
    for name in ("dblf", "hm", "mta", "ffp", "sdf", "oracle"):
        assert claimed[name] == both, name
    for name in ("plan", "plan-fast", "plan-lookahead"):
        assert claimed[name] == {"arrival"}, name
    for name in ("random", "irbpp-random", "tapnet-random", "vlm", "endpoint"):
        assert claimed[name] == frozenset(), name
    for name, options in ORDER_READING_OPTIONS:
        assert seed_free_modes(name, options) == {"arrival"}
    assert seed_free_modes("plan-fast", {"time_s": 0.5}) == frozenset()


#: Policies whose default budgets take seconds an episode: checked on one case per difficulty.
SLOW = frozenset({"plan", "plan-lookahead"})


@pytest.mark.parametrize(("policy", "mode"), claims())
def test_a_claimed_policy_plays_the_same_episode_for_every_seed(policy, mode):
    chosen = cases()[::2] if policy in SLOW else None
    assert seed_mismatches(policy, mode, chosen=chosen) == []


@pytest.mark.parametrize(("policy", "options"), ORDER_READING_OPTIONS)
def test_order_reading_options_keep_their_arrival_claim(policy, options):
    assert seed_mismatches(policy, "arrival", options=options) == []


@pytest.mark.physics
@pytest.mark.parametrize("policy", ["dblf", "oracle"])
def test_claims_hold_on_the_mujoco_backend(policy):
    easy = tuple(c for c in cases() if c.difficulty == "easy")
    assert seed_mismatches(policy, "shuffled", "mujoco", chosen=easy) == []


def test_the_copy_shows_each_seed_its_own_order():
    """Not a vacuous check: the copies differ from the lead where the seeds' shuffles do."""
    case = next(c for c in cases() if c.difficulty == "medium")
    lead = run_task(case, "dblf", SEEDS[0], "geometric")
    assert isinstance(lead, EpisodeOk)
    copy = reused_record(lead, case, SEEDS[1], "shuffled")
    assert [s.shown for s in copy.steps] != [s.shown for s in lead.steps]
    assert [s.internal_id for s in copy.steps] == [s.internal_id for s in lead.steps]
    assert copy.seed == SEEDS[1] and copy.reused_from_seed == SEEDS[0]


# -- the check catches a policy that claims too much ---------------------------------------

SEED_READER, ORDER_READER = "test-seed-reader", "test-order-reader"


class SeedReader:
    """Claims seed freedom but settles ties with a generator seeded by the run seed."""

    name = SEED_READER

    def reset(self, case: Case, seed: int) -> None:
        self._rng = np.random.default_rng(seed)

    def act(self, observation: Observation) -> Action:
        cands = observation_candidates(observation)
        if len(cands) == 0:
            return Action(0, 0, 0, 0)
        i = int(self._rng.integers(len(cands)))
        return Action(int(cands.obj[i]), int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i]))


class OrderReader:
    """Never reads the seed but places the first shown box: it follows the shuffle."""

    name = ORDER_READER

    def reset(self, case: Case, seed: int) -> None:
        pass

    def act(self, observation: Observation) -> Action:
        first = np.flatnonzero(observation_candidates(observation).obj == 0)
        if first.size == 0:  # it fits nowhere: out of bounds, set aside
            return Action(0, 0, 0, 0)
        cands, i = observation_candidates(observation), int(first[0])
        return Action(0, int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i]))


@pytest.fixture
def false_claims():
    """Both fakes registered for one test, each claiming every mode."""
    register_policy(SEED_READER)(declare_seed_free(seed_free_always)(lambda: SeedReader()))
    register_policy(ORDER_READER)(declare_seed_free(seed_free_always)(lambda: OrderReader()))
    try:
        yield
    finally:
        unregister_policy(SEED_READER)
        unregister_policy(ORDER_READER)


def test_the_check_catches_a_policy_that_reads_the_seed(false_claims):
    assert seed_free_modes(SEED_READER) == {"shuffled", "arrival"}
    assert seed_mismatches(SEED_READER, "shuffled")
    assert seed_mismatches(SEED_READER, "arrival")


def test_the_check_catches_a_policy_that_reads_the_shown_order(false_claims):
    assert seed_mismatches(ORDER_READER, "shuffled")
    # In arrival order nothing is shuffled: there it is seed-free indeed.
    assert seed_mismatches(ORDER_READER, "arrival") == []


def test_a_policy_that_states_nothing_depends_on_the_seed(installed_plugin):  # noqa: F811
    register_policy("test-silent")(lambda: SeedReader())
    try:
        assert seed_free_modes("test-silent") == frozenset()
    finally:
        unregister_policy("test-silent")
    assert seed_free_modes(PLUGIN_POLICY) == frozenset()
