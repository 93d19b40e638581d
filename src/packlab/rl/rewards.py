"""Step rewards of the RL action-space envs, chosen by :data:`~packlab.core.choices.RLReward`.

The bench ranks by Overall = Success Ratio x Compactness, so the default reward is built to sum
to it. Let Phi(s) be the Overall the episode would score if it ended in state s: the inside
volume's share of the case's volume times that volume over (X * Y * current max height).
Phi is 0 before the first placement and equals the final Overall once every object is
processed, so paying ``Phi(s') - Phi(s)`` per step (potential-based shaping, Ng et al. 1999)
gives an undiscounted return that telescopes to exactly the final Overall while every step is
told at once what its placement did to the score: a box that raises the peak without filling
costs compactness now, a box pushed out costs its volume now.

- ``overall`` (default, trains the shipped agents): the potential difference above.
- ``overall-terminal``: 0 on every step but the last, which pays the final Overall.
- ``success``: the change in packed-volume fraction (``packlab/Pack-v0``'s reward).
"""

from __future__ import annotations

import numpy as np

from packlab.core.choices import RLReward, require_choice
from packlab.core.types import Case
from packlab.metrics import compactness, success_ratio
from packlab.sim.env import InsideVolume


class StepReward:
    """The reward of each step of one episode (reset per case, updated after each step)."""

    def __init__(self, kind: RLReward = "overall") -> None:
        require_choice(kind, RLReward, "reward")
        self.kind = kind
        self._inside = InsideVolume()

    def reset(self, case: Case) -> None:
        self._case = case
        self._inside.reset(case)
        self._potential = 0.0

    def overall_so_far(self, heightmap: np.ndarray) -> float:
        """Phi: the Overall of the current state, judged as if the episode ended now."""
        volume = self._inside.volume
        sr = success_ratio(volume, self._case.total_volume_mm3)
        peak = int(heightmap.max()) if heightmap.size else 0
        return sr * compactness(volume, self._case.container, peak)

    def update(self, positions_mm: np.ndarray, heightmap: np.ndarray, done: bool) -> float:
        """The reward of a step whose settled centres are ``positions_mm`` ((n, 3) float mm,
        NaN rows for boxes not in the container) and whose heightmap is ``heightmap``."""
        fraction_gain = self._inside.update(positions_mm)
        if self.kind == "success":
            return fraction_gain
        potential = self.overall_so_far(heightmap)
        if self.kind == "overall-terminal":
            return potential if done else 0.0
        reward, self._potential = potential - self._potential, potential
        return reward
