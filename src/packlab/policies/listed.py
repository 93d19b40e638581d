"""Teachers restricted to the proposer's listed placements: which listed index each would pick.

Candidate-mode training labels each state with a teacher's pick among the K placements the
proposer listed (:mod:`packlab.policies.candidates`), so the label is a function of what the
model is shown. Teachers (``TEACHERS``):

- ``plan``: rolls out each listed placement as the first placement (the planner's search with
  the listed set instead of its own proposals, default budget) and picks the cheapest;
- ``sdf``, ``mta``: rank the listed placements by their own keys, then the shared tie-break
  (larger object first, then scan order);
- ``oracle``: the case's own plan (hidden layout); its action is often not listed, then -1;
- ``oracle-canonical``: the oracle's object and rotation, the position the proposer ranks first
  for that (object, rotation) among the listed ones (lowest, most flush); -1 when the list has
  no placement of that object and rotation;
- ``first``: always index 0 (the proposer's own pick; a floor, not a teacher to train on).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.feasibility import CandidateSet
from packlab.core.types import Action, Case, Observation
from packlab.policies.candidates import Candidate
from packlab.policies.heuristics.policy import SCORERS
from packlab.policies.heuristics.select import object_rank
from packlab.policies.oracle import OraclePolicy
from packlab.policies.plan.evaluate import Weights
from packlab.policies.plan.policy import observation_problem
from packlab.policies.plan.search import Budget, search

TEACHERS = ("plan", "sdf", "mta", "oracle", "oracle-canonical", "first")


def flat_index(cands: CandidateSet, cand: Candidate) -> int:
    """The index of a listed placement in the candidate search it came from."""
    for g in cands.groups:
        if g.object_index == cand.object_index and g.rotation == cand.rotation:
            return g.offset + cand.x * g.z.shape[1] + cand.y
    raise KeyError(f"no group for object {cand.object_index} rotation {cand.rotation}")


def _listed_flat(cands: CandidateSet, listed: Sequence[Candidate]) -> np.ndarray:
    return np.array([flat_index(cands, c) for c in listed], dtype=np.int64)


def best_by_keys(cands: CandidateSet, teacher: str, listed: Sequence[Candidate]) -> int:
    """The listed index SDF-Pack or MTA ranks first (its keys, then the default tie-break)."""
    flat = _listed_flat(cands, listed)
    keys = [np.asarray(k)[flat] for k in SCORERS[teacher](cands)]
    rank = object_rank(cands.shown_sizes_mm, cands.shown_id_order)[cands.obj[flat]]
    # np.lexsort sorts by its last key first: the teacher's keys, then object rank, then scan.
    return int(np.lexsort((flat, rank, *reversed(keys)))[0])


def best_by_plan(observation: Observation, cands: CandidateSet, listed: Sequence[Candidate]) -> int:
    """The listed index whose rollout the planner (default budget) finds cheapest."""
    problem = observation_problem(observation, Weights())
    flat = _listed_flat(cands, listed)
    placement = search(observation.heightmap, problem, Budget(), firsts=flat.tolist()).placement
    if placement is None:  # listed placements always fit; keep the proposer's pick regardless
        return 0
    chosen = Action(placement.object_index, placement.rotation, placement.x, placement.y)
    return next(i for i, c in enumerate(listed) if c.action == chosen)


class ListedTeacher:
    """One teacher's pick among listed placements; ``reset`` before each episode (the oracle
    reads the case's plan)."""

    def __init__(self, teacher: str) -> None:
        if teacher not in TEACHERS:
            raise ConfigError(f"teacher = {teacher!r}: expected one of {', '.join(TEACHERS)}")
        self.teacher = teacher
        self._oracle = OraclePolicy()

    def reset(self, case: Case, seed: int) -> None:
        if self.teacher.startswith("oracle"):
            self._oracle.reset(case, seed)

    def own_action(self, observation: Observation) -> Action:
        """The teacher's own action where its pick is not listed (the raw oracle's layout)."""
        return self._oracle.act(observation)

    def choose(
        self, observation: Observation, cands: CandidateSet, listed: Sequence[Candidate]
    ) -> int:
        """The index into ``listed`` (non-empty), or -1 when the teacher's action is not listed."""
        if self.teacher == "first":
            return 0
        if self.teacher == "plan":
            return best_by_plan(observation, cands, listed)
        if self.teacher in SCORERS:
            return best_by_keys(cands, self.teacher, listed)
        action = self._oracle.act(observation)
        if self.teacher == "oracle":
            return next((i for i, c in enumerate(listed) if c.action == action), -1)
        same = (action.object_id, action.rotation)
        return next((i for i, c in enumerate(listed) if (c.object_index, c.rotation) == same), -1)
