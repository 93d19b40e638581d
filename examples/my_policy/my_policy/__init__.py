"""``my-policy``: lowest-first, a packing policy of your own for packlab.

Each step it places a shown box where a box comes to rest lowest (its drop height), keeping
the top under the container's rim. Among equally low placements it takes the one with the
larger footprint (``prefer="area"``, the default) or the first in scan order
(``prefer="scan"``). It is a few lines over packlab's shared candidate search, which lists
every placement of every shown box with its resting height; a real policy would score those
candidates its own way.
"""

from __future__ import annotations

import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Action, Observation
from packlab.policies import EpisodeStart

NAME = "my-policy"
PREFERENCES = ("area", "scan")
#: The answer when no shown box fits the floor at all: set the first one aside on purpose (the
#: episode records the step with reason ``set_aside``; the box counts as unpacked).
SET_ASIDE = Action.set_aside(0)


class LowestFirstPolicy:
    """The Policy protocol (``packlab.core.protocols.Policy``): ``name``, ``reset``, ``act``."""

    name = NAME

    def __init__(self, prefer: str = "area") -> None:
        if prefer not in PREFERENCES:
            # A ConfigError is printed by packlab's commands as one line, exit code 2.
            raise ConfigError(
                f"policy-arg {NAME}:prefer = {prefer!r}: choose one of {', '.join(PREFERENCES)}"
            )
        self.prefer = prefer

    def reset(self, start: EpisodeStart, seed: int) -> None:
        """A new episode: ``start`` holds what a cell knows (container, buffer size) and random
        streams; this policy keeps no state between steps."""

    def act(self, observation: Observation) -> Action:
        """The placement for this step, read from the observation alone."""
        # Every placement of every shown box (both rotations, every cell) whose footprint lies
        # on the floor, with its resting height ``z`` and top ``top`` in mm.
        cands = observation_candidates(observation)
        if len(cands) == 0:
            return SET_ASIDE
        under_rim = np.flatnonzero(cands.fits_in_rim)
        if under_rim.size:
            pool, height = under_rim, cands.z[under_rim]
        else:  # nothing stays under the rim: stick out as little as possible
            pool, height = np.arange(len(cands)), cands.top
        area = cands.fx[pool] * cands.fy[pool]
        tie = -area if self.prefer == "area" else np.zeros_like(area)
        # lexsort sorts by its last key first and is stable: lowest, then the tie rule, then
        # the scan order the candidates come in (shown box, rotation, x, y).
        best = pool[np.lexsort((tie, height))[0]]
        return Action(
            object_id=int(cands.obj[best]),
            rotation=int(cands.rotation[best]),
            x=int(cands.x[best]),
            y=int(cands.y[best]),
        )


def make_lowest_first(prefer: str = "area") -> LowestFirstPolicy:
    """Lowest-first: where a box comes to rest lowest, the larger footprint on ties."""
    return LowestFirstPolicy(prefer=prefer)
