"""Carrying out a chosen placement in the episode loop: exactly as planned, or as a robot
executes it (noisy execution).

The noise itself and the place skill's command are ``packlab.sim.execution``; the skill is
``packlab.sim.physics.place_skill``. This module holds what the loop decides between them: the
footprint the robot believes in, the drop it executes (with the sides the skill seats toward,
read from the observed heightmap), and which backend call carries it out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol, cast

import numpy as np

from packlab.core.types import ShownItem
from packlab.sim.execution import (
    ExecutedDrop,
    ExecutionNoise,
    full_faces,
    perturb_drop,
    seat_sides,
)
from packlab.sim.physics import Transition, TransitionBackend
from packlab.sim.physics.place_skill import PlaceCommand, SkillReport


class NoisyBackend(TransitionBackend, Protocol):
    """A backend that executes a robot's placement (``supports_noisy_execution``: mujoco)."""

    def execute(
        self,
        index: int,
        rotation: int,
        command: PlaceCommand,
        offset_mm: tuple[float, float],
        yaw_deg: float,
        redraw: Callable[[], tuple[tuple[float, float], float]] | None = None,
    ) -> tuple[Transition, SkillReport]: ...


def executes_noisy_drops(backend: TransitionBackend) -> bool:
    """Whether ``backend`` can execute a robot's placement (``NoisyBackend``)."""
    return bool(getattr(backend, "supports_noisy_execution", False))


@dataclass(frozen=True, slots=True)
class Placement:
    """A valid step's placement as carried out."""

    drop_mm: tuple[int, int, int]  # footprint minimum corner and Eq. 2 height, as planned
    transition: Transition  # the backend's outcome: the settled heightmap and settle counts
    executed: ExecutedDrop | None = None  # noisy execution only: the drop really executed
    command: PlaceCommand | None = None  # the place skill's command, when it placed the box
    skill: SkillReport | None = None  # what the skill had to do, when it placed the box


def believed_footprint(item: ShownItem, rotation: int) -> tuple[int, int]:
    """The footprint cells (x, y) of the size the robot was shown (perceived mode: the
    perceived size, named longer first), turned by the policy's ``rotation`` of it."""
    l_cells, w_cells, _ = item.size_cells
    return (w_cells, l_cells) if rotation == 1 else (l_cells, w_cells)


def robot_drop(
    noise: ExecutionNoise,
    rng: np.random.Generator,
    grasp_error: tuple[float, float, float],
    observed: np.ndarray,
    drop_mm: tuple[int, int, int],
    footprint_cells: tuple[int, int],
    cell_xy_mm: int,
) -> ExecutedDrop:
    """The drop as the robot executes it: the arm's noise plus the grasped box's pose-estimate
    error, and the sides the place skill seats it toward, read from the ``observed`` heightmap
    around the footprint the robot believes in."""
    executed = perturb_drop(noise, rng, grasp_error)
    if executed.is_exact or executed.seat_mm == 0:
        return executed
    x, y = drop_mm[0] // cell_xy_mm, drop_mm[1] // cell_xy_mm
    sides = seat_sides(observed, x, y, footprint_cells, drop_mm[2])
    full = full_faces(observed, x, y, footprint_cells, drop_mm[2], sides)
    return replace(executed, seat_sides=sides, full_faces=full)


def arm_redraw(
    noise: ExecutionNoise, rng: np.random.Generator, grasp_error: tuple[float, float, float]
) -> Callable[[], tuple[tuple[float, float], float]]:
    """A fresh draw of the arm's noise for a placement the skill tries again (the offset and
    yaw, as ``perturb_drop``): the arm's repeatability error is independent per motion, the
    grasp (and its estimate's error) stays. It draws from ``rng`` (the episode's execution
    stream) only when called, so a placement that is not retried leaves the stream as
    before."""

    def draw() -> tuple[tuple[float, float], float]:
        again = perturb_drop(noise, rng, grasp_error)
        return again.offset_mm, again.yaw_deg

    return draw


def carry_out(
    backend: TransitionBackend,
    index: int,
    rotation: int,
    drop_mm: tuple[int, int, int],
    executed: ExecutedDrop | None,
    command: PlaceCommand | None,
    redraw: Callable[[], tuple[tuple[float, float], float]] | None = None,
) -> tuple[Transition, SkillReport | None]:
    """Place case object ``index``: exactly as planned (exact execution, or a noisy draw that
    came out exact), else by the robot's place skill from ``command``, which may try again
    with ``redraw`` (``arm_redraw``)."""
    if executed is None or executed.is_exact or command is None:
        return backend.place(index, rotation, drop_mm), None
    # The episode refuses an execution noise for a backend that cannot execute noisy drops.
    noisy = cast(NoisyBackend, backend)
    return noisy.execute(index, rotation, command, executed.offset_mm, executed.yaw_deg, redraw)
