"""Execution noise: a chosen placement as a robot would really execute it.

The policy chooses a drop (footprint minimum corner in mm, rotation 0/1); a robot puts the box
down with an error: the gripper's xy offset and a yaw error (the arm's repeatability, Gaussian,
zero mean, plus in perceived mode the error of the grasped box's estimated pose) and a release
height above the planned rest height (the gripper opens before contact, so the box falls that
far). The physics decides what happens next, so boxes can land off-plan.

The place skill (``packlab.sim.physics.place_skill``) acts only on what the robot knows: its
command is built from the perceived size and heightmap, the sides it pushes the box toward
(``seat_sides``) are read from the observed heightmap around the planned footprint, never from
the true scene, and its descent and pushes stop or yield on contact force.

Only the mujoco backend executes noisy drops (``MujocoBackend.execute``): the geometric
backend places boxes on whole cells and cannot turn them, so a noisy run on it is refused
(``RunConfig`` and ``Episode``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from packlab.core.choices import NoisePreset, require_choice
from packlab.core.errors import ConfigError
from packlab.core.levels import FACE_RISE_MM
from packlab.sim.physics.place_skill import PlaceCommand


@dataclass(frozen=True, slots=True)
class ExecutionNoise:
    """Robot execution noise: standard deviations of Gaussian errors and a release height."""

    xy_sigma_mm: float = 0.0  # per axis, of the box centre in the container plane
    yaw_sigma_deg: float = 0.0  # about z, added to the chosen rotation's 0 or 90 degrees
    release_mm: float = 0.0  # the box is let go this far above its planned rest height
    #: The place skill's compliant wrist lets a contact slide the box at most this far in all
    #: as it lowers it (``place_skill.descend``): off a wall, a tilted face, a neighbour's edge.
    comply_mm: float = 0.0
    #: The place skill pushes the box toward the sides its planned pose is flush with on the
    #: observed heightmap (``seat_sides``), a guarded move that stops on contact force, at most
    #: this far past the command (``place_skill.seat``), so errors do not add up along a row.
    #: 0: the box stays where the noise put it.
    seat_mm: float = 0.0
    #: The place skill takes a box back out and sets it aside when its descent still stops
    #: well above its target after the last retry, instead of letting it go on a neighbour's
    #: top (``place_skill.PlaceCommand.set_aside_stuck``).
    set_aside_stuck: bool = False

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
#: degrees. Release heights are typical suction-gripper drops. The place skill's settings
#: (``comply_mm``, ``seat_mm``) are the robot's, not noise: the skill does not know its error,
#: so its slides and pushes must reach past the largest errors the arm and the grasp estimate
#: make (their tails reach 10-15 mm with structured light, more with stereo); chosen on
#: generated training cases, never on a bench suite.
EXECUTION_PRESETS: dict[str, ExecutionNoise] = {
    "none": ExecutionNoise(),
    "structured-light": ExecutionNoise(
        xy_sigma_mm=2.0,
        yaw_sigma_deg=1.0,
        release_mm=5.0,
        comply_mm=20.0,
        seat_mm=15.0,
        set_aside_stuck=True,
    ),
    "stereo": ExecutionNoise(
        xy_sigma_mm=5.0,
        yaw_sigma_deg=3.0,
        release_mm=10.0,
        comply_mm=30.0,
        seat_mm=25.0,
        set_aside_stuck=True,
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
    comply_mm: float = 0.0  # how far a contact may slide the box (ExecutionNoise)
    seat_mm: float = 0.0  # how far past the command the box may be pushed flush (ExecutionNoise)
    #: Per axis (x, y), the side the skill pushes toward (-1, +1, or 0: none), ``seat_sides``.
    seat_sides: tuple[int, int] = (0, 0)
    #: Per axis, whether the seat side's face covers the whole footprint (``full_faces``): the
    #: only faces a contact's torque may turn the box flush with.
    full_faces: tuple[bool, bool] = (True, True)
    set_aside_stuck: bool = False  # (ExecutionNoise)

    @property
    def is_exact(self) -> bool:
        return self.offset_mm == (0.0, 0.0) and self.yaw_deg == 0.0 and self.release_mm == 0.0


EXACT_DROP = ExecutedDrop((0.0, 0.0), 0.0, 0.0)


NO_GRASP_ERROR = (0.0, 0.0, 0.0)


def perturb_drop(
    noise: ExecutionNoise,
    rng: np.random.Generator,
    grasp_error: tuple[float, float, float] = NO_GRASP_ERROR,
) -> ExecutedDrop:
    """Sample how a commanded drop is really executed (pure but for ``rng``, which it advances).

    ``grasp_error`` is the error of the grasped box's estimated pose (dx mm, dy mm, dyaw deg;
    estimated minus true, ``Perception.grasp_errors``): the robot puts the box's *estimated*
    pose at the commanded one, so the true box lands off by the error with its sign reversed,
    on top of the arm's noise. This is the simulator's side (it may know the error; the robot
    does not): nothing here clamps or corrects the result. A box the noise pushes into a wall
    is slid off it by the place skill's compliant descent, on the wall's contact force
    (``packlab.sim.physics.place_skill``). Exactly three normal draws per call (x, y, yaw),
    whatever the noise, so one seed gives one noise sequence.
    """
    dx, dy, dyaw = rng.normal(size=3)
    if noise.is_zero and tuple(grasp_error) == NO_GRASP_ERROR:
        return EXACT_DROP
    gx, gy, gyaw = (float(v) for v in grasp_error)
    return ExecutedDrop(
        (float(dx) * noise.xy_sigma_mm - gx, float(dy) * noise.xy_sigma_mm - gy),
        float(dyaw) * noise.yaw_sigma_deg - gyaw,
        float(noise.release_mm),
        float(noise.comply_mm),
        float(noise.seat_mm),
        set_aside_stuck=noise.set_aside_stuck,
    )


def place_command(
    size_mm: tuple[int, int, int],
    rotation: int,
    drop_mm: tuple[int, int, int],
    heightmap: np.ndarray,
    executed: ExecutedDrop,
) -> PlaceCommand:
    """The place skill's command, from what the robot knows only: ``size_mm``, the size it was
    shown (perceived in perceived mode, sides named as shown), ``rotation``, the policy's
    choice on those sides, ``drop_mm``, the footprint's minimum corner and the Eq. 2 height
    the episode read on the observed ``heightmap`` under the shown footprint, and the skill's
    settings (release height, slide budget, seat reach and sides) carried by ``executed``;
    its noise is not read. The target centre is the corner plus half the shown footprint."""
    l, w, h = size_mm
    fx, fy = (w, l) if rotation == 1 else (l, w)
    x, y, z = drop_mm
    return PlaceCommand(
        centre_mm=(x + fx / 2, y + fy / 2),
        footprint_mm=(float(fx), float(fy)),
        bottom_mm=float(z),
        height_mm=float(h),
        release_mm=executed.release_mm,
        seen_top_mm=float(heightmap.max(initial=0)),
        comply_mm=executed.comply_mm,
        seat_mm=executed.seat_mm,
        seat_sides=executed.seat_sides,
        full_faces=executed.full_faces,
        set_aside_stuck=executed.set_aside_stuck,
    )


#: A side of a planned footprint is flush (something to push the box against) when a cell of
#: the strip beside it on the observed heightmap rises at least this far above the box's
#: bottom: over the per-cell error of the stereo preset's heightmap (a few mm) so a neighbour
#: level with the support never reads as a face, and far below the smallest box height (80 mm
#: in packlab-bench-v1) so a real neighbour always does.
SEAT_FACE_MM = FACE_RISE_MM  # the shared constant (packlab.core.levels), not a same-level test


def _axis_views(
    heightmap: np.ndarray, x: int, y: int, footprint_cells: tuple[int, int]
) -> tuple[tuple[np.ndarray, int, int, slice], ...]:
    """Per axis (x, y): the grid with that axis first, the footprint's start and length along
    it, and its cells across it (the strips beside a footprint are rows of that grid)."""
    fx, fy = footprint_cells
    return (heightmap, x, fx, slice(y, y + fy)), (heightmap.T, y, fy, slice(x, x + fx))


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
    sides = []
    for grid, start, length, across in _axis_views(heightmap, x, y, footprint_cells):
        side = 0
        for direction, strip in ((-1, start - 1), (1, start + length)):
            wall = not 0 <= strip < grid.shape[0]
            if wall or (grid[strip, across] >= bottom_mm + face_mm).any():
                side = direction
                break
        sides.append(side)
    return sides[0], sides[1]


def full_faces(
    heightmap: np.ndarray,
    x: int,
    y: int,
    footprint_cells: tuple[int, int],
    bottom_mm: int,
    sides: tuple[int, int],
    face_mm: int = SEAT_FACE_MM,
) -> tuple[bool, bool]:
    """Per axis (x, y), whether the side ``sides`` names (``seat_sides``) is a face along the
    whole footprint on ``heightmap`` (what the robot observed): a container wall, or a strip
    of cells beside the footprint every one of which rises ``face_mm`` over the bottom. A
    neighbour under part of the face only cannot square the box: pushed through its centre,
    the box turns about the neighbour's end and the contact's torque never reverses."""
    full = []
    views = _axis_views(heightmap, x, y, footprint_cells)
    for (grid, start, length, across), side in zip(views, sides, strict=True):
        strip = start - 1 if side < 0 else start + length
        wall = not 0 <= strip < grid.shape[0]
        full.append(
            side != 0 and (wall or bool((grid[strip, across] >= bottom_mm + face_mm).all()))
        )
    return full[0], full[1]


__all__ = [
    "EXACT_DROP",
    "EXECUTION_PRESETS",
    "NO_GRASP_ERROR",
    "SEAT_FACE_MM",
    "ExecutedDrop",
    "ExecutionNoise",
    "execution_noise",
    "full_faces",
    "perturb_drop",
    "place_command",
    "seat_sides",
]
