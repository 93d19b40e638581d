"""The random policy: uniform over placements whose top stays within the rim (the floor row)."""

from __future__ import annotations

import numpy as np

from packlab.policies.registry import register_policy
from packlab.sim.buffer import episode_rng
from packlab.sim.heightmap import footprint_max
from packlab.types import Action, Case, Observation


class RandomPolicy:
    """Samples uniformly among in-rim candidates; if there are none, among all that fit."""

    name = "random"

    def __init__(self) -> None:
        self._rng = np.random.default_rng(0)

    def reset(self, case: Case, seed: int) -> None:
        # Offset the stream from the episode's shuffle RNG so the two are independent.
        self._rng = episode_rng(case.seed + 7919, seed)

    def act(self, observation: Observation) -> Action:
        rim = observation.container.height_mm
        fitting: list[tuple[int, int, int, int]] = []
        in_rim: list[tuple[int, int, int, int]] = []
        for item in observation.shown:
            l, w, h = item.size_cells[0], item.size_cells[1], item.size_mm[2]
            for rotation, (fx, fy) in enumerate(((l, w), (w, l))):
                z = footprint_max(observation.heightmap, fx, fy)
                xs, ys = np.nonzero(np.ones_like(z, dtype=bool))
                ok = (z[xs, ys] + h) <= rim
                fitting += [(item.shown_index, rotation, int(x), int(y)) for x, y in zip(xs, ys)]
                in_rim += [(item.shown_index, rotation, int(x), int(y)) for x, y in zip(xs[ok], ys[ok])]
        pool = in_rim or fitting
        if not pool:  # nothing fits the floor at all: any action is set aside anyway
            return Action(0, 0, 0, 0)
        obj, rot, x, y = pool[int(self._rng.integers(len(pool)))]
        return Action(obj, rot, x, y)


@register_policy("random")
def make_random() -> RandomPolicy:
    return RandomPolicy()
