"""Transition backends behind one protocol: ``geometric`` (exact Eq. 2) and ``mujoco`` (physics)."""

from __future__ import annotations

from packlab.errors import ConfigError
from packlab.sim.physics.base import Transition, TransitionBackend
from packlab.sim.physics.geometric import GeometricBackend

BACKENDS = ("geometric", "mujoco")


def make_backend(name: str, physics=None) -> TransitionBackend:
    """A fresh backend by name; ``physics`` is a ``PhysicsConfig`` for the mujoco backend."""
    if name == "geometric":
        return GeometricBackend()
    if name == "mujoco":
        # Imported here so planning code that only needs geometry does not load the engine.
        from packlab.sim.physics.mujoco_backend import MujocoBackend

        return MujocoBackend(physics)
    raise ConfigError(f"backend = {name!r}: unknown; choose one of {', '.join(BACKENDS)}")


__all__ = ["BACKENDS", "GeometricBackend", "Transition", "TransitionBackend", "make_backend"]
