"""Execution noise (issue 15): a chosen placement as a robot would really execute it.

The policy chooses a drop (footprint minimum corner in mm, rotation 0/1); a robot puts the box
down with an error: the gripper's xy offset and a yaw error (the arm's repeatability, Gaussian,
zero mean, plus in perceived mode the error of the grasped box's estimated pose) and a release
height above the planned rest height (the gripper opens before contact, so the box falls that
far). The physics decides what happens next, so boxes can land off-plan.

The place skill acts only on what the robot knows: the sides it pushes the box toward
(``seat_sides``) are read from the observed heightmap around the planned footprint, never from
the true scene, and the push stops on contact force (``MujocoBackend._seat``).

Only the mujoco backend executes noisy drops (``MujocoBackend.place`` with ``offset_mm``,
``yaw_deg``, ``release_mm``): the geometric backend places boxes on whole cells and cannot turn
them, so a noisy run on it is refused (``RunConfig`` and ``Episode``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from packlab.core.choices import NoisePreset, require_choice
from packlab.core.errors import ConfigError
from packlab.core.levels import FACE_RISE_MM


@dataclass(frozen=True, slots=True)
class ExecutionNoise:
    """Robot execution noise: standard deviations of Gaussian errors and a release height."""

    xy_sigma_mm: float = 0.0  # per axis, of the box centre in the container plane
    yaw_sigma_deg: float = 0.0  # about z, added to the chosen rotation's 0 or 90 degrees
    release_mm: float = 0.0  # the box is let go this far above its planned rest height
    #: A box that would start inside a neighbour (itself off-plan) slides up to this far aside,
    #: as a compliant wrist lets it (``MujocoBackend._comply``), instead of landing on top.
    comply_mm: float = 0.0
    #: The place skill pushes the box toward the sides its planned pose is flush with on the
    #: observed heightmap (``seat_sides``), a guarded move that stops on contact force, at most
    #: this far past the plan (``MujocoBackend._seat``), so errors do not add up along a row.
    #: 0: the box stays where the noise put it.
    seat_mm: float = 0.0

    def __post_init__(self) -> None:
        for name in ("xy_sigma_mm", "yaw_sigma_deg", "release_mm", "comply_mm", "seat_mm"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ConfigError(f"ExecutionNoise.{name} = {value!r}: must be a number >= 0")

    @property
    def is_zero(self) -> bool:
        return self.xy_sigma_mm == 0 and self.yaw_sigma_deg == 0 and self.release_mm == 0


#: Robot noise by preset (named like the sensor presets, ``packlab.core.choices.NoisePreset``):
#: a careful cell with a structured-light camera (about 1 mm depth noise) estimates grasp poses
#: to a few mm and a degree; a consumer stereo camera (5-10 mm depth noise) to about 5 mm and 3
#: degrees. Release heights are typical suction-gripper drops.
EXECUTION_PRESETS: dict[str, ExecutionNoise] = {
    "none": ExecutionNoise(),
    "structured-light": ExecutionNoise(
        xy_sigma_mm=2.0, yaw_sigma_deg=1.0, release_mm=5.0, comply_mm=10.0, seat_mm=5.0
    ),
    "stereo": ExecutionNoise(
        xy_sigma_mm=5.0, yaw_sigma_deg=3.0, release_mm=10.0, comply_mm=20.0, seat_mm=10.0
    ),
}


def execution_noise(preset: NoisePreset) -> ExecutionNoise:
    """The robot noise of a named preset (ConfigError naming ``noise`` when unknown)."""
    require_choice(preset, NoisePreset, "noise")
    return EXECUTION_PRESETS[preset]


@dataclass(frozen=True, slots=True)
class ExecutedDrop:
    """How a drop is really executed: the planned drop plus these deviations."""

    offset_mm: tuple[float, float]  # xy shift of the box centre from the planned one, mm
    yaw_deg: float  # extra yaw about z, degrees, added to the chosen rotation
    release_mm: float  # extra drop height above the planned rest height, mm
    comply_mm: float = 0.0  # how far the box may slide aside off a neighbour (ExecutionNoise)
    seat_mm: float = 0.0  # how far past the plan the box may be pushed flush (ExecutionNoise)
    #: Per axis (x, y), the side the skill pushes toward (-1, +1, or 0: none), ``seat_sides``.
    seat_sides: tuple[int, int] = (0, 0)

    @property
    def is_exact(self) -> bool:
        return self.offset_mm == (0.0, 0.0) and self.yaw_deg == 0.0 and self.release_mm == 0.0


EXACT_DROP = ExecutedDrop((0.0, 0.0), 0.0, 0.0)


def _half_extent(footprint_mm: tuple[float, float], yaw_deg: float) -> tuple[float, float]:
    """Half sizes (mm) of the axis-aligned rectangle around a footprint turned by ``yaw_deg``."""
    fx, fy = footprint_mm
    c, s = abs(math.cos(math.radians(yaw_deg))), abs(math.sin(math.radians(yaw_deg)))
    return (c * fx + s * fy) / 2, (s * fx + c * fy) / 2


NO_GRASP_ERROR = (0.0, 0.0, 0.0)


def perturb_drop(
    noise: ExecutionNoise,
    min_corner_mm: tuple[int, int, int],
    footprint_mm: tuple[int, int],
    container_mm: tuple[int, int],
    rng: np.random.Generator,
    grasp_error: tuple[float, float, float] = NO_GRASP_ERROR,
) -> ExecutedDrop:
    """Sample the executed drop of a planned one (pure but for ``rng``, which it advances).

    ``footprint_mm`` is the box's (x, y) footprint under the chosen rotation, ``container_mm``
    the container's inner (X, Y). ``grasp_error`` is the error of the grasped box's estimated
    pose (dx mm, dy mm, dyaw deg; estimated minus true, ``Perception.grasp_errors``): the robot
    puts the box's *estimated* pose at the plan, so the true box lands off by the error with its
    sign reversed, on top of the arm's noise. The xy offset is clamped so the turned footprint
    stays inside the walls: a robot guided by the walls does not push a box into them, and a
    box started inside a wall would be shot out by the contact solver. Exactly three normal
    draws per call (x, y, yaw), whatever the noise, so one seed gives one noise sequence.
    """
    dx, dy, dyaw = rng.normal(size=3)
    if noise.is_zero and tuple(grasp_error) == NO_GRASP_ERROR:
        return EXACT_DROP
    gx, gy, gyaw = (float(v) for v in grasp_error)
    yaw = float(dyaw) * noise.yaw_sigma_deg - gyaw
    half_x, half_y = _half_extent(footprint_mm, yaw)
    cx = min_corner_mm[0] + footprint_mm[0] / 2
    cy = min_corner_mm[1] + footprint_mm[1] / 2
    # Clamp the centre into [half, size - half] (an oversized footprint stays where planned).
    nx = float(
        np.clip(cx + dx * noise.xy_sigma_mm - gx, half_x, max(half_x, container_mm[0] - half_x))
    )
    ny = float(
        np.clip(cy + dy * noise.xy_sigma_mm - gy, half_y, max(half_y, container_mm[1] - half_y))
    )
    return ExecutedDrop(
        (nx - cx, ny - cy),
        yaw,
        float(noise.release_mm),
        float(noise.comply_mm),
        float(noise.seat_mm),
    )


#: A side of a planned footprint is flush (something to push the box against) when a cell of
#: the strip beside it on the observed heightmap rises at least this far above the box's
#: bottom: over the per-cell error of the stereo preset's heightmap (a few mm) so a neighbour
#: level with the support never reads as a face, and far below the smallest box height (80 mm
#: in packlab-bench-v1) so a real neighbour always does.
SEAT_FACE_MM = FACE_RISE_MM  # the shared constant (packlab.core.levels), not a same-level test


def seat_sides(
    heightmap: np.ndarray,
    x: int,
    y: int,
    footprint_cells: tuple[int, int],
    bottom_mm: int,
    face_mm: int = SEAT_FACE_MM,
) -> tuple[int, int]:
    """Per axis (x, y), the side (-1, +1, or 0: none) a planned footprint is flush with, read
    from ``heightmap`` (what the robot observed) only: a container wall, or a strip of cells
    beside the footprint with a cell at least ``bottom_mm + face_mm`` high. With both sides
    flush (a tight slot) the minimum side wins, as a minimum-corner rule plans."""
    fx, fy = footprint_cells
    # Per axis: the grid with that axis first, the footprint's start and length along it, and
    # its cells across it.
    axes = ((heightmap, x, fx, slice(y, y + fy)), (heightmap.T, y, fy, slice(x, x + fx)))
    sides = []
    for grid, start, length, across in axes:
        side = 0
        for direction, strip in ((-1, start - 1), (1, start + length)):
            wall = not 0 <= strip < grid.shape[0]
            if wall or (grid[strip, across] >= bottom_mm + face_mm).any():
                side = direction
                break
        sides.append(side)
    return sides[0], sides[1]


__all__ = [
    "EXACT_DROP",
    "EXECUTION_PRESETS",
    "NO_GRASP_ERROR",
    "SEAT_FACE_MM",
    "ExecutedDrop",
    "ExecutionNoise",
    "execution_noise",
    "perturb_drop",
    "seat_sides",
]
