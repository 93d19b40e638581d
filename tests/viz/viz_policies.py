"""A policy for the viewer tests: one invalid (set-aside) step among DBLF's placements."""

from __future__ import annotations

from packlab.core.types import Action, Case, Observation
from packlab.policies import make_policy


class OutOfBoundsAtStep1:
    """DBLF, except that step 1 places far outside the container (an invalid, set-aside step)."""

    name = "oob1"

    def reset(self, case: Case, seed: int) -> None:
        self._dblf = make_policy("dblf")
        self._dblf.reset(case, seed)

    def act(self, observation: Observation) -> Action:
        if observation.step_index == 1:
            return Action(0, 0, 999, 0)
        return self._dblf.act(observation)
