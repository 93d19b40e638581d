"""Closed-loop scores of an agent on cases (rl extra): the trainer's held-out evaluation."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from packlab.core.types import Case
from packlab.rl.agent import choose_row
from packlab.rl.envs import SET_ASIDE
from packlab.rl.features import FeatureSpec, encode
from packlab.sim.episode import Episode


def play(model: Any, spec: FeatureSpec, case: Case, seed: int = 0, backend: str = "geometric"):
    """One episode of ``case`` with the model's greedy choices; its EpisodeMetrics."""
    episode = Episode(backend)
    observation = episode.reset(case, seed)
    while not episode.done:
        encoded = encode(observation, spec)
        action = encoded.actions[choose_row(model, encoded)] if encoded.actions else SET_ASIDE
        episode.step(action)
        if not episode.done:
            observation = episode.observe()
    return episode.metrics()


def evaluate(model: Any, spec: FeatureSpec, cases: Sequence[Case]) -> dict[str, float]:
    """Mean Overall per level and ``avg`` (the mean of the level means), geometric, seed 0."""
    by_level: dict[str, list[float]] = defaultdict(list)
    for case in cases:
        by_level[case.difficulty].append(play(model, spec, case).overall)
    scores = {level: float(np.mean(v)) for level, v in sorted(by_level.items())}
    scores["avg"] = float(np.mean(list(scores.values())))
    return scores
