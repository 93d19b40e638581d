"""The scene a camera sees when a case is packed by its perfect plan (for figures and timings)."""

from __future__ import annotations

import numpy as np

from packlab.core.types import Case
from packlab.metrics import planned_centres_mm
from packlab.sim.heightmap import yaw_quaternion


def planned_scene(case: Case) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sizes (n, 3) mm, centres (n, 3) mm, quaternions (n, 4) wxyz) of every box where the
    case's perfect plan puts it, in the backends' ``poses()`` layout; NaN rows for boxes the plan
    does not place."""
    sizes = np.array([b.size_mm for b in case.objects], dtype=float)
    positions = np.full((len(sizes), 3), np.nan)
    quats = np.full((len(sizes), 4), np.nan)
    index = {b.internal_id: i for i, b in enumerate(case.objects)}
    centres = planned_centres_mm(case) if case.gt_plan is not None else {}
    for step in case.gt_plan or ():
        i = index[step.internal_id]
        positions[i] = centres[step.internal_id]
        quats[i] = yaw_quaternion(step.rotation)
    return sizes, positions, quats
