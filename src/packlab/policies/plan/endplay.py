"""The last boxes played out: the planner's own play as the base of a rollout (pure).

When every box still to come is in view (``remaining`` equals the shown count), the end of the
episode is computable under the planner's model (the geometric backend's: a box rests at Eq. 2's
height on the heightmap). Overall is then proportional to V**2 / H (V the volume packed inside,
H the highest cell; :mod:`packlab.policies.overflow`). The planner's action is one way to go on;
a few others (:func:`beam_firsts`) may end higher. Each candidate first action is followed by
the planner's own play to the end (:func:`played_value`), and the one that ends highest is
taken, ties to the planner's action. That is policy improvement by rollout with the planner as
the base policy: on the geometric backend, where the model is exact, the episode cannot end
lower than the planner alone would end it, since at the next step the planner's own action
continues the play that was just scored.

Why the planner and not a cheaper player: the planner's endgame, completion and finale close
the last boxes better than any greedy play, so a first action judged by a weaker continuation
is judged wrongly (a beam of greedy continuations, tried first, overrode the planner where its
own play would have ended higher; docs/history/planner.md, "The endplay").

The other first actions come from a small beam over the shown boxes' placements and set-asides
(:func:`beam_firsts`): partial plays ranked by the lookahead's own state cost
(:func:`.evaluate.state_cost`, with every box still to come known), complete plays by V**2 / H.
Every state a played continuation passes through is remembered with its final value
(:class:`Endplay`), so the planner's action at the next step, which continues a play already
scored, costs nothing to score again.

It stays out when the run hides ``remaining``, under the online protocol (the arriving box must
be placed), with ``overflow=place`` (the planner never sets a box aside then) and while more
than ``max_boxes`` boxes are in view.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.feasibility import (
    ROTATIONS,
    footprint_cells,
    footprint_fits,
    placement_height,
    search_candidates,
)
from packlab.core.types import Action, HistoryEntry, Observation, ShownItem
from packlab.policies.heuristics import sdf
from packlab.policies.overflow import packed_inside_volume
from packlab.policies.plan.evaluate import PathLoss, Weights, state_cost
from packlab.policies.plan.finale import end_ratio, everything_in_view
from packlab.policies.plan.outlook import Outlook, cell_volume
from packlab.policies.plan.surface import water_level
from packlab.sim.heightmap import place_box

#: A base player: the planner's action for an observation (a fresh copy of the planner per play).
BasePlayer = Callable[[Observation], Action]


@dataclass(frozen=True, slots=True)
class EndplayConfig:
    """``alternatives``: first actions tried besides the planner's (0 turns the rule off);
    ``max_boxes``: the most boxes in view for which it decides; ``beam``: the width of the beam
    that proposes them; ``picks``: placements per distinct box shape and ranking in the beam."""

    alternatives: int = 3
    max_boxes: int = 10
    beam: int = 8
    picks: int = 2

    def __post_init__(self) -> None:
        for name in ("alternatives", "max_boxes", "beam", "picks"):
            value = getattr(self, name)
            least = 0 if name == "alternatives" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ConfigError(
                    f"plan: endplay {name} = {value!r}: must be a whole number >= {least}"
                )


@dataclass(frozen=True, slots=True)
class Step:
    """One action under the geometric model: the next observation, the volume it packed inside
    the rim (mm^3) and the top it reached (mm; 0 for a set-aside or an action that fits nowhere)."""

    observation: Observation
    packed: float
    top: int


def step(observation: Observation, action: Action) -> Step:
    """``action`` taken on ``observation`` under the geometric model: the box rests at Eq. 2's
    height (or is set aside: an out-of-bounds action sets it aside, as an episode does), leaves
    the buffer, and nothing new arrives (every box still to come is in view)."""
    shown = list(observation.shown)
    rim = observation.container.height_mm
    heightmap = np.asarray(observation.heightmap)
    after, packed, top = heightmap, 0.0, 0
    in_buffer = 0 <= action.object_id < len(shown)
    index = action.object_id if in_buffer else 0
    placed = in_buffer and not action.sets_aside
    if placed and action.rotation in ROTATIONS:
        item = shown[index]
        x, y = action.x, action.y
        fx, fy = footprint_cells(item, action.rotation)
        if fx >= 1 and fy >= 1 and footprint_fits(heightmap.shape, x, y, fx, fy):
            z = placement_height(heightmap, x, y, fx, fy)  # Eq. 2
            top = z + int(item.size_mm[2])
            after = place_box(heightmap, x, y, fx, fy, top)
            # Packed when the box's centre stays under the rim (the metric's rule).
            if 2 * z + int(item.size_mm[2]) <= 2 * rim:
                packed = float(np.prod(item.size_mm))
    rest = shown[:index] + shown[index + 1 :]
    entry = HistoryEntry(observation.heightmap, observation.shown, action, top > 0)
    remaining = None if observation.remaining is None else observation.remaining - 1
    following = dataclasses.replace(
        observation,
        step_index=observation.step_index + 1,
        heightmap=after.astype(heightmap.dtype),
        shown=tuple(dataclasses.replace(s, shown_index=k) for k, s in enumerate(rest)),
        remaining=remaining,
        history=(*observation.history, entry),
    )
    return Step(following, packed, top)


def _state_key(observation: Observation, volume: float, height: int) -> tuple[object, ...]:
    heightmap = np.asarray(observation.heightmap)
    sizes = tuple(sorted(tuple(s.size_mm) for s in observation.shown))
    return (heightmap.shape, heightmap.tobytes(), sizes, volume, height)


def played_value(
    observation: Observation,
    first: Action,
    player: BasePlayer,
    memo: dict[tuple[object, ...], float],
) -> float:
    """V**2 / H at the end of ``first`` followed by ``player``'s play of every other box
    (geometric model); every state on the way is remembered in ``memo`` with that value."""
    volume = float(packed_inside_volume(observation))
    height = max(int(np.asarray(observation.heightmap).max()), 1)
    current, action = observation, first
    path: list[tuple[object, ...]] = []
    value: float | None = None
    while True:
        moved = step(current, action)
        current = moved.observation
        volume += moved.packed
        height = max(height, moved.top)
        if not current.shown:
            break
        key = _state_key(current, volume, height)
        if key in memo:
            value = memo[key]
            break
        path.append(key)
        action = player(current)
    if value is None:
        value = end_ratio(volume, height)
    for key in path:
        memo[key] = value
    return value


@dataclass
class _Partial:
    """A play in the beam: the heightmap, V, H, the shown boxes left (indices into the root's
    shown), the first action and what the path lost (the cost's path terms)."""

    heightmap: np.ndarray
    volume: float
    height: int
    left: tuple[int, ...]
    first: Action | None
    path: PathLoss
    cost: float = 0.0


def _shape(item: ShownItem) -> tuple[int, int, int]:
    a, b, h = item.size_mm
    return (min(a, b), max(a, b), h)


def _successors(
    node: _Partial, shown: list[ShownItem], rim: int, cell: int, picks: int
) -> list[_Partial]:
    """Set-asides (one per distinct shape) and, per distinct shape, the ``picks`` best
    placements by SDF-Pack's keys and by the lowest top."""
    out: list[_Partial] = []
    firsts: dict[tuple[int, int, int], int] = {}
    for j, i in enumerate(node.left):
        firsts.setdefault(_shape(shown[i]), j)
    for j in firsts.values():
        left = node.left[:j] + node.left[j + 1 :]
        first = node.first or Action.set_aside(node.left[j])
        out.append(_Partial(node.heightmap, node.volume, node.height, left, first, node.path))
    items = [shown[i] for i in node.left]
    cands = search_candidates(node.heightmap, items, rim, cell)
    if len(cands) == 0:
        return out
    sdf_keys = sdf.score(cands)
    chosen: set[int] = set()
    for o in firsts.values():
        rows = np.flatnonzero(cands.obj == o)
        if rows.size == 0:
            continue
        rankings = (
            tuple(np.asarray(k)[rows] for k in sdf_keys),
            (cands.top[rows], cands.z[rows], cands.x[rows], cands.y[rows]),
        )
        for keys in rankings:
            order = np.lexsort(tuple(reversed(keys)))
            chosen.update(int(rows[t]) for t in order[:picks])
    for i in sorted(chosen):
        o = int(cands.obj[i])
        x, y, fx, fy = (int(a[i]) for a in (cands.x, cands.y, cands.fx, cands.fy))
        z, top = int(cands.z[i]), int(cands.top[i])
        trapped = int((z - node.heightmap[x : x + fx, y : y + fy]).sum())
        over_rim = max(0, top - rim) * fx * fy
        packed = float(np.prod(items[o].size_mm)) if 2 * z + int(cands.h[i]) <= 2 * rim else 0.0
        first = node.first or Action(node.left[o], int(cands.rotation[i]), x, y)
        out.append(
            _Partial(
                place_box(node.heightmap, x, y, fx, fy, top),
                node.volume + packed,
                max(node.height, top),
                node.left[:o] + node.left[o + 1 :],
                first,
                node.path.plus(trapped, over_rim),
            )
        )
    return out


def beam_firsts(observation: Observation, config: EndplayConfig) -> list[Action]:
    """First actions by the best end a beam of plays reaches from them (best first)."""
    shown = list(observation.shown)
    rim = observation.container.height_mm
    cell = observation.container.cell_xy_mm
    cell_area = cell * cell
    heightmap = np.asarray(observation.heightmap).astype(np.int64)
    start = float(packed_inside_volume(observation))
    total = int(start // cell_area) + sum(cell_volume(s) for s in shown)
    weights = Weights()
    best: dict[Action, float] = {}

    def finish(node: _Partial, value: float) -> None:
        if node.first is not None and value > best.get(node.first, -1.0):
            best[node.first] = value

    everything = tuple(range(len(shown)))
    height = max(int(heightmap.max()), 1)
    frontier = [_Partial(heightmap, start, height, everything, None, PathLoss())]
    while frontier:
        children: list[_Partial] = []
        for node in frontier:
            for child in _successors(node, shown, rim, cell, config.picks):
                if child.left:
                    children.append(child)
                else:
                    finish(child, end_ratio(child.volume, child.height))
            finish(node, end_ratio(node.volume, node.height))  # or the rest set aside here
        for child in children:
            footprints: set[tuple[int, int]] = set()
            for i in child.left:
                a, b = shown[i].size_cells[:2]
                footprints.update({(a, b), (b, a)})
            to_come = sum(cell_volume(shown[i]) for i in child.left)
            outlook = Outlook(int(child.volume // cell_area), to_come, total, rim)
            child.cost = state_cost(
                child.heightmap, child.path, tuple(sorted(footprints)), weights, outlook
            )
        children.sort(key=lambda c: c.cost)
        frontier = children[: config.beam]
    return sorted(best, key=lambda a: -best[a])


def best_end_bound(observation: Observation) -> float:
    """An upper bound of V**2 / H at the episode's end: every box in view packed, the top at
    least the highest cell now and at least the level their volume reaches poured over the
    lowest cells (the heightmap only rises, by at least the volume packed). V**2 / max(H_now,
    level) grows with the volume packed, so packing all of it bounds every play."""
    heightmap = np.asarray(observation.heightmap).astype(np.int64)
    cell_area = observation.container.cell_xy_mm**2
    to_come = sum(cell_volume(s) for s in observation.shown)
    volume = float(packed_inside_volume(observation)) + to_come * cell_area
    level = max(float(heightmap.max()), water_level(heightmap, to_come), 1.0)
    return volume * volume / level


@dataclass
class Endplay:
    """The rule with its memory of scored states (reset per episode)."""

    config: EndplayConfig = field(default_factory=EndplayConfig)
    _memo: dict[tuple[object, ...], float] = field(default_factory=dict, repr=False)

    def reset(self) -> None:
        self._memo = {}

    def applies(self, observation: Observation) -> bool:
        return (
            self.config.alternatives > 0
            and everything_in_view(observation)
            and 2 <= len(observation.shown) <= self.config.max_boxes
        )

    def decide(
        self, observation: Observation, planned: Action, player: Callable[[], BasePlayer]
    ) -> Action:
        """``planned`` (the planner's action) or a first action whose play ends strictly higher;
        ``player()`` gives a fresh base player for each play (the planner keeps state)."""
        if not self.applies(observation):
            return planned

        def lazily() -> BasePlayer:
            # A copy of the planner costs a deep copy; a play answered from the memo needs none.
            made: list[BasePlayer] = []

            def play(state: Observation) -> Action:
                if not made:
                    made.append(player())
                return made[0](state)

            return play

        best, best_value = planned, played_value(observation, planned, lazily(), self._memo)
        if best_value * (1 + 1e-9) >= best_end_bound(observation):
            return planned  # nothing can end strictly higher: the search would change nothing
        others = [a for a in beam_firsts(observation, self.config) if a != planned]
        for action in others[: self.config.alternatives]:
            value = played_value(observation, action, lazily(), self._memo)
            if value > best_value * (1 + 1e-9):
                best, best_value = action, value
        return best
