"""Teachers restricted to the proposer's listed placements: which listed index each would pick.

Candidate-mode training labels each state with a teacher's pick among the K placements the
proposer listed (:mod:`packlab.policies.candidates`), so the label is a function of what the
model is shown. Teachers (``TEACHERS``):

- ``plan``: the planner itself (``plan-fast``: completion, then lookahead) decides with its own
  proposals; its pick is added to the list (as line K) when the proposer did not list it, so a
  student can always be shown its teacher's action. When the pick comes from a tiling of the
  lowest level, every listed placement that is a box of that tiling is an equally good first
  placement: the label's soft target gives the pick half the mass and those boxes the other
  half (:class:`TeacherLabel`);
- ``plan-lookahead``: rolls out each listed placement as the first placement (the planner's
  search with the listed set instead of its own proposals, default budget) and picks the
  cheapest (the planner's teacher without the completion stage);
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
from dataclasses import dataclass

import numpy as np

from packlab.core.choices import TEACHERS
from packlab.core.errors import ConfigError
from packlab.core.feasibility import CandidateSet
from packlab.core.types import Action, Case, Observation
from packlab.policies.candidates import Candidate, candidate_for, placement_index
from packlab.policies.heuristics.policy import SCORERS
from packlab.policies.heuristics.select import object_rank
from packlab.policies.oracle import OraclePolicy
from packlab.policies.plan.cover import JOKER
from packlab.policies.plan.evaluate import Weights
from packlab.policies.plan.policy import PlanDecision, make_plan_fast, observation_problem
from packlab.policies.plan.search import Budget, search
from packlab.sim.episode import episode_start

#: The soft target's share for the teacher's own pick when other listed boxes of its tiling
#: share the rest: the pick stays the single most likely answer.
PICK_SHARE = 0.5


@dataclass(frozen=True, slots=True)
class TeacherLabel:
    """A teacher's answer for one state: the listed placements it is given over (the proposer's
    K, plus the teacher's own pick when it was missing: ``added``), the index it picks (-1: not
    listed), its preference over the listed lines (``soft``, sums to 1; empty: all on
    ``label``) and its own action (what to play when following the teacher)."""

    listed: tuple[Candidate, ...]
    label: int
    action: Action
    soft: tuple[float, ...] = ()
    added: bool = False


def flat_index(cands: CandidateSet, cand: Candidate) -> int:
    """The index of a listed placement in the candidate search it came from."""
    i = placement_index(cands, cand.object_index, cand.rotation, cand.x, cand.y)
    if i is None:
        raise KeyError(f"no placement of object {cand.object_index} rotation {cand.rotation}")
    return i


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
        # A listed placement cannot say "set this box aside": the planner labels with the rim
        # rule the list can hold (packlab.policies.overflow).
        self._plan = make_plan_fast(overflow="place")

    def reset(self, case: Case, seed: int) -> None:
        if self.teacher.startswith("oracle"):
            self._oracle.reset(case, seed)
        # The planner keeps an episode's state (a filling it follows, a proof that none exists):
        # a new episode must not inherit the last one's.
        self._plan.reset(episode_start(case, seed), seed)

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
            return self.label(observation, cands, listed).label
        if self.teacher == "plan-lookahead":
            return best_by_plan(observation, cands, listed)
        if self.teacher in SCORERS:
            return best_by_keys(cands, self.teacher, listed)
        action = self._oracle.act(observation)
        if self.teacher == "oracle":
            return next((i for i, c in enumerate(listed) if c.action == action), -1)
        same = (action.object_id, action.rotation)
        return next((i for i, c in enumerate(listed) if (c.object_index, c.rotation) == same), -1)

    def label(
        self, observation: Observation, cands: CandidateSet, listed: Sequence[Candidate]
    ) -> TeacherLabel:
        """The teacher's full answer (:class:`TeacherLabel`); only ``plan`` adds its pick to the
        list and gives a soft target, every other teacher labels the list as given."""
        if self.teacher != "plan":
            label = self.choose(observation, cands, listed)
            own = listed[label].action if label >= 0 else self.own_action(observation)
            return TeacherLabel(tuple(listed), label, own)
        decision = self._plan.decide(observation)
        shown = observation.shown
        listed = list(listed)
        label = next((i for i, c in enumerate(listed) if _same(c, decision.action, shown)), -1)
        added = False
        if label < 0:
            extra = _listable(cands, decision.action, shown, len(listed))
            if extra is not None:
                listed.append(extra)
                label, added = len(listed) - 1, True
        soft = _tiling_soft(decision, listed, label, shown) if label >= 0 else ()
        return TeacherLabel(tuple(listed), label, decision.action, soft, added)


def _shape_at(c: Candidate, shown: Sequence) -> tuple[int, int, int, int, int]:
    """What makes two placements the same: footprint, box height and position (boxes of
    identical size are interchangeable; the proposer lists only one of them)."""
    return (c.fx, c.fy, shown[c.object_index].size_mm[2], c.x, c.y)


def _same(c: Candidate, action: Action, shown: Sequence) -> bool:
    s = shown[action.object_id].size_cells
    fx, fy = (s[0], s[1]) if action.rotation == 0 else (s[1], s[0])
    return _shape_at(c, shown) == (fx, fy, shown[action.object_id].size_mm[2], action.x, action.y)


def _listable(cands: CandidateSet, action: Action, shown: Sequence, index: int) -> Candidate | None:
    """The teacher's action as a listed line (a square box's turn is its rotation 0)."""
    found = candidate_for(cands, action, index)
    size = shown[action.object_id].size_cells if 0 <= action.object_id < len(shown) else None
    if found is None and size is not None and size[0] == size[1]:
        turned = Action(action.object_id, 1 - action.rotation, action.x, action.y)
        found = candidate_for(cands, turned, index)
    return found


def _tiling_soft(
    decision: PlanDecision, listed: Sequence[Candidate], label: int, shown: Sequence
) -> tuple[float, ...]:
    """The soft target: the pick, and the listed boxes of its tiling (see PICK_SHARE)."""
    tiling = decision.completion
    if tiling is None:
        return ()
    # Each box's own height: a tiling of mixed heights (CompletionConfig.mixed) has no one.
    boxes = {
        (s.fx, s.fy, shown[s.key].size_mm[2], s.x, s.y) for s in tiling.slots if s.key != JOKER
    }
    others = [i for i, c in enumerate(listed) if i != label and _shape_at(c, shown) in boxes]
    if not others:
        return ()
    soft = np.zeros(len(listed))
    soft[label] = PICK_SHARE
    soft[others] = (1 - PICK_SHARE) / len(others)
    return tuple(float(v) for v in soft)
