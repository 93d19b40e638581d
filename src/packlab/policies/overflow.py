"""What to do when no shown box fits under the rim: place one sticking out, or set one aside.

The shared rim rule (:func:`packlab.policies.heuristics.select.rim_pool`) places the box that
sticks out least when no placement stays within the rim. The metric (DESIGN.md section 5)
punishes that twice: a box counts as packed only when its settled centre is inside the
container, and compactness divides by the final heightmap's highest cell, which a box sticking
out raises whether it counts or not. With every box's volume fixed, Overall = SR x compactness
is proportional to V**2 / H (V: the volume packed inside, H: the highest cell), so

* placing a box whose centre stays inside turns (V, H) into (V + v, max(H, top));
* placing one whose centre rises above the rim turns it into (V, max(H, top)): never better;
* setting a box aside leaves (V, H) as it is.

Rule ``score`` (:data:`packlab.core.choices.OverflowRule`) takes, among the candidates (all of
them over the rim), the placement with the largest (V + v)**2 / max(H, top) and places it when
that beats V**2 / H; otherwise it sets a box aside (:meth:`Action.set_aside`). A box that fits
nowhere under the rim now never will (the heightmap only rises), so waiting cannot save it.

V and H are the policy's own estimates: H is the highest cell of the heightmap it sees, V the
volume of the boxes it placed this episode whose centre (Eq. 2 height on the heightmap it saw
then, plus half the box's height) stayed within the rim, from the sizes it was shown. The rule
is greedy: boxes still to come add to V whichever way this box goes, and are not counted.

**The last box.** The same comparison is exact, not greedy, for the episode's last box
(``remaining`` is 1: nothing comes after it), so rule ``score`` also decides it whenever every
placement of it raises the highest cell: a box that does not fit into the layer below is stacked
only where the volume it adds outweighs the height (a last box of an eighth of the volume
stacked on one closed layer halves compactness, Overall 0.5, set aside 0.77). Where a placement
keeps the highest cell, the policy decides as before. Nothing is known of the order's length when
the run hides ``remaining``, and the rule then stays out.

Under the online protocol the arriving box must be placed, so the rule is never asked there.
"""

from __future__ import annotations

import numpy as np

from packlab.core.choices import OverflowRule
from packlab.core.feasibility import CandidateSet, footprint_cells, placement_height
from packlab.core.types import Action, Observation


def overflowing(cands: CandidateSet) -> bool:
    """Whether no candidate's top stays within the rim (so also when there is no candidate)."""
    return not bool(cands.fits_in_rim.any())


def overflow_decision(
    observation: Observation, cands: CandidateSet, rule: OverflowRule
) -> Action | None:
    """The action rule ``score`` takes where it applies (the buffer protocol, no candidate under
    the rim, or the last box raising the top), else None: the policy decides as it would
    without the rule. Every policy with an ``overflow`` option asks this, with the candidate
    set it computes anyway."""
    if rule != "score" or observation.must_place_first:
        return None
    if overflowing(cands) or last_box_raises_top(observation, cands):
        return overflow_action(observation, cands)
    return None


def last_box_raises_top(observation: Observation, cands: CandidateSet) -> bool:
    """Whether the box shown is the episode's last (``remaining`` known and 1) and every
    placement of it would raise the highest cell of the heightmap (module docstring)."""
    if observation.remaining != 1 or len(cands) == 0:
        return False
    height_now = int(np.asarray(observation.heightmap).max())
    return bool((cands.top > height_now).all())


def packed_inside_volume(observation: Observation) -> int:
    """V above (mm^3): the boxes this episode placed whose centre stayed within the rim, by the
    observation's own history (shown sizes, Eq. 2 heights on the heightmaps seen then)."""
    rim = observation.container.height_mm
    volume = 0
    for entry in observation.history:
        action = entry.action
        if not entry.valid or not isinstance(action, Action):
            continue
        item = entry.shown[action.object_id]
        fx, fy = footprint_cells(item, action.rotation)
        z = placement_height(np.asarray(entry.heightmap), action.x, action.y, fx, fy)
        length, width, height = item.size_mm
        if 2 * z + height <= 2 * rim:
            volume += length * width * height
    return volume


def overflow_action(observation: Observation, cands: CandidateSet) -> Action:
    """Rule ``score`` (module docstring) for a step where :func:`overflowing` or
    :func:`last_box_raises_top` holds."""
    if len(cands) == 0:  # nothing fits the floor at all: the box cannot be placed
        return Action.set_aside(0)
    rim = observation.container.height_mm
    height_now = max(int(np.asarray(observation.heightmap).max()), 1)
    volume_now = float(packed_inside_volume(observation))
    inside = 2 * cands.z + cands.h <= 2 * rim
    box_volume = np.prod(cands.shown_sizes_mm[cands.obj], axis=1).astype(np.float64)
    after = (volume_now + box_volume * inside) ** 2 / np.maximum(height_now, cands.top)
    best = int(np.argmax(after))  # first of equals: scan order
    if after[best] > volume_now**2 / height_now:
        return Action(
            int(cands.obj[best]), int(cands.rotation[best]), int(cands.x[best]), int(cands.y[best])
        )
    # No box is worth placing. Set aside the one that would stick out most: all are lost to
    # this container, and a box arriving next may still fit.
    # (A shown box with no candidate at all fits nowhere: it goes first.)
    lowest_top = np.full(cands.buffer_size, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(lowest_top, cands.obj, cands.top)
    return Action.set_aside(int(np.argmax(lowest_top)))
