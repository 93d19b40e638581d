"""Pure packing metrics (DESIGN.md section 5): Success Ratio, Compactness, Overall.

All are judged on *final* poses: a box knocked outside late in an episode does not count.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from packlab.core.types import Case, Container, InternalId, Pose

#: The three metrics of every summary, in table order.
METRICS = ("success_ratio", "compactness", "overall")
#: The field's metric: packed volume over container volume, reported beside the three
#: above (its own table section; ``packlab.bench.summary``).
UTILIZATION = "space_utilization"
#: The summary group holding the mean over difficulty levels (the paper's "Average" column).
AVERAGE = "average"

#: A settled centre may stray this far outside the interior and still count as inside (mm).
INSIDE_TOLERANCE_MM = 1.0


def box_inside(
    position_mm: Sequence[float] | None, container: Container, tol_mm: float = INSIDE_TOLERANCE_MM
) -> bool:
    """True when a box's settled centre lies within the closed container interior (+ tolerance).

    ``None`` (a box set aside, never placed) is outside. The interior includes the space up to
    the rim height, so a box whose centre rises above the rim is outside.
    """
    if position_mm is None:
        return False
    x, y, z = (float(v) for v in position_mm)
    sx, sy, sz = container.size_mm
    return (
        -tol_mm <= x <= sx + tol_mm and -tol_mm <= y <= sy + tol_mm and -tol_mm <= z <= sz + tol_mm
    )


def inside_mask(
    positions_mm: np.ndarray, container: Container, tol_mm: float = INSIDE_TOLERANCE_MM
) -> np.ndarray:
    """``box_inside`` over many boxes at once: (n,) bool from centres (n, 3) float mm.

    NaN rows (boxes set aside or not yet placed) are outside, as ``None`` is for ``box_inside``.
    """
    centres = np.asarray(positions_mm, dtype=np.float64).reshape(-1, 3)
    upper = np.asarray(container.size_mm, dtype=np.float64) + tol_mm
    mask: np.ndarray = np.all((centres >= -tol_mm) & (centres <= upper), axis=1)
    return mask


def space_utilization(inside_volume_mm3: float, container: Container) -> float:
    """Packed volume over the container's volume (X * Y * Z), the online field's metric.

    "Packed" is the volume of the boxes inside (:func:`box_inside`, as for the Success Ratio)
    when the episode ended: under the online protocol at the first box that fits nowhere, so
    nothing after it counts; under the buffer protocol after every box was processed.
    """
    x, y, z = container.size_mm
    return float(inside_volume_mm3) / (float(x) * float(y) * float(z))


def success_ratio(inside_volume_mm3: float, total_volume_mm3: float) -> float:
    """Volume of inside boxes over the volume of all boxes in the case."""
    if total_volume_mm3 <= 0:
        raise ValueError(f"total volume must be positive, got {total_volume_mm3}")
    return float(inside_volume_mm3) / float(total_volume_mm3)


def compactness(inside_volume_mm3: float, container: Container, max_height_mm: float) -> float:
    """Inside volume over X * Y * H with H the max final heightmap; 0 when nothing is inside."""
    if inside_volume_mm3 <= 0 or max_height_mm <= 0:
        return 0.0
    x, y, _ = container.size_mm
    return float(inside_volume_mm3) / (float(x) * float(y) * float(max_height_mm))


@dataclass(frozen=True, slots=True)
class EpisodeMetrics:
    """Final scores of one episode plus counters."""

    success_ratio: float
    compactness: float
    overall: float
    inside_volume_mm3: int
    total_volume_mm3: int
    max_height_mm: int
    n_objects: int
    n_inside: int
    n_set_aside: int
    invalid_by_reason: dict[str, int] = field(default_factory=dict)
    settle_steps: int = 0
    #: Placements whose settle hit the per-placement step cap (``settled: false`` steps).
    unsettled_steps: int = 0
    #: Steps of the final settle after the last object (its own, larger cap).
    final_settle_steps: int = 0
    #: Every box was at rest when the episode was scored; False when the final settle hit its cap.
    at_rest: bool = True
    #: Largest linear (m/s) and angular (rad/s) speed of any box when the episode was scored.
    residual_linear_mps: float = 0.0
    residual_angular_radps: float = 0.0
    wall_time_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def score_final_state(
    container: Container,
    volumes_mm3: Sequence[int],
    positions_mm: Sequence[Sequence[float] | None],
    heightmap: np.ndarray,
) -> tuple[float, float, float, int, int, int]:
    """(success ratio, compactness, overall, inside volume, n inside, max height) of final poses.

    ``positions_mm[i]`` is box i's settled centre or None when it was set aside; ``heightmap``
    is the final heightmap over the container (int32 mm).
    """
    inside = [box_inside(p, container) for p in positions_mm]
    inside_volume = int(sum(v for v, ok in zip(volumes_mm3, inside) if ok))
    max_height = int(heightmap.max()) if heightmap.size else 0
    sr = success_ratio(inside_volume, sum(volumes_mm3))
    comp = compactness(inside_volume, container, max_height)
    return sr, comp, sr * comp, inside_volume, sum(inside), max_height


def planned_centres_mm(case: Case) -> dict[InternalId, tuple[float, float, float]]:
    """Centre (mm) of every object in the case's perfect layout, by internal id."""
    if case.gt_plan is None:
        raise ValueError(f"case {case.episode_id!r} has no gt_plan")
    cell, cell_z = case.container.cell_xy_mm, case.container.cell_z_mm
    centres: dict[InternalId, tuple[float, float, float]] = {}
    for p in case.gt_plan:
        box = case.box_by_id(p.internal_id)
        fx, fy = box.footprint_mm(p.rotation)
        centres[p.internal_id] = (
            p.x * cell + fx / 2,
            p.y * cell + fy / 2,
            p.cell_min[2] * cell_z + box.size_mm[2] / 2,
        )
    return centres


def plan_drift_mm(case: Case, poses: Mapping[InternalId, Pose | None]) -> float:
    """Largest per-axis distance (mm) between settled centres and the plan; inf if one is missing.

    ``poses`` maps internal id to a ``Pose`` (or None for an object never placed).
    """
    worst = 0.0
    for internal_id, centre in planned_centres_mm(case).items():
        pose = poses.get(internal_id)
        if pose is None:
            return float("inf")
        worst = max(worst, max(abs(a - b) for a, b in zip(pose.position_mm, centre)))
    return worst
