"""Closed-loop scores of an agent on cases (rl extra): the trainer's held-out evaluation."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Case, Observation
from packlab.metrics import EpisodeMetrics
from packlab.rl.agent import greedy_action
from packlab.rl.features import FeatureSpec
from packlab.sim.episode import run_episode


class GreedyAgent:
    """An in-memory model as a Policy (the bench's ``irbpp`` / ``tapnet`` load theirs)."""

    def __init__(self, model: Any, spec: FeatureSpec, name: str = "agent") -> None:
        self.model, self.spec, self.name = model, spec, name

    def reset(self, start: EpisodeStart, seed: int) -> None:
        """Nothing to prepare: the agent keeps no state between steps."""

    def act(self, observation: Observation) -> Action:
        return greedy_action(self.model, self.spec, observation)


def play(
    model: Any, spec: FeatureSpec, case: Case, seed: int = 0, backend: str = "geometric"
) -> EpisodeMetrics:
    """One episode of ``case`` with the model's greedy choices; its EpisodeMetrics."""
    return run_episode(case, GreedyAgent(model, spec), seed, backend).metrics


def evaluate(model: Any, spec: FeatureSpec, cases: Sequence[Case]) -> dict[str, float]:
    """Mean Overall per level and ``avg`` (the mean of the level means), geometric, seed 0."""
    by_level: dict[str, list[float]] = defaultdict(list)
    for case in cases:
        by_level[case.difficulty].append(play(model, spec, case).overall)
    scores = {level: float(np.mean(v)) for level, v in sorted(by_level.items())}
    scores["avg"] = float(np.mean(list(scores.values())))
    return scores
