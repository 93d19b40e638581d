"""The agents' one decision rule (pure, torch-free): from the network's row logits to an action.

Every way an agent plays goes through :func:`decide`: the bench policies under either runtime
(ONNX Runtime or torch), the trainer's held-out evaluation and the export check, so the runtimes
can only differ in the logits they compute, never in what is done with them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from packlab.core.types import Action
from packlab.rl.features import Encoded

#: What is done when nothing can be chosen: shown object 0 at the origin, which is out of
#: bounds exactly when the object fits nowhere (the episode records it invalid, sets it aside).
SET_ASIDE = Action(object_id=0, rotation=0, x=0, y=0)

#: The network's raw logits of one encoded observation: ``arrays`` as
#: :func:`packlab.rl.features.encode` makes them (no batch axis) -> (N,) float, one per item row.
RowLogits = Callable[[dict[str, np.ndarray]], np.ndarray]


def pick_row(logits: np.ndarray, mask: np.ndarray) -> int:
    """The greedy row: the highest logit among the rows ``mask`` allows, the first on a tie
    (MaskablePPO's deterministic choice: masked rows can never win)."""
    logits = np.asarray(logits, dtype=np.float64).reshape(-1)
    mask = np.asarray(mask, dtype=bool).reshape(-1)
    if logits.shape != mask.shape:
        raise ValueError(f"logits {logits.shape} and mask {mask.shape} differ in rows")
    if not mask.any():
        raise ValueError("no row to choose: every row is masked")
    return int(np.argmax(np.where(mask, logits, -np.inf)))


def decide(encoded: Encoded, row_logits: RowLogits) -> Action:
    """The packing action the agent takes greedily for ``encoded``; the box is set aside when
    nothing is listed (the network is not asked then)."""
    if not encoded.actions:
        return SET_ASIDE
    return encoded.actions[pick_row(row_logits(encoded.arrays), encoded.mask)]


def ranked_rows(encoded: Encoded, row_logits: RowLogits) -> list[int]:
    """The rows ``encoded.mask`` allows, highest logit first (ties to the earlier row, as
    :func:`pick_row` breaks them): the agent's own preference order, so its first is the row
    :func:`decide` takes. Empty when nothing is listed (the network is not asked then)."""
    if not encoded.actions:
        return []
    n = len(encoded.actions)
    logits = np.asarray(row_logits(encoded.arrays), dtype=np.float64).reshape(-1)[:n]
    allowed = np.asarray(encoded.mask, dtype=bool).reshape(-1)[:n]
    order = np.argsort(-logits, kind="stable")
    return [int(r) for r in order if allowed[r]]
