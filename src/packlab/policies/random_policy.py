"""The random policy: uniform over placements whose top stays within the rim (the floor row)."""

from __future__ import annotations

import numpy as np

from packlab.core.feasibility import observation_candidates
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Observation
from packlab.policies.heuristics.select import rim_pool, to_action

#: The policy's random stream (``EpisodeStart.rng``): apart from the episode's own shuffle.
RNG_STREAM = 7919


class RandomPolicy:
    """Samples uniformly from the shared candidate search's rim pool.

    The pool is every in-rim candidate, or the lowest-top ones when none stays within the rim
    (the same rule the heuristics use), so the row measures placement skill, not rim luck.
    """

    name = "random"

    def __init__(self) -> None:
        self._rng = np.random.default_rng(0)

    def reset(self, start: EpisodeStart, seed: int) -> None:
        self._rng = start.rng(RNG_STREAM)

    def act(self, observation: Observation) -> Action:
        cands = observation_candidates(observation)
        pool = rim_pool(cands)
        if pool.size == 0:  # nothing fits the floor at all: the object is set aside anyway
            return Action(0, 0, 0, 0)
        return to_action(cands, int(pool[self._rng.integers(pool.size)]))


def make_random() -> RandomPolicy:
    return RandomPolicy()
