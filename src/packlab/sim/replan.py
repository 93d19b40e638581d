"""Perceived observations and re-planning events.

In ``perceived`` mode the episode shows the policy what a perceiver (the depth cameras and
perception of ``packlab.sim.sensing``) recovers from the scene, not the exact state. After
every placement it compares the newly perceived heightmap with the one predicted from the
previous perceived heightmap by paper Eq. 2 for the intended placement (with the sizes the
policy was shown), and logs a *re-plan event* when they differ by more than ``ReplanRule``.
The policies are closed-loop already; the event measures how often the world departs from the
plan (a box slid, toppled, or was perceived wrongly), it does not change the loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from packlab.core.errors import ConfigError
from packlab.core.feasibility import placement_height
from packlab.core.types import Container
from packlab.sim.heightmap import place_box


@dataclass(frozen=True, slots=True)
class Scene:
    """The true state a perceiver looks at (what a camera could see, and the ground truth)."""

    container: Container
    sizes_mm: np.ndarray  # (n, 3) int l, w, h mm of every box of the case, indexed like it
    positions_mm: np.ndarray  # (n, 3) float mm box centres; NaN rows: not in the container
    quaternions: np.ndarray  # (n, 4) float wxyz; NaN rows: not in the container
    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, the exact heightmap
    shown: tuple[int, ...]  # case indices of the buffered objects, in the order shown


@dataclass(frozen=True, slots=True)
class Perception:
    """What the perceiver recovered: the policy's observation in ``perceived`` mode."""

    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm, perceived container heightmap
    #: Perceived (l, w, h) mm per listed box, in the order the robot lists them. Without
    #: ``picks``, one per buffered box, in the scene's ``shown`` order.
    sizes_mm: tuple[tuple[int, int, int], ...]
    #: Errors against the truth, where the perceiver reports them (for the robustness tables):
    #: per listed box the largest size error (mm) and the yaw error (degrees), and the mean
    #: absolute heightmap error over the container's cells (mm).
    dims_error_mm: tuple[float, ...] = ()
    yaw_error_deg: tuple[float, ...] = ()
    heightmap_mae_mm: float | None = None
    #: Per listed box, how far the estimated pose of the box on the buffer is from its true
    #: pose: (dx mm, dy mm, dyaw degrees), estimated minus true, world frame, yaw wrapped to the
    #: box's symmetry. A robot grasps and turns the box by its estimate, so this error travels
    #: into the placement: the estimated pose is put at the plan, the true box lands off by the
    #: error with its sign reversed (``execution.perturb_drop``). Empty: no error (exact).
    grasp_errors: tuple[tuple[float, float, float], ...] = ()
    #: Simulator bookkeeping per listed box: the buffered box a pick at it takes (its position
    #: in the scene's ``shown``). None: the listed boxes are the buffered ones, in order.
    picks: tuple[int, ...] | None = None
    #: Buffered boxes no listed box stands for (positions in the scene's ``shown``): they stay
    #: in the buffer, unshown, and are looked at again at the next observation.
    missed: tuple[int, ...] = ()
    #: The robot's own check of the look: as many box-like segments as the buffer holds and no
    #: other. After ``LOOKS_BEFORE_SET_ASIDE`` looks in a row that fail it the episode clears
    #: ``cleared``.
    clean: bool = True
    #: The buffered boxes (positions in the scene's ``shown``) under the segments the robot could
    #: not identify (not box-like): what it takes off the buffer when it clears it.
    cleared: tuple[int, ...] = ()
    #: Simulator bookkeeping per listed box: True where the perceived first side (the longer
    #: one: a camera cannot see which side a catalogue calls l) is the box's own w side, so the
    #: episode turns the box by the other rotation to do what the policy chose. Empty: none.
    axis_swapped: tuple[bool, ...] = ()
    #: Looks at the buffer this perception took (2: one re-scan; None: not reported).
    scans: int | None = None

    def listed_boxes(self, shown: int) -> tuple[int, ...]:
        """Per listed box, its position among the ``shown`` buffered boxes."""
        return tuple(range(shown)) if self.picks is None else self.picks


class Perceiver(Protocol):
    """Turns a scene into a perception; ``rng`` is its only source of randomness (seeded)."""

    def __call__(self, scene: Scene, rng: np.random.Generator) -> Perception: ...


def exact_perceiver(scene: Scene, rng: np.random.Generator) -> Perception:
    """The ideal perceiver: the exact heightmap and sizes (what ``exact`` mode shows)."""
    sizes = tuple(tuple(int(v) for v in scene.sizes_mm[i]) for i in scene.shown)
    return Perception(scene.heightmap.copy(), sizes)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class ReplanRule:
    """When a perceived heightmap departs from its prediction: more than ``min_cells`` cells off
    by more than ``threshold_mm``.

    20 mm is ten height steps of the 2 mm grid: several times the per-cell error a 1-10 mm depth
    camera leaves after binning (median of many pixels per 25 mm cell), yet less than the
    thinnest box, so a box that slid off-plan or toppled shows. One or two cells can disagree at
    a box edge by sampling alone (a box 1 mm over a cell border), hence ``min_cells`` = 2.
    """

    threshold_mm: int = 20
    min_cells: int = 2

    def __post_init__(self) -> None:
        if self.threshold_mm < 0 or self.min_cells < 0:
            raise ConfigError(f"ReplanRule = {self!r}: thresholds must not be negative")


def predict_heightmap(
    heightmap: np.ndarray, x: int, y: int, footprint_cells: tuple[int, int], height_mm: int
) -> np.ndarray:
    """Eq. 2 prediction: a box of ``height_mm`` on ``footprint_cells`` at cell (x, y) rests on
    the highest cell under it (``heightmap`` is the perceived one before the placement)."""
    fx, fy = footprint_cells
    z = placement_height(heightmap, x, y, fx, fy)
    return place_box(heightmap, x, y, fx, fy, z + height_mm)


def deviates(predicted: np.ndarray, perceived: np.ndarray, rule: ReplanRule) -> bool:
    """True when ``perceived`` departs from ``predicted`` by the rule (a re-plan event)."""
    diff = np.abs(perceived.astype(np.int64) - predicted.astype(np.int64))
    return int((diff > rule.threshold_mm).sum()) > rule.min_cells


__all__ = [
    "Perceiver",
    "Perception",
    "ReplanRule",
    "Scene",
    "deviates",
    "exact_perceiver",
    "predict_heightmap",
]
