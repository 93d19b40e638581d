"""Policies by name, found through the ``packlab.policies`` entry-point group.

The registry imports no policy family: each one (the built-in heuristics, ``random``,
``oracle``, the VLM policies, a user's own package) declares ``name = "module:factory"`` under
``[project.entry-points."packlab.policies"]`` and is imported only when that name is made, so
heavy stacks (torch, transformers) load only for the policies that need them.
``register_policy`` adds a factory at run time (tests, notebooks); it wins over an entry point
of the same name.

A factory may also state in which episodes its policy's play does not depend on the run seed
(:func:`declare_seed_free`, read by :func:`seed_free_modes`); the bench then plays such an
episode once per case and copies it to the other seeds. A factory that states nothing (every
plugin unless it declares) depends on the seed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Literal, TypeVar

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


# -- the run seed -------------------------------------------------------------------------

#: Where a policy may be free of the run seed. Only episodes of exact observation and exact
#: execution qualify: perception and robot noise are drawn from the seed, so every policy's
#: episodes depend on it there. What is left of the seed is the order the buffer is shown in:
#:
#: * ``"shuffled"``: the buffer and offline protocols show the window in a seeded shuffle, fresh
#:   every step. Seed-free there: a policy that never reads the seed and chooses the same box
#:   (by its id), rotation and position whatever order the window is shown in, including
#:   between tied placements and when it sets a box aside. Its actions then differ between
#:   seeds only in the shown index they name, which the bench maps to each seed's own order.
#: * ``"arrival"``: the online protocol shows the boxes in arrival order and draws nothing.
#:   Seed-free there: a deterministic policy that never reads the seed.
SeedFreeMode = Literal["shuffled", "arrival"]
SEED_FREE_MODES: tuple[SeedFreeMode, ...] = ("shuffled", "arrival")

#: A factory's statement: its keyword options -> the modes in which its policy is seed-free.
SeedFreeRule = Callable[[Mapping[str, Any]], frozenset[SeedFreeMode]]

#: The factory attribute :func:`declare_seed_free` sets.
SEED_FREE_ATTR = "seed_free_modes"

_F = TypeVar("_F", bound=Callable[..., Any])


def declare_seed_free(rule: SeedFreeRule) -> Callable[[_F], _F]:
    """Decorator of a policy factory: ``rule(options)`` says in which :data:`SeedFreeMode`
    modes the policy it makes with ``options`` plays the same episode for every run seed. A
    claim is checked by tests/policies/test_seed_free.py, which plays two seeds of it."""

    def decorate(factory: _F) -> _F:
        setattr(factory, SEED_FREE_ATTR, rule)
        return factory

    return decorate


def seed_free_always(options: Mapping[str, Any]) -> frozenset[SeedFreeMode]:
    """The rule of a policy seed-free in every mode whatever its options."""
    return frozenset(SEED_FREE_MODES)


def seed_free_modes(name: str, options: Mapping[str, Any] | None = None) -> frozenset[SeedFreeMode]:
    """The modes in which policy ``name`` made with ``options`` is free of the run seed: what
    its factory declares, or none (a factory that states nothing depends on the seed)."""
    rule = getattr(policy_factory(name), SEED_FREE_ATTR, None)
    if rule is None:
        return frozenset()
    return frozenset(rule(dict(options or {}))) & frozenset(SEED_FREE_MODES)
