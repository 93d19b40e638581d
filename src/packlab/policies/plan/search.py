"""Lookahead over the shown buffer: first placements, greedy rollouts, an end-state cost (pure).

The model of the container is the geometric backend's: a box rests at Eq. 2's height and the
heightmap under its footprint becomes its top. A decision:

1. proposes first placements (:mod:`.proposer`): ``first`` from SDF-Pack's ranking,
   ``first`` from a flush/contact ranking and ``listed`` from the students' proposer, over
   every shown object and both rotations;
2. rolls each out: a base policy places the other shown objects one by one, ``depth``
   placements at most (a rollout that finds no floor-fitting place for an object stops and pays
   for it). ``rollout`` names the base policies: SDF-Pack's choice, the students' proposer's
   first listed placement (``lowest``), the flush/contact ranking's first (``flush``); with more
   than one, each first placement is rolled out by each and costs its cheapest end state (a
   rollout over several base policies does at least as well, under the model, as the best of
   them alone);
3. scores the end state (:func:`.evaluate.state_cost`, with the episode's volumes where they
   are known, :mod:`.outlook`): every complete rollout has placed the same boxes, so the costs
   compare like for like;
4. commits only the first placement of the cheapest rollout (receding horizon: the closed loop
   corrects what the model got wrong); with ``check_support`` the cheapest whose centre is
   over its support (:mod:`.stability`), falling back down the ranking.

With ``time_s`` set, rollouts stop once the time is spent (the first one always runs); the
answer is the best so far.

Under the online protocol (``Problem.in_order``, from ``Observation.must_place_first``) the
first placements are the first shown box's only, and every rollout places the other shown boxes
in the order shown, as the protocol will make the robot place them: the lookahead boxes still
decide where the first one goes.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from packlab.core.choices import RolloutBase
from packlab.core.feasibility import CandidateSet, search_candidates
from packlab.core.types import ShownItem
from packlab.policies.candidates import ProposerConfig, proposed_indices
from packlab.policies.features import space_under_at
from packlab.policies.heuristics import sdf
from packlab.policies.heuristics.select import choose, rim_pool
from packlab.policies.plan.evaluate import PathLoss, Weights, state_cost
from packlab.policies.plan.outlook import Outlook, cell_volume
from packlab.policies.plan.proposer import by_flush, by_sdf, first_placements
from packlab.policies.plan.stability import centre_supported
from packlab.sim.heightmap import place_box


@dataclass(frozen=True, slots=True)
class Budget:
    """How much search a decision may use."""

    first: int = 3  # first placements from each of the two rankings
    listed: int = 4  # and from the students' proposer (:mod:`.proposer`, item 3)
    depth: int = 10  # placements per rollout after the first (all shown objects when larger)
    time_s: float | None = None  # anytime limit (not bit-reproducible when set)
    beam: int = 1  # partial rollouts kept per depth, and placements tried per kept rollout
    #: The base policies that roll each first placement out (``_BASES``); a first placement
    #: costs the cheapest of its rollouts. The beam (``beam`` > 1) extends by SDF-Pack's
    #: ranking only and does not read it.
    rollout: RolloutBase = "sdf"


@dataclass(frozen=True, slots=True)
class Problem:
    """What one decision searches over (fixed during the search)."""

    shown: tuple[ShownItem, ...]
    container_height_mm: int
    cell_mm: int
    footprints: tuple[tuple[int, int], ...]  # for the unreachable-pit term
    weights: Weights
    #: Online protocol: the boxes are placed in the order shown (``shown[0]`` first).
    in_order: bool = False
    #: The episode's volumes before this decision (:mod:`.outlook`); None: not known.
    outlook: Outlook | None = None

    def state_outlook(self, left: tuple[int, ...], stuck: bool = False) -> Outlook | None:
        """The outlook once the shown objects not in ``left`` are placed; ``left`` is still to
        come, or with ``stuck`` lost (fits nowhere)."""
        if self.outlook is None:
            return None
        placed = sum(cell_volume(s) for k, s in enumerate(self.shown) if k not in left)
        to_come = 0 if stuck else sum(cell_volume(self.shown[k]) for k in left)
        return self.outlook.after(placed, to_come)


@dataclass(frozen=True, slots=True)
class Placement:
    object_index: int  # into Problem.shown
    rotation: int
    x: int
    y: int


@dataclass(frozen=True, slots=True)
class Outcome:
    """The search's answer and what it cost."""

    placement: Placement | None  # None when no shown object fits the floor
    rollouts: int
    cost: float
    fell_back: bool = False  # the cheapest placement failed the support test (check_support)


def _candidates(hm: np.ndarray, problem: Problem, left: tuple[int, ...]) -> CandidateSet:
    """Candidates of the objects ``left`` (indices into ``left``); in order, of ``left[0]``
    only (its index stays 0)."""
    return search_candidates(
        hm,
        [problem.shown[i] for i in left],
        problem.container_height_mm,
        problem.cell_mm,
        first_only=problem.in_order,
    )


def _apply(
    hm: np.ndarray, cands: CandidateSet, i: int, problem: Problem
) -> tuple[np.ndarray, PathLoss]:
    """(heightmap after candidate ``i``, what that placement lost: trapped and over-rim cell-mm)."""
    x, y, fx, fy = (int(a[i]) for a in (cands.x, cands.y, cands.fx, cands.fy))
    top, z = int(cands.top[i]), int(cands.z[i])
    trapped = space_under_at(hm, x, y, fx, fy, z)
    over = max(0, top - problem.container_height_mm) * fx * fy
    return place_box(hm, x, y, fx, fy, top), PathLoss(trapped, over)


def _stuck_cost(hm: np.ndarray, loss: PathLoss, left: tuple[int, ...], problem: Problem) -> float:
    """Cost when none of the objects ``left`` fits: they count as lost over the rim."""
    lost = sum(int(np.prod(problem.shown[k].size_cells[:2])) for k in left)
    loss = loss.plus(0, lost * problem.container_height_mm)
    outlook = problem.state_outlook(left, stuck=True)
    return state_cost(hm, loss, problem.footprints, problem.weights, outlook)


def _sdf_pick(cands: CandidateSet) -> int | None:
    return choose(cands, sdf.score(cands))


def _lowest_pick(cands: CandidateSet) -> int | None:
    listed = proposed_indices(cands, ProposerConfig(k=1))
    return listed[0] if listed else None


def _flush_pick(cands: CandidateSet) -> int | None:
    pool = rim_pool(cands)
    return int(by_flush(cands, pool)[0]) if pool.size else None


#: Rollout base policies by name: SDF-Pack's choice, the students' proposer's first listed
#: placement (each shape's lowest, most enclosed resting place, lowest first), the flush/contact
#: ranking's first. Measured in docs/planner.md ("Rollout base policies"); the default is ``sdf``.
_BASES: dict[RolloutBase, tuple[Callable[[CandidateSet], int | None], ...]] = {
    "sdf": (_sdf_pick,),
    "lowest": (_lowest_pick,),
    "sdf+lowest": (_sdf_pick, _lowest_pick),
    "sdf+lowest+flush": (_sdf_pick, _lowest_pick, _flush_pick),
}


def rollout(
    hm: np.ndarray,
    left: tuple[int, ...],
    problem: Problem,
    depth: int,
    loss: PathLoss,
    base: Callable[[CandidateSet], int | None] = _sdf_pick,
) -> float:
    """End-state cost after the ``base`` policy (default SDF-Pack's choice) places up to
    ``depth`` of the objects ``left``."""
    for _ in range(min(depth, len(left))):
        cands = _candidates(hm, problem, left)
        i = base(cands)
        if i is None:  # nothing fits: the objects left count as lost over the rim
            return _stuck_cost(hm, loss, left, problem)
        hm, lost = _apply(hm, cands, i, problem)
        loss = loss.plus(lost.trapped, lost.over_rim)
        placed = left[int(cands.obj[i])]
        left = tuple(k for k in left if k != placed)
    return state_cost(hm, loss, problem.footprints, problem.weights, problem.state_outlook(left))


@dataclass(frozen=True, slots=True)
class _Path:
    """A partial rollout in the beam: its heightmap, what it lost, the objects still to place."""

    hm: np.ndarray
    loss: PathLoss
    left: tuple[int, ...]
    cost: float


def _children(path: _Path, problem: Problem, width: int) -> list[_Path]:
    """``path`` extended by each of SDF-Pack's ``width`` best placements of its objects left."""
    cands = _candidates(path.hm, problem, path.left)
    pool = rim_pool(cands)
    if pool.size == 0:
        return [_Path(path.hm, path.loss, (), _stuck_cost(path.hm, path.loss, path.left, problem))]
    out = []
    for i in by_sdf(cands, pool)[:width]:
        hm, lost = _apply(path.hm, cands, int(i), problem)
        loss = path.loss.plus(lost.trapped, lost.over_rim)
        placed = path.left[int(cands.obj[i])]
        left = tuple(k for k in path.left if k != placed)
        outlook = problem.state_outlook(left)
        cost = state_cost(hm, loss, problem.footprints, problem.weights, outlook)
        out.append(_Path(hm, loss, left, cost))
    return out


def beam_rollout(
    hm: np.ndarray, left: tuple[int, ...], problem: Problem, budget: Budget, loss: PathLoss
) -> float:
    """Like :func:`rollout`, but keeping the ``budget.beam`` cheapest partial rollouts at each
    depth, each extended by SDF-Pack's ``budget.beam`` best placements (not only its best)."""
    paths = [_Path(hm, loss, left, 0.0)]
    for _ in range(min(budget.depth, len(left))):
        grown = [c for p in paths for c in (_children(p, problem, budget.beam) if p.left else [p])]
        paths = sorted(grown, key=lambda p: p.cost)[: budget.beam]
    return min(p.cost for p in paths)


def _supported(hm: np.ndarray, cands: CandidateSet, i: int) -> bool:
    x, y, fx, fy, z = (int(a[i]) for a in (cands.x, cands.y, cands.fx, cands.fy, cands.z))
    return centre_supported(hm, x, y, fx, fy, z)


def _pick(
    hm: np.ndarray, cands: CandidateSet, scored: list[tuple[float, int]], check_support: bool
) -> tuple[float, int, bool]:
    """(cost, candidate, whether the cheapest failed the support test): the cheapest scored
    first placement, or with ``check_support`` the cheapest whose centre is supported (the
    cheapest overall when none is)."""
    ranked = sorted(scored, key=lambda t: t[0])  # stable: equal costs keep proposal order
    if not check_support:
        return ranked[0][0], ranked[0][1], False
    for n, (cost, i) in enumerate(ranked):
        if _supported(hm, cands, i):
            return cost, i, n > 0
    return ranked[0][0], ranked[0][1], True


def search(
    heightmap: np.ndarray,
    problem: Problem,
    budget: Budget,
    check_support: bool = False,
    firsts: Sequence[int] | None = None,
    candidates: CandidateSet | None = None,
) -> Outcome:
    """The first placement of the cheapest rollout (see the module docstring).

    ``firsts`` replaces step 1's proposals by these indices into the shared candidate search of
    the whole shown buffer (the planner restricted to another proposer's set, for measuring it).
    ``candidates``: that search when the caller already ran it on this heightmap and problem.
    """
    start = time.perf_counter()
    hm = np.asarray(heightmap)
    everything = tuple(range(len(problem.shown)))
    cands = _candidates(hm, problem, everything) if candidates is None else candidates
    if firsts is None:
        firsts = first_placements(cands, budget.first, budget.listed)
    else:
        firsts = list(firsts)
    if not firsts:
        return Outcome(None, 0, float("inf"))
    scored: list[tuple[float, int]] = []
    for i in firsts:
        after, loss = _apply(hm, cands, i, problem)
        placed = int(cands.obj[i])
        left = tuple(k for k in everything if k != placed)
        if budget.beam > 1:
            scored.append((beam_rollout(after, left, problem, budget, loss), i))
        else:
            cost = min(
                rollout(after, left, problem, budget.depth, loss, base)
                for base in _BASES[budget.rollout]
            )
            scored.append((cost, i))
        if budget.time_s is not None and time.perf_counter() - start > budget.time_s:
            break
    cost, i, fell_back = _pick(hm, cands, scored, check_support)
    return Outcome(
        Placement(int(cands.obj[i]), int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i])),
        len(scored),
        cost,
        fell_back,
    )
