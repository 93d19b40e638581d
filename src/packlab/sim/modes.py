"""The episode's observation and execution modes by name, as the bench selects them.

``observation``: ``exact`` (the true heightmap and sizes) or ``perceived`` (what the simulated
depth cameras and perception of ``packlab.sim.sensing`` recover under the ``noise`` preset's
sensor, the buffer's boxes told apart by ``segmentation``: ``depth``, or the ``truth`` masks).
``execution``: ``exact`` or ``noisy`` (the preset's robot noise, ``packlab.sim.execution``).
Both exact: no perceiver, no noise, the exact-mode loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from packlab.core.choices import (
    DEFAULT_NOISE,
    DEFAULT_REMAINING,
    DEFAULT_SEGMENTATION,
    DEFAULT_SIDES,
    DEFAULT_SIZE_PRIOR,
    ExecutionMode,
    NoisePreset,
    ObservationMode,
    RemainingMode,
    Segmentation,
    SideNames,
    SizePrior,
    require_choice,
)
from packlab.core.packing_protocol import BUFFER, PackingProtocol
from packlab.sim.execution import ExecutionNoise, execution_noise
from packlab.sim.replan import Perceiver, Perception, Scene
from packlab.sim.sensing import PerceivedState, perceive_state


@dataclass(frozen=True, slots=True)
class SensingPerceiver:
    """A ``Perceiver`` over ``packlab.sim.sensing.perceive_state``: one sensor preset, and how
    the buffer's boxes are told apart (``depth``: from the depth image alone, the robot's
    default; ``truth``: the simulator's masks, an ablation), and the size prior (``grid``:
    sizes snap to the container's grids; ``none``: raw estimates in whole mm)."""

    preset: NoisePreset
    segmentation: Segmentation = DEFAULT_SEGMENTATION
    size_prior: SizePrior = DEFAULT_SIZE_PRIOR

    def __call__(self, scene: Scene, rng: np.random.Generator) -> Perception:
        return perception_of(self.perceived_state(scene, rng))

    def perceived_state(self, scene: Scene, rng: np.random.Generator) -> PerceivedState:
        """What the cameras and the perception made of ``scene``: the noisy depth images, the
        buffer's segments and which shown box each stands for, behind the ``Perception`` this
        perceiver returns (a driver that sends the images to a cell service reads them)."""
        shown = scene.sizes_mm[list(scene.shown)].reshape(-1, 3)
        return perceive_state(
            scene.container,
            scene.sizes_mm,
            scene.positions_mm,
            scene.quaternions,
            shown,
            self.preset,
            rng,
            self.segmentation,
            size_prior=self.size_prior,
        )


def perception_of(state: PerceivedState) -> Perception:
    """The episode's ``Perception`` of a ``PerceivedState``."""
    sizes = tuple(tuple(int(v) for v in row) for row in np.asarray(state.shown_sizes_mm))
    grasp = tuple(tuple(float(v) for v in row) for row in state.grasp_errors)
    return Perception(
        np.asarray(state.heightmap, dtype=np.int32),
        sizes,  # type: ignore[arg-type]
        dims_error_mm=tuple(float(v) for v in state.stats.dims_error_mm),
        yaw_error_deg=tuple(float(v) for v in state.stats.yaw_error_deg),
        heightmap_mae_mm=float(state.stats.heightmap_mae_mm),
        grasp_errors=grasp,  # type: ignore[arg-type]
        picks=state.picks,
        missed=state.missed,
        clean=state.buffer.clean,
        cleared=tuple(sorted({row for row in state.buffer.blobs if row >= 0})),
        axis_swapped=tuple(bool(v) for v in state.axis_swapped),
        scans=state.stats.scans,
    )


@dataclass(frozen=True, slots=True)
class EpisodeModes:
    """What ``Episode`` takes for the modes: a perceiver (None: exact) and noise (None: exact)."""

    perceiver: Perceiver | None = None
    execution: ExecutionNoise | None = None
    #: Exact observation: the sides' names (perceived mode always names them longer first).
    sides: SideNames = DEFAULT_SIDES
    #: Observations carry ``remaining`` (``core.choices.RemainingMode``).
    show_remaining: bool = True
    #: The episode protocol: packlab's buffered one unless the run asks otherwise.
    protocol: PackingProtocol = BUFFER


#: Both modes exact: what every run uses unless asked otherwise.
EXACT_MODES = EpisodeModes()


def episode_modes(
    observation: ObservationMode = "exact",
    execution: ExecutionMode = "exact",
    noise: NoisePreset = DEFAULT_NOISE,
    segmentation: Segmentation = DEFAULT_SEGMENTATION,
    sides: SideNames = DEFAULT_SIDES,
    remaining: RemainingMode = DEFAULT_REMAINING,
    size_prior: SizePrior = DEFAULT_SIZE_PRIOR,
) -> EpisodeModes:
    """The modes by name (ConfigError naming the field for an unknown value)."""
    require_choice(observation, ObservationMode, "observation")
    require_choice(execution, ExecutionMode, "execution")
    require_choice(noise, NoisePreset, "noise")
    require_choice(segmentation, Segmentation, "segmentation")
    require_choice(sides, SideNames, "sides")
    require_choice(remaining, RemainingMode, "remaining")
    require_choice(size_prior, SizePrior, "size_prior")
    perceiver = (
        SensingPerceiver(noise, segmentation, size_prior) if observation == "perceived" else None
    )
    return EpisodeModes(
        perceiver=perceiver,
        execution=execution_noise(noise) if execution == "noisy" else None,
        sides=sides,
        show_remaining=remaining == "shown",
    )


__all__ = [
    "DEFAULT_NOISE",
    "DEFAULT_SEGMENTATION",
    "DEFAULT_SIDES",
    "EXACT_MODES",
    "EpisodeModes",
    "SensingPerceiver",
    "episode_modes",
    "perception_of",
]
