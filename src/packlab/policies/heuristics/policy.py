"""HeuristicPolicy: the Policy protocol over one scorer, and the registered names.

Each decision is: candidate search on the observation (one Eq. 2 window max per footprint),
the heuristic's keys, the shared rim rule and tie-break (:mod:`.select`). Heuristics are
deterministic; the run seed is accepted and ignored.

Options (factory keywords, so ``packlab bench --policy-arg dblf:tie_break=shown_order`` works):

- ``tie_break``: how placements that tie on every key are settled, one of
  :data:`~packlab.policies.heuristics.select.TIE_BREAKS`; default ``"larger_volume"``.
- ``overflow``: when no shown box fits under the rim, ``place`` the one sticking out least
  (the literature's rule, the default) or ``score`` (:mod:`packlab.policies.overflow`: place
  one only where that raises the episode's Overall, else set one aside; it also decides the
  episode's last box where every placement of it raises the top).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from packlab.core.choices import OverflowRule, require_choice
from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Observation
from packlab.policies.heuristics import dblf, ffp, hm, mta, sdf
from packlab.policies.heuristics.select import (
    DEFAULT_TIE_BREAK,
    Scorer,
    TieBreak,
    check_tie_break,
    choose,
    first_object,
    to_action,
)
from packlab.policies.overflow import overflow_decision
from packlab.policies.registry import SeedFreeMode, declare_seed_free

#: Heuristic scorers by registered policy name.
SCORERS: dict[str, Scorer] = {
    dblf.NAME: dblf.score,
    hm.NAME: hm.score,
    mta.NAME: mta.score,
    ffp.NAME: ffp.score,
    sdf.NAME: sdf.score,
}

#: The action returned when no shown object fits the floor in any rotation. The episode records
#: it as an invalid (out_of_bounds) step and sets that object aside, which is all that can
#: happen. Its object is the first of the tie-break order (:func:`.select.first_object`; shown
#: object 0 under ``shown_order``), so the default rule does not read the shown order here either.
NO_CANDIDATE_ACTION = Action(object_id=0, rotation=0, x=0, y=0)


#: Factory keywords every heuristic accepts.
OPTIONS = ("tie_break", "overflow")


def decide(
    observation: Observation,
    scorer: Scorer,
    tie_break: TieBreak = DEFAULT_TIE_BREAK,
    overflow: OverflowRule = "place",
) -> Action:
    """The action a scorer chooses for an observation (pure)."""
    cands = observation_candidates(observation)
    overflowed = overflow_decision(observation, cands, overflow)
    if overflowed is not None:
        return overflowed
    index = choose(cands, scorer(cands), tie_break)
    if index is None:
        return replace(NO_CANDIDATE_ACTION, object_id=first_object(cands, tie_break))
    return to_action(cands, index)


@dataclass(frozen=True, slots=True)
class HeuristicPolicy:
    """A heuristic as a Policy: stateless, deterministic."""

    name: str
    scorer: Scorer
    tie_break: TieBreak = DEFAULT_TIE_BREAK
    overflow: OverflowRule = "place"

    def __post_init__(self) -> None:
        check_tie_break(self.tie_break, self.name)
        require_choice(self.overflow, OverflowRule, f"policy-arg {self.name}:overflow")

    def reset(self, start: EpisodeStart, seed: int) -> None:
        """Nothing to prepare: the heuristics keep no state across steps."""

    def act(self, observation: Observation) -> Action:
        return decide(observation, self.scorer, self.tie_break, self.overflow)


def make_heuristic(name: str, **options: Any) -> HeuristicPolicy:
    """A HeuristicPolicy by name (one of SCORERS) with options (see the module docstring)."""
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise ConfigError(
            f"policy-arg {name}:{unknown[0]}: unknown option of heuristic {name!r}; "
            f"known: {', '.join(OPTIONS)}"
        )
    tie_break = check_tie_break(options.get("tie_break", DEFAULT_TIE_BREAK), name)
    overflow = options.get("overflow", "place")
    return HeuristicPolicy(name=name, scorer=SCORERS[name], tie_break=tie_break, overflow=overflow)


def heuristic_seed_free(options: Mapping[str, Any]) -> frozenset[SeedFreeMode]:
    """Where a heuristic plays the same episode for every run seed (``registry.SeedFreeMode``).

    It never reads the seed, so in arrival order always. Under a shuffled buffer only with the
    default rules: ``larger_volume`` settles ties by size and id, never by the shown order, and
    ``overflow=place`` is the rim rule; ``shown_order`` and rule ``score`` (first of equal
    scores, set-aside of shown box 0 where nothing fits) read the shown order.
    """
    order_free = (
        options.get("tie_break", DEFAULT_TIE_BREAK) == "larger_volume"
        and options.get("overflow", "place") == "place"
    )
    return frozenset({"arrival", "shuffled"} if order_free else {"arrival"})


# The entry-point factories (pyproject ``packlab.policies``): one per heuristic.
@declare_seed_free(heuristic_seed_free)
def make_dblf(**options: Any) -> HeuristicPolicy:
    return make_heuristic("dblf", **options)


@declare_seed_free(heuristic_seed_free)
def make_hm(**options: Any) -> HeuristicPolicy:
    return make_heuristic("hm", **options)


@declare_seed_free(heuristic_seed_free)
def make_mta(**options: Any) -> HeuristicPolicy:
    return make_heuristic("mta", **options)


@declare_seed_free(heuristic_seed_free)
def make_ffp(**options: Any) -> HeuristicPolicy:
    return make_heuristic("ffp", **options)


@declare_seed_free(heuristic_seed_free)
def make_sdf(**options: Any) -> HeuristicPolicy:
    return make_heuristic("sdf", **options)
