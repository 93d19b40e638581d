"""The protocols every part plugs into.

A ``Policy`` chooses actions, a ``TransitionBackend`` executes them. Both live in the contract
layer so that ``sim`` (which runs policies) and ``policies`` (which read the simulator's
observations) share them without importing each other.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from packlab.core.types import Action, Box, Container, Observation, Unparsable


@dataclass(frozen=True, slots=True)
class Transition:
    """The outcome of one placement (or of the final settle before scoring)."""

    heightmap: np.ndarray  # (x_cells, y_cells) int32 mm after settling stopped
    settle_steps: int  # physics steps taken (0 for the geometric backend)
    capped: bool  # True when the step cap ended settling before the bodies came to rest
    #: Largest linear (m/s) and angular (rad/s) speed of any box in the container when settling
    #: stopped: under the rest thresholds unless ``capped``. 0 for the geometric backend.
    max_linear_speed: float = 0.0
    max_angular_speed: float = 0.0

    @property
    def settled(self) -> bool:
        """Every box came to rest (the opposite of ``capped``)."""
        return not self.capped


class TransitionBackend(Protocol):
    """One engine behind the episode. Boxes are addressed by their index in the case."""

    name: str

    def reset(self, container: Container, boxes: Sequence[Box]) -> np.ndarray:
        """Start an empty container holding none of ``boxes``; return the empty heightmap."""
        ...

    def place(self, index: int, rotation: int, min_corner_mm: tuple[int, int, int]) -> Transition:
        """Put box ``index`` with its footprint's minimum corner at ``min_corner_mm`` and settle."""
        ...

    def finish(self) -> Transition:
        """Called once after the last object: let everything come to rest before scoring.

        Runs under its own (larger) cap; a ``capped`` result means the episode is scored with
        boxes still moving, which the episode records as ``at_rest: false``.
        """
        ...

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres (n, 3) float mm and quaternions (n, 4) wxyz of all boxes.

        NaN rows = not placed.
        """
        ...


@dataclass(frozen=True, slots=True)
class EpisodeStart:
    """What a policy is told when an episode starts: what a robot cell knows before its first
    look (the container and how many boxes its buffer shows), and random streams of its own.

    Nothing here names the case: not its boxes, its plan, its id or its seed. A policy that
    needs the case itself (the oracle replays its plan) says so with ``needs_case = True`` and
    is handed the :class:`~packlab.core.types.Case` instead.
    """

    container: Container
    buffer_size: int
    #: stream number -> a generator (the episode's derivation; see :meth:`rng`).
    streams: Callable[[int], np.random.Generator] = field(repr=False, compare=False)

    def rng(self, stream: int) -> np.random.Generator:
        """A random stream of the policy's own: the same for the same case, run seed and
        ``stream`` (>= 1), independent of the episode's own shuffle and of other streams."""
        if stream < 1:
            raise ValueError(f"stream = {stream}: must be >= 1 (0 is the episode's own)")
        return self.streams(stream)


@runtime_checkable
class Policy(Protocol):
    """Chooses one action per step from an observation."""

    name: str

    def reset(self, start: EpisodeStart, seed: int) -> None:
        """Prepare for a new episode with run seed ``seed``. A policy with ``needs_case = True``
        is handed the :class:`~packlab.core.types.Case` in place of ``start``."""
        ...

    def act(self, observation: Observation) -> Action | Unparsable:
        """The next action (``Unparsable`` when a model's answer could not be read)."""
        ...
