"""A short list of valid placements for candidate action spaces, from a rule that uses no teacher.

A policy that answers with an index into listed placements (the VLM's candidate mode, an RL
agent's candidate action space) needs a proposer: something that turns an observation into K
placements worth choosing between. This one reads only the observation and simple geometry; it
never scores with SDF-Pack, MTA or the planner, which are the teachers such a policy learns
from (``benchmarks/proposer_ceiling.py`` measures how much of each teacher the set keeps).

The rule (deterministic: the same observation always gives the same list):

1. **Pool.** Every floor-fitting placement from the shared candidate search
   (:func:`packlab.core.feasibility.search_candidates`), restricted to the shared rim pool
   (top within the rim, or the lowest tops when nothing fits under it), as every heuristic and
   ``random`` use it. So every proposal is a valid action: in bounds, resting at Eq. 2's height.
2. **Distinct shapes.** Shown boxes of identical size give identical placements, so only one of
   them is proposed: the first in ``internal_id`` order, the shared tie-break's choice between
   identical boxes. Rotation 1 of a square footprint repeats rotation 0 and is skipped.
3. **Per shape, lowest first.** Each remaining (object, rotation) ranks its positions by
   resting height z (lower first), then flushness (more of the box's side cells touching a wall
   or a taller column), then x, then y. Its first position is the lowest, most enclosed resting
   place of that box: a corner on an empty floor, a pocket among placed boxes.
4. **Rounds.** Round r holds every shape's r-th position. Rounds are taken in turn until K
   placements are listed, so every shape gets its lowest position before any gets a second
   (all of them when there are at most K shapes). Within a round the order is set by
   :data:`~packlab.core.choices.ProposerRule`:

   - ``"lowest"`` (default): z, then flushness, then larger box volume, then shape order;
   - ``"lowest+largest"``: two orders taken alternately, ``"lowest"``'s and larger volume first
     (then z, flushness), so big boxes, which greedy contact rules favour, are always listed.

The listed order is the selection order, so index 0 is the proposer's own first choice; the
index is the answer (0 to K - 1). Fewer than K placements are listed only when fewer exist;
none when no shown box fits the floor.

The geometry each :class:`Candidate` carries (resting z, top, support, flushness, the empty
space under it) is what a text rendering can show next to the index; support, flushness and
the space under are the shared placement features (:mod:`packlab.policies.features`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.core.choices import OverflowRule, ProposerRule, require_choice
from packlab.core.feasibility import CandidateSet, Orientation, observation_candidates
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Observation
from packlab.policies.features import (
    flush_cells_at,
    flush_grid,
    side_cells,
    space_under_at,
    support_cells_at,
    walled,
)
from packlab.policies.heuristics.policy import make_sdf
from packlab.policies.heuristics.select import rim_pool
from packlab.policies.overflow import overflow_decision

#: Default number of listed placements.
DEFAULT_K = 8
#: Placements listed for a learned policy to choose from (the candidate-mode VLM, ``irbpp``):
#: more than the proposer's own K because a student can only reach its teacher's pick when it
#: is listed; why 16 (measured on generated training cases): docs/candidates.md. Index 0, the
#: proposer's own pick, does not depend on K.
STUDENT_K = 16


@dataclass(frozen=True, slots=True)
class ProposerConfig:
    """How many placements to list (``k``) and the round order (``rule``, module docstring).

    The defaults keep the most of the teachers in closed loop for the fewest tokens
    (docs/candidates.md: K = 16 and ``"lowest+largest"`` list more of their actions, not better
    ones).
    """

    k: int = DEFAULT_K
    rule: ProposerRule = "lowest"

    def __post_init__(self) -> None:
        if isinstance(self.k, bool) or not isinstance(self.k, int) or self.k < 1:
            raise ValueError(f"ProposerConfig.k = {self.k!r}: must be a whole number >= 1")
        require_choice(self.rule, ProposerRule, "ProposerConfig.rule")


@dataclass(frozen=True, slots=True)
class Candidate:
    """One listed placement and the geometry a prompt can show for it (all integers)."""

    index: int  # place in the list: the answer that picks it
    object_index: int  # into the shown buffer
    rotation: int  # 0 or 1 (1 swaps l and w)
    x: int  # footprint's minimum cell
    y: int
    fx: int  # footprint cells along x at this rotation
    fy: int  # footprint cells along y
    z_mm: int  # resting height, Eq. 2
    top_mm: int  # z + box height
    support_pct: int  # share of the footprint's cells at height z (what it rests on), 0-100
    flush_pct: int  # share of its side cells against a wall or a column above z, 0-100
    void_mm: int  # mean empty height between the surface and the box's underside

    @property
    def action(self) -> Action:
        return Action(object_id=self.object_index, rotation=self.rotation, x=self.x, y=self.y)


@dataclass(frozen=True, slots=True)
class _Shape:
    """One proposed (object, rotation): its ranked pool positions (flat candidate indices) and
    the flushness of each of them."""

    group: Orientation
    ranked: np.ndarray  # (m,) flat indices into the CandidateSet, best first, m <= k
    flush: np.ndarray  # (m,) side cells of each ranked position against a wall or a taller column


def _distinct_groups(cands: CandidateSet) -> list[Orientation]:
    """The groups of step 2, in scan order: one per distinct (fx, fy, h) footprint shape."""
    by_id = sorted(
        cands.groups, key=lambda g: (int(cands.shown_id_order[g.object_index]), g.rotation)
    )
    kept: dict[tuple[int, int, int], Orientation] = {}
    for g in by_id:
        kept.setdefault((g.fx, g.fy, g.height_mm), g)
    return sorted(kept.values(), key=lambda g: g.offset)


def _shape(
    cands: CandidateSet, g: Orientation, in_pool: np.ndarray, walls: np.ndarray, k: int
) -> _Shape | None:
    """Step 3 for one group: its best ``k`` pool positions; None when none is in the pool.

    ``walls`` is the heightmap inside a ring of walls at the rim's height
    (:func:`~packlab.policies.features.walled`).
    """
    pool = in_pool[g.offset : g.offset + g.size].reshape(g.z.shape)
    if not pool.any():
        return None
    # Only pool positions no higher than the k-th lowest can be among the best k (at least k
    # lie at or below it), so flushness, the costly part, is taken over their bounding
    # rectangle alone: the same ranking as over the whole grid.
    low = g.z[pool]
    cut = low.max() if low.size <= k else np.partition(low, k - 1)[k - 1]
    wanted = pool & (g.z <= cut)
    xs, ys = np.nonzero(wanted)
    box = (slice(int(xs.min()), int(xs.max()) + 1), slice(int(ys.min()), int(ys.max()) + 1))
    z, keep = g.z[box], wanted[box]
    # Positions not wanted are dropped below whatever their flushness; reading them at ``cut``
    # adds no height for flush_grid to go through.
    z_read = np.where(keep, z, cut)
    flush = flush_grid(walls, g.fx, g.fy, z_read, origin=(box[0].start, box[1].start)).ravel()
    flat = (g.offset + np.arange(g.size).reshape(g.z.shape)[box]).ravel()
    # Row-major grids list x then y, so the flat index breaks the last ties by x, then y.
    order = np.lexsort((flat, -flush, z.ravel()))
    best = order[keep.ravel()[order]][:k]
    return _Shape(g, flat[best], flush[best])


def _round_keys(cands: CandidateSet, shapes: list[_Shape], r: int, by_volume: bool) -> list[int]:
    """Shape positions in round ``r`` (indices into ``shapes``), in the round's order."""
    members = [s for s in range(len(shapes)) if r < shapes[s].ranked.size]

    def key(s: int) -> tuple[int, ...]:
        shape = shapes[s]
        i = int(shape.ranked[r])
        g = shape.group
        volume = g.fx * g.fy * g.height_mm
        low = (int(cands.z[i]), -_percent(int(shape.flush[r]), side_cells(g.fx, g.fy)))
        return (-volume, *low, s) if by_volume else (*low, -volume, s)

    return sorted(members, key=key)


def _select(cands: CandidateSet, shapes: list[_Shape], config: ProposerConfig) -> list[int]:
    """Step 4: (shape, round) picks as flat candidate indices, in listing order."""
    orders = [False, True] if config.rule == "lowest+largest" else [False]
    streams: list[list[int]] = [[] for _ in orders]
    rounds = max((s.ranked.size for s in shapes), default=0)
    for j, by_volume in enumerate(orders):
        for r in range(rounds):
            if len(streams[j]) >= config.k:
                break
            order = _round_keys(cands, shapes, r, by_volume)
            streams[j] += [int(shapes[s].ranked[r]) for s in order]
    out: list[int] = []
    for r in range(config.k):  # the streams in turn, each placement once
        for stream in streams:
            if r < len(stream) and stream[r] not in out:
                out.append(stream[r])
    return out[: config.k]


def _percent(part: int, whole: int) -> int:
    return round(100 * part / whole)


def _candidate(cands: CandidateSet, g: Orientation, flush: int, i: int, index: int) -> Candidate:
    """Listed placement ``index`` of flat candidate ``i`` of group ``g`` (``flush``: its side
    cells against a wall or a taller column)."""
    x, y = int(cands.x[i]), int(cands.y[i])
    z = int(cands.z[i])
    area = g.fx * g.fy
    # Only listed placements need these, so they are read off the heightmap one by one.
    hm = cands.heightmap
    return Candidate(
        index=index,
        object_index=g.object_index,
        rotation=g.rotation,
        x=x,
        y=y,
        fx=g.fx,
        fy=g.fy,
        z_mm=z,
        top_mm=int(cands.top[i]),
        support_pct=_percent(support_cells_at(hm, x, y, g.fx, g.fy, z), area),
        flush_pct=_percent(flush, side_cells(g.fx, g.fy)),
        void_mm=round(space_under_at(hm, x, y, g.fx, g.fy, z) / area),
    )


def propose_from(
    cands: CandidateSet, config: ProposerConfig = ProposerConfig()
) -> tuple[Candidate, ...]:
    """The listed placements of a candidate set (module docstring); empty when nothing fits."""
    shapes = _shapes(cands, config)
    owner = {int(i): (s.group, int(f)) for s in shapes for i, f in zip(s.ranked, s.flush)}
    picks = _select(cands, shapes, config)
    return tuple(_candidate(cands, *owner[i], i, n) for n, i in enumerate(picks))


def proposed_indices(cands: CandidateSet, config: ProposerConfig = ProposerConfig()) -> list[int]:
    """The listed placements as flat indices into ``cands``, in list order (what
    :func:`propose_from` lists, without the geometry a prompt shows)."""
    return _select(cands, _shapes(cands, config), config)


def _shapes(cands: CandidateSet, config: ProposerConfig) -> list[_Shape]:
    """Steps 1-3 of the module docstring: each distinct (object, rotation)'s ranked positions."""
    pool = rim_pool(cands)
    in_pool = np.zeros(len(cands), dtype=bool)
    in_pool[pool] = True
    walls = walled(cands.heightmap, cands.container_height_mm)
    shapes = []
    for g in _distinct_groups(cands):
        shape = _shape(cands, g, in_pool, walls, config.k)
        if shape is not None:
            shapes.append(shape)
    return shapes


def _group_at(
    cands: CandidateSet, obj: int, rotation: int, x: int, y: int
) -> tuple[Orientation, int] | None:
    """The group of (object, rotation) and the flat index of its placement at (x, y); None when
    the candidate search has no such placement."""
    for g in cands.groups:
        if (g.object_index, g.rotation) != (obj, rotation):
            continue
        nx, ny = g.z.shape  # minimum cells whose footprint fits the floor
        if not (0 <= x < nx and 0 <= y < ny):
            return None
        return g, int(g.offset + x * ny + y)
    return None


def placement_index(cands: CandidateSet, obj: int, rotation: int, x: int, y: int) -> int | None:
    """The flat index in ``cands`` of placement (object, rotation, x, y); None when the set has
    no such placement (the box fits nowhere at that rotation or the cell is out of range)."""
    found = _group_at(cands, obj, rotation, x, y)
    return None if found is None else found[1]


def candidate_for(cands: CandidateSet, action: Action, index: int) -> Candidate | None:
    """``action`` as a listed placement numbered ``index`` (the geometry a listed line shows),
    or None when it is not a floor-fitting placement of the candidate search. Used to list a
    teacher's own pick that the proposer did not list, so a student can be shown it."""
    found = _group_at(cands, action.object_id, action.rotation, action.x, action.y)
    if found is None:
        return None
    g, i = found
    walls = walled(cands.heightmap, cands.container_height_mm)
    flush = flush_cells_at(walls, action.x, action.y, g.fx, g.fy, int(cands.z[i]))
    return _candidate(cands, g, flush, i, index)


def propose(
    observation: Observation, config: ProposerConfig = ProposerConfig()
) -> tuple[Candidate, ...]:
    """The listed placements for an observation (module docstring); empty when nothing fits."""
    return propose_from(observation_candidates(observation), config)


class ProposerPolicy:
    """``proposer``: always the proposer's own pick (index 0 of its list), the floor a
    candidate-mode model starts from; SDF-Pack's action when nothing is listed."""

    name = "proposer"

    def __init__(
        self, k: int = DEFAULT_K, rule: str = "lowest", overflow: OverflowRule = "score"
    ) -> None:
        """``overflow``: what it does where no shown box fits under the rim or the last box
        would raise the top (as the students it is the floor of:
        :mod:`packlab.policies.overflow`, default ``score``)."""
        self.config = ProposerConfig(k=k, rule=rule)  # type: ignore[arg-type]
        require_choice(overflow, OverflowRule, "policy-arg proposer:overflow")
        self.overflow = overflow

    def reset(self, start: EpisodeStart, seed: int) -> None:
        self._fallback = make_sdf()
        self._fallback.reset(start, seed)

    def act(self, observation: Observation) -> Action:
        cands = observation_candidates(observation)
        overflowed = overflow_decision(observation, cands, self.overflow)
        if overflowed is not None:
            return overflowed
        listed = propose_from(cands, self.config)
        return listed[0].action if listed else self._fallback.act(observation)


def make_proposer(**kwargs: object) -> ProposerPolicy:
    return ProposerPolicy(**kwargs)  # type: ignore[arg-type]
