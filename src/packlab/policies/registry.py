"""Policies by name, found through the ``packlab.policies`` entry-point group.

The registry imports no policy family: each one (the built-in heuristics, ``random``,
``oracle``, the VLM policies, a user's own package) declares ``name = "module:factory"`` under
``[project.entry-points."packlab.policies"]`` and is imported only when that name is made, so
heavy stacks (torch, transformers) load only for the policies that need them.
``register_policy`` adds a factory at run time (tests, notebooks); it wins over an entry point
of the same name.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from packlab.core.errors import ConfigError
from packlab.core.protocols import Policy

#: The entry-point group policy packages declare their factories under.
ENTRY_POINT_GROUP = "packlab.policies"

PolicyFactory = Callable[..., Policy]

_RUNTIME: dict[str, PolicyFactory] = {}

#: Factories already loaded from an entry point. Scanning every installed distribution's
#: metadata costs milliseconds, and the bench makes a policy per episode.
_LOADED: dict[str, PolicyFactory] = {}


def register_policy(name: str) -> Callable[[PolicyFactory], PolicyFactory]:
    """Decorator: register ``factory(**kwargs) -> Policy`` under ``name`` for this process."""

    def decorate(factory: PolicyFactory) -> PolicyFactory:
        if name in _RUNTIME and _RUNTIME[name] is not factory:
            raise ValueError(f"policy {name!r} is already registered")
        _RUNTIME[name] = factory
        return factory

    return decorate


def unregister_policy(name: str) -> None:
    """Forget a factory added by :func:`register_policy` (no error when absent)."""
    _RUNTIME.pop(name, None)


def _declared() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available_policies() -> list[str]:
    """Every policy name that can be made: declared entry points and run-time registrations."""
    return sorted(set(_declared()) | set(_RUNTIME))


def policy_factory(name: str) -> PolicyFactory:
    """The factory registered under ``name`` (imports its package), or a ConfigError."""
    if name in _RUNTIME:
        return _RUNTIME[name]
    if name in _LOADED:
        return _LOADED[name]
    declared = _declared()
    if name not in declared:
        known = ", ".join(available_policies()) or "none (is packlab installed? pip install -e .)"
        raise ConfigError(f"policy = {name!r}: unknown; available: {known}")
    factory: PolicyFactory = declared[name].load()
    _LOADED[name] = factory
    return factory


def make_policy(name: str, **kwargs: Any) -> Policy:
    """A new policy instance by registered name."""
    return policy_factory(name)(**kwargs)
