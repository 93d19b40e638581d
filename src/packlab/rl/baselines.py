"""``irbpp-random`` and ``tapnet-random``: a uniformly random row of each agent's action space.

The floor an agent must clear to have learned anything: the same listed placements (irbpp) or
the same object-then-DBLF placement (tapnet), chosen at random (seeded by the case and run
seed, so reruns repeat). Torch-free.
"""

from __future__ import annotations

import numpy as np

from packlab.core.choices import RLAgent
from packlab.core.errors import ConfigError
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Observation
from packlab.policies.candidates import STUDENT_K
from packlab.rl.envs import SET_ASIDE
from packlab.rl.features import FeatureSpec, encode

#: The policies' random stream (``EpisodeStart.rng``): apart from the episode's own shuffle.
RNG_OFFSET = 104_729


class RandomRowPolicy:
    """A uniformly random allowed row of an agent's action space."""

    def __init__(self, agent: RLAgent, k: int = STUDENT_K) -> None:
        self.spec = FeatureSpec.default(agent, k)
        self.name = f"{agent}-random"
        self._rng = np.random.default_rng(0)

    def reset(self, start: EpisodeStart, seed: int) -> None:
        self._rng = start.rng(RNG_OFFSET)

    def act(self, observation: Observation) -> Action:
        encoded = encode(observation, self.spec)
        if not encoded.actions:
            return SET_ASIDE
        return encoded.actions[int(self._rng.integers(len(encoded.actions)))]


def _make(agent: RLAgent, options: dict) -> RandomRowPolicy:
    unknown = sorted(set(options) - ({"k"} if agent == "irbpp" else set()))
    if unknown:
        raise ConfigError(f"policy-arg {agent}-random:{unknown[0]}: unknown option")
    return RandomRowPolicy(agent, int(options.get("k", STUDENT_K)))


def make_irbpp_random(**options) -> RandomRowPolicy:
    return _make("irbpp", options)


def make_tapnet_random(**options) -> RandomRowPolicy:
    return _make("tapnet", options)
