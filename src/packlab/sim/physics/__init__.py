"""Transition backends behind one protocol: ``geometric`` (exact Eq. 2) and ``mujoco`` (physics)."""

from __future__ import annotations

from packlab.core.choices import PhysicsBackend, choices, require_choice
from packlab.core.protocols import Transition, TransitionBackend
from packlab.sim.physics.geometric import GeometricBackend
from packlab.sim.physics.mujoco_backend import MujocoBackend, PhysicsConfig

#: The backend names, from the :data:`PhysicsBackend` choice type.
BACKENDS: tuple[str, ...] = choices(PhysicsBackend)


def make_backend(name: PhysicsBackend, physics: PhysicsConfig | None = None) -> TransitionBackend:
    """A fresh backend by name; ``physics`` configures the mujoco backend."""
    require_choice(name, PhysicsBackend, "backend")
    if name == "geometric":
        return GeometricBackend()
    return MujocoBackend(physics)


__all__ = [
    "BACKENDS",
    "GeometricBackend",
    "MujocoBackend",
    "PhysicsConfig",
    "Transition",
    "TransitionBackend",
    "make_backend",
]
