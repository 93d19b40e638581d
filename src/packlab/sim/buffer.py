"""The visible window over the arrival sequence and its seeded visible-order shuffle."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def visible_window(pending: Sequence[int], buffer_size: int) -> list[int]:
    """The first ``buffer_size`` unprocessed objects (indices into the case) in arrival order."""
    return list(pending[:buffer_size])


def shuffled_view(window: Sequence[int], rng: np.random.Generator) -> list[int]:
    """The window in the order the policy sees it this step (a fresh permutation each step)."""
    order = rng.permutation(len(window))
    return [window[i] for i in order]


def episode_rng(case_seed: int, run_seed: int) -> np.random.Generator:
    """The episode's RNG, seeded from (case seed, run seed) so runs are reproducible per case."""
    return np.random.default_rng(
        np.random.SeedSequence([int(case_seed) & 0xFFFFFFFF, int(run_seed) & 0xFFFFFFFF])
    )
