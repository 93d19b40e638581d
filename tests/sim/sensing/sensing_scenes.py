"""A packed scene shared by the sensing tests: a small layered case placed by its perfect plan."""

from __future__ import annotations

from layered_cases import make_layered_case

from packlab.core.types import Case
from packlab.sim.physics.geometric import GeometricBackend


def packed_layered_case(seed: int) -> tuple[Case, GeometricBackend]:
    """(case, geometric backend holding every box where the case's plan puts it)."""
    case = make_layered_case(seed, cells=(16, 12), pieces=5)
    backend = GeometricBackend()
    backend.reset(case.container, case.objects)
    ids = [b.internal_id for b in case.objects]
    for step in case.gt_plan:
        backend.place(
            ids.index(step.internal_id),
            step.rotation,
            (step.x * 25, step.y * 25, step.cell_min[2] * 2),
        )
    return case, backend
