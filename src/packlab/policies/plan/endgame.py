"""Endgame: when every box still to come is in view, pack them all exactly.

A perfect layout's last boxes fill what is left of the container to one flat top. Once the
observation shows every remaining box (``remaining`` equals the shown count, e.g. a buffer as
large as the rest of the sequence, or the last steps of any run), the planner needs no guess: it
searches for a filling of the space above the heightmap with exactly these boxes, in a build
order. The flat top is fixed by the volume (:func:`.skyline.filling_ceiling`): a heightmap that
already hides a gap, or one read with sensor noise, has no whole-millimetre top and the endgame
stands aside. Two searches:

* where the surface is flat (an empty container, a closed layer),
  :func:`.guillotine.guillotine_fill` assembles the boxes into the cuboid above it by merging
  boxes that share a face: fast on guillotine packings of 30 boxes and more (the ``cut``
  family), blind to the others;
* otherwise, or when that found nothing, :func:`.skyline.skyline_fill` places boxes one by one on
  the stepped surface (any perfect packing, up to about 20 boxes within its budget).

A found filling is kept and followed while the world goes as planned: the next decision reuses
it when the heightmap is the one the filling predicted and a shown box has the next box's size.
Anything else (a box settled elsewhere, a run that hides ``remaining``) searches again or leaves
the decision to the rest of the planner.

A skyline search that ends without a filling (not for want of budget) proves there is none, and
none appears later while the boxes only move from the buffer into the container: a box placed
flat plus a filling of what is left after it would be a filling now. So the endgame does not
search again in that episode until the total volume (heightmap plus boxes in view) changes,
which is what a gap left under a box or a box set aside does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from packlab.core.types import Action, Observation
from packlab.policies.plan.guillotine import guillotine_fill
from packlab.policies.plan.skyline import (
    Block,
    Placed,
    SkylineResult,
    filling_ceiling,
    skyline_fill,
)


@dataclass(frozen=True, slots=True)
class EndgameConfig:
    """The searches' budgets; both 0 turns the endgame off."""

    #: Nodes of one skyline search. A filling of a dozen boxes takes tens of nodes; the budget
    #: bounds the searches that fail (about 0.2-0.7 ms per node on one core).
    max_nodes: int = 5_000
    #: At most this many boxes in view for the skyline search: beyond it a failing search costs
    #: its whole budget at every step for little chance (measured on generated cut cases:
    #: fillings of more than about 20 boxes are rarely found within the budget).
    max_boxes: int = 24
    #: Nodes of one guillotine assembly (:mod:`.guillotine`), tried first whenever the surface
    #: is flat (an empty container; a closed layer). About 0.1 ms per node for 30 boxes; on
    #: generated hard cut training cases 123 of 124 packings were found within 50 000 nodes,
    #: most within as many nodes as boxes.
    guillotine_nodes: int = 50_000
    #: At most this many boxes in view for the assembly (a node's cost grows with the square
    #: of the count).
    guillotine_boxes: int = 48


@dataclass
class Endgame:
    """Finds and follows an exact filling of the rest of the container (module docstring)."""

    config: EndgameConfig = field(default_factory=EndgameConfig)
    #: The filling being followed: the boxes not yet placed, in build order.
    _plan: list[Placed] = field(default_factory=list)
    #: The heightmap the filling predicts for the coming decision.
    _expected: np.ndarray | None = None
    #: The total volume (heightmap plus boxes in view, mm x cells) at which a search proved
    #: that no filling exists (None: no such proof this episode).
    _hopeless_volume: int | None = None
    #: Decisions taken from a filling, and searches run.
    decided: int = 0
    searches: int = 0

    def reset(self) -> None:
        """A new episode: forget the filling and any proof that there is none."""
        self._forget()
        self._hopeless_volume = None

    def _forget(self) -> None:
        self._plan, self._expected = [], None

    def act(self, observation: Observation) -> Action | None:
        """The next box of an exact filling of the rest, or None when there is none to follow."""
        shown = observation.shown
        if (
            observation.remaining is None
            or observation.remaining != len(shown)
            or not shown
            or len(shown) > max(self.config.max_boxes, self.config.guillotine_boxes)
        ):
            self._forget()
            return None
        hm = np.asarray(observation.heightmap)
        if not self._following(hm) and not self._search(observation):
            return None
        action = self._next_action(observation)
        if action is None:
            self._forget()
        return action

    def _following(self, hm: np.ndarray) -> bool:
        return bool(
            self._plan
            and self._expected is not None
            and self._expected.shape == hm.shape
            and (self._expected == hm).all()
        )

    def _search(self, observation: Observation) -> bool:
        blocks = [
            Block(s.shown_index, s.size_cells[0], s.size_cells[1], s.size_mm[2])
            for s in observation.shown
        ]
        hm = np.asarray(observation.heightmap)
        ceiling = filling_ceiling(hm, blocks)
        self._forget()
        if ceiling is None or ceiling > observation.container.height_mm:
            return False
        volume = int(hm.sum(dtype=np.int64)) + sum(b.length * b.width * b.height_mm for b in blocks)
        if volume == self._hopeless_volume:  # proved earlier: see the module docstring
            return False
        found = self._fill(hm, blocks, ceiling)
        if found is None or found.placements is None:
            if found is not None and not found.exhausted:
                self._hopeless_volume = volume
            return False
        self._plan = list(found.placements)
        self._expected = hm.astype(np.int32, copy=True)
        return True

    def _fill(self, hm: np.ndarray, blocks: list[Block], ceiling: int) -> SkylineResult | None:
        """A filling by guillotine assembly where the surface is flat, else (or when none was
        found) by the skyline search; None when neither may run. Only the skyline search's
        "none" is a proof: the assembly finds guillotine packings only."""
        cfg = self.config
        flat = bool((hm == hm.flat[0]).all())
        if flat and cfg.guillotine_nodes and len(blocks) <= cfg.guillotine_boxes:
            self.searches += 1
            base = int(hm.flat[0])
            found = guillotine_fill(blocks, hm.shape, ceiling - base, base, cfg.guillotine_nodes)
            if found.placements is not None:
                return found
        if not cfg.max_nodes or len(blocks) > cfg.max_boxes:
            return None
        self.searches += 1
        return skyline_fill(hm, blocks, ceiling, cfg.max_nodes)

    def _next_action(self, observation: Observation) -> Action | None:
        """The filling's next box as an action on a shown box of its size (shown indices change
        from step to step, sizes do not), and the heightmap it leaves."""
        if not self._plan or self._expected is None:
            return None
        step = self._plan[0]
        for s in observation.shown:
            length, width = s.size_cells[0], s.size_cells[1]
            if s.size_mm[2] != step.height_mm:
                continue
            if (length, width) == (step.fx, step.fy):
                rotation = 0
            elif (width, length) == (step.fx, step.fy):
                rotation = 1
            else:
                continue
            self._plan.pop(0)
            self._expected[step.x : step.x + step.fx, step.y : step.y + step.fy] = step.top_mm
            self.decided += 1
            return Action(object_id=s.shown_index, rotation=rotation, x=step.x, y=step.y)
        return None
