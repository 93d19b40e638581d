"""HeuristicPolicy: the Policy protocol over one scorer, and the registered names.

Each decision is: candidate search on the observation (one Eq. 2 window max per footprint),
the heuristic's keys, the shared rim rule and tie-break (:mod:`.select`). Heuristics are
deterministic; the run seed is accepted and ignored.
"""

from __future__ import annotations

from dataclasses import dataclass

from packlab.policies.heuristics import dblf, ffp, hm, mta, sdf
from packlab.policies.heuristics.candidates import observation_candidates
from packlab.policies.heuristics.select import Scorer, choose, to_action
from packlab.policies.registry import register_policy
from packlab.types import Action, Case, Observation

#: Heuristic scorers by registered policy name.
SCORERS: dict[str, Scorer] = {
    dblf.NAME: dblf.score,
    hm.NAME: hm.score,
    mta.NAME: mta.score,
    ffp.NAME: ffp.score,
    sdf.NAME: sdf.score,
}

#: The action returned when no shown object fits the floor in any rotation. The episode records
#: it as an invalid (out_of_bounds) step and sets an object aside, which is all that can happen.
NO_CANDIDATE_ACTION = Action(object_id=0, rotation=0, x=0, y=0)


def decide(observation: Observation, scorer: Scorer) -> Action:
    """The action a scorer chooses for an observation (pure)."""
    cands = observation_candidates(observation)
    index = choose(cands, scorer(cands))
    return NO_CANDIDATE_ACTION if index is None else to_action(cands, index)


@dataclass(frozen=True, slots=True)
class HeuristicPolicy:
    """A heuristic as a Policy: stateless, deterministic."""

    name: str
    scorer: Scorer

    def reset(self, case: Case, seed: int) -> None:
        """Nothing to prepare: the heuristics keep no state across steps."""

    def act(self, observation: Observation) -> Action:
        return decide(observation, self.scorer)


def make_heuristic(name: str) -> HeuristicPolicy:
    """A HeuristicPolicy by name (one of SCORERS)."""
    return HeuristicPolicy(name=name, scorer=SCORERS[name])


@register_policy(dblf.NAME)
def make_dblf() -> HeuristicPolicy:
    return make_heuristic(dblf.NAME)


@register_policy(hm.NAME)
def make_hm() -> HeuristicPolicy:
    return make_heuristic(hm.NAME)


@register_policy(mta.NAME)
def make_mta() -> HeuristicPolicy:
    return make_heuristic(mta.NAME)


@register_policy(ffp.NAME)
def make_ffp() -> HeuristicPolicy:
    return make_heuristic(ffp.NAME)


@register_policy(sdf.NAME)
def make_sdf() -> HeuristicPolicy:
    return make_heuristic(sdf.NAME)
