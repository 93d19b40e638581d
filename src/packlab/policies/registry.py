"""Policies by name. Factories import heavy stacks lazily so the registry itself stays light."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from packlab.errors import ConfigError
from packlab.policies.base import Policy

_FACTORIES: dict[str, Callable[..., Policy]] = {}


def register_policy(name: str) -> Callable[[Callable[..., Policy]], Callable[..., Policy]]:
    """Decorator: register ``factory(**kwargs) -> Policy`` under ``name``."""

    def decorate(factory: Callable[..., Policy]) -> Callable[..., Policy]:
        if name in _FACTORIES and _FACTORIES[name] is not factory:
            raise ValueError(f"policy {name!r} is already registered")
        _FACTORIES[name] = factory
        return factory

    return decorate


def _load_builtins() -> None:
    # Importing the modules runs their @register_policy decorators.
    import packlab.policies.oracle
    import packlab.policies.random_policy

    try:
        import packlab.policies.heuristics
    except ModuleNotFoundError as exc:  # heuristics not built in this checkout
        if exc.name != "packlab.policies.heuristics":
            raise
    try:
        import packlab.vlm.policies  # noqa: F401  (registers vlm/endpoint; imports torch lazily)
    except ModuleNotFoundError as exc:
        if exc.name != "packlab.vlm.policies":
            raise


def available_policies() -> list[str]:
    _load_builtins()
    return sorted(_FACTORIES)


def make_policy(name: str, **kwargs: Any) -> Policy:
    """A new policy instance by registered name."""
    _load_builtins()
    if name not in _FACTORIES:
        raise ConfigError(f"policy = {name!r}: unknown; available: {', '.join(sorted(_FACTORIES))}")
    return _FACTORIES[name](**kwargs)
