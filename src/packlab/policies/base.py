"""The Policy protocol every packing policy implements (DESIGN.md section 7)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from packlab.types import Action, Case, Observation, Unparsable


@runtime_checkable
class Policy(Protocol):
    """Chooses one action per step from an observation."""

    name: str

    def reset(self, case: Case, seed: int) -> None:
        """Prepare for a new episode of ``case`` with run seed ``seed``."""
        ...

    def act(self, observation: Observation) -> Action | Unparsable:
        """The next action (``Unparsable`` when a model's answer could not be read)."""
        ...
