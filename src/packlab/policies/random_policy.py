"""The random policy: uniform over placements whose top stays within the rim (the floor row)."""

from __future__ import annotations

import numpy as np

from packlab.core.feasibility import observation_candidates
from packlab.core.types import Action, Case, Observation
from packlab.policies.heuristics.select import rim_pool, to_action
from packlab.sim.buffer import episode_rng


class RandomPolicy:
    """Samples uniformly from the shared candidate search's rim pool.

    The pool is every in-rim candidate, or the lowest-top ones when none stays within the rim
    (the same rule the heuristics use), so the row measures placement skill, not rim luck.
    """

    name = "random"

    def __init__(self) -> None:
        self._rng = np.random.default_rng(0)

    def reset(self, case: Case, seed: int) -> None:
        # Offset the stream from the episode's shuffle RNG so the two are independent.
        self._rng = episode_rng(case.seed + 7919, seed)

    def act(self, observation: Observation) -> Action:
        cands = observation_candidates(observation)
        pool = rim_pool(cands)
        if pool.size == 0:  # nothing fits the floor at all: the object is set aside anyway
            return Action(0, 0, 0, 0)
        return to_action(cands, int(pool[self._rng.integers(pool.size)]))


def make_random() -> RandomPolicy:
    return RandomPolicy()
