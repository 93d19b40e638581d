"""Lookahead over the shown buffer: first placements, greedy rollouts, an end-state cost (pure).

The model of the container is the geometric backend's: a box rests at Eq. 2's height and the
heightmap under its footprint becomes its top. A decision:

1. proposes first placements (:mod:`.proposer`): ``first`` from SDF-Pack's ranking and
   ``first`` from a flush/contact ranking, over every shown object and both rotations;
2. rolls each out: SDF-Pack places the other shown objects one by one, ``depth`` placements at
   most (a rollout that finds no floor-fitting place for an object stops and pays for it);
3. scores the end state (:func:`.evaluate.state_cost`): every complete rollout has placed the
   same boxes, so the costs compare like for like;
4. commits only the first placement of the cheapest rollout (receding horizon: the closed loop
   corrects what the model got wrong).

With ``time_s`` set, rollouts stop once the time is spent (the first one always runs); the
answer is the best so far.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from packlab.core.feasibility import CandidateSet, search_candidates
from packlab.core.types import ShownItem
from packlab.policies.heuristics import sdf
from packlab.policies.heuristics.select import choose
from packlab.policies.plan.evaluate import PathLoss, Weights, state_cost
from packlab.policies.plan.proposer import first_placements
from packlab.sim.heightmap import place_box


@dataclass(frozen=True, slots=True)
class Budget:
    """How much search a decision may use."""

    first: int = 3  # first placements from each of the two rankings
    depth: int = 10  # placements per rollout after the first (all shown objects when larger)
    time_s: float | None = None  # anytime limit (not bit-reproducible when set)


@dataclass(frozen=True, slots=True)
class Problem:
    """What one decision searches over (fixed during the search)."""

    shown: tuple[ShownItem, ...]
    container_height_mm: int
    cell_mm: int
    footprints: tuple[tuple[int, int], ...]  # for the unreachable-pit term
    weights: Weights


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


def _candidates(hm: np.ndarray, problem: Problem, left: tuple[int, ...]) -> CandidateSet:
    return search_candidates(
        hm, [problem.shown[i] for i in left], problem.container_height_mm, problem.cell_mm
    )


def _apply(
    hm: np.ndarray, cands: CandidateSet, i: int, problem: Problem
) -> tuple[np.ndarray, PathLoss]:
    """(heightmap after candidate ``i``, what that placement lost: trapped and over-rim cell-mm)."""
    x, y, fx, fy = (int(a[i]) for a in (cands.x, cands.y, cands.fx, cands.fy))
    top, z = int(cands.top[i]), int(cands.z[i])
    trapped = fx * fy * z - int(hm[x : x + fx, y : y + fy].sum(dtype=np.int64))
    over = max(0, top - problem.container_height_mm) * fx * fy
    return place_box(hm, x, y, fx, fy, top), PathLoss(trapped, over)


def rollout(
    hm: np.ndarray, left: tuple[int, ...], problem: Problem, depth: int, loss: PathLoss
) -> float:
    """End-state cost after SDF-Pack places up to ``depth`` of the objects ``left``."""
    for _ in range(min(depth, len(left))):
        cands = _candidates(hm, problem, left)
        i = choose(cands, sdf.score(cands))
        if i is None:  # nothing fits: the objects left count as lost over the rim
            lost = sum(int(np.prod(problem.shown[k].size_cells[:2])) for k in left)
            return state_cost(
                hm,
                loss.plus(0, lost * problem.container_height_mm),
                problem.footprints,
                problem.weights,
            )
        hm, lost = _apply(hm, cands, i, problem)
        loss = loss.plus(lost.trapped, lost.over_rim)
        placed = left[int(cands.obj[i])]
        left = tuple(k for k in left if k != placed)
    return state_cost(hm, loss, problem.footprints, problem.weights)


def search(heightmap: np.ndarray, problem: Problem, budget: Budget) -> Outcome:
    """The first placement of the cheapest rollout (see the module docstring)."""
    start = time.perf_counter()
    hm = np.asarray(heightmap)
    everything = tuple(range(len(problem.shown)))
    cands = _candidates(hm, problem, everything)
    firsts = first_placements(cands, budget.first)
    if not firsts:
        return Outcome(None, 0, float("inf"))
    best: tuple[float, int] | None = None
    for n, i in enumerate(firsts, 1):
        after, loss = _apply(hm, cands, i, problem)
        placed = int(cands.obj[i])
        left = tuple(k for k in everything if k != placed)
        cost = rollout(after, left, problem, budget.depth, loss)
        if best is None or cost < best[0]:
            best = (cost, i)
        if budget.time_s is not None and time.perf_counter() - start > budget.time_s:
            break
    assert best is not None
    i = best[1]
    return Outcome(
        Placement(int(cands.obj[i]), int(cands.rotation[i]), int(cands.x[i]), int(cands.y[i])),
        n,
        best[0],
    )
