"""How far settled boxes still move: shared by the settle tests."""

from __future__ import annotations

import mujoco
import numpy as np

from packlab.sim.physics.mujoco_backend import MujocoBackend


def movement_mm(backend: MujocoBackend, steps: int) -> float:
    """Largest distance (mm) any placed box's centre travels when the simulation runs on."""
    before, _ = backend.poses()
    for _ in range(steps):
        mujoco.mj_step(backend._model, backend._data)
    after, _ = backend.poses()
    placed = ~np.isnan(before[:, 0])
    return float(np.linalg.norm(after[placed] - before[placed], axis=1).max())
