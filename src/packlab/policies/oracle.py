"""The oracle: replays a case's perfect layout (``gt_plan``), the ceiling of every suite."""

from __future__ import annotations

from packlab.core.errors import ConfigError
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Case, InternalId, Observation, PlanStep
from packlab.policies.registry import declare_seed_free, seed_free_always


class OraclePolicy:
    """Each step places the shown object that comes first in the plan, where the plan puts it.

    The plan order is a valid placement order (every object supported), and the arrival order
    of generated cases follows it, so the earliest planned object is always in the window.

    The plan's rotations refer to the catalogue's (l, w); an observation may name a box's sides
    otherwise (``--sides longer-first``: (w, l) where l < w), and then the shown rotation that
    puts the box where the plan does is the other one. The oracle tells which from the shown
    size, so it replays the plan under either naming.
    """

    name = "oracle"
    #: It replays the case's plan: the episode hands it the case (``EpisodeStart`` otherwise).
    needs_case = True

    def __init__(self) -> None:
        self._plan: dict[InternalId, tuple[int, PlanStep]] = {}
        self._sizes: dict[InternalId, tuple[int, int, int]] = {}

    def reset(self, case: EpisodeStart | Case, seed: int) -> None:
        if not isinstance(case, Case):
            raise ConfigError("the oracle replays the case's plan: it must be handed the case")
        if case.gt_plan is None:
            raise ConfigError(
                f"case {case.episode_id!r}: the oracle needs a gt_plan and this case has none"
            )
        self._plan = {step.internal_id: (order, step) for order, step in enumerate(case.gt_plan)}
        self._sizes = {box.internal_id: box.size_mm for box in case.objects}

    def act(self, observation: Observation) -> Action:
        planned = [
            (self._plan[s.internal_id][0], s)
            for s in observation.shown
            if s.internal_id in self._plan
        ]
        if not planned:
            raise ConfigError(
                "oracle: no shown object is in the plan (it replays the plan by the case's "
                "ids; perceived observation shows fresh ids, so it needs --observation exact)"
            )
        _, item = min(planned, key=lambda pair: pair[0])
        step = self._plan[item.internal_id][1]
        l, w, _ = self._sizes[item.internal_id]
        swapped = l != w and tuple(item.size_mm[:2]) == (w, l)
        rotation = step.rotation ^ int(swapped)
        return Action(object_id=item.shown_index, rotation=rotation, x=step.x, y=step.y)


# Seed-free everywhere: it never reads the seed, and the shown box it takes is the earliest in
# the plan, found by id whatever order the buffer is shown in.
@declare_seed_free(seed_free_always)
def make_oracle() -> OraclePolicy:
    return OraclePolicy()
