"""The bench run configuration: what to run (``RunConfig``) and its resolved form (``ResolvedRun``).

``RunConfig`` is what a user asks for (defaults left empty); ``resolve`` fills the defaults,
loads and filters the cases and returns a ``ResolvedRun`` whose ``to_json()`` is written as the
run directory's ``config.json``. The *identity* part of that file (cases digest, policies,
seeds, backend, difficulties, physics) decides the records; a rerun into the same directory must
match it, which is what makes resuming safe. The *execution* part (workers, executor) may change
between a killed run and its resumption.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from packlab.bench.describe import difficulty_order
from packlab.bench.suites import DEFAULT_SUITE, CaseSource, resolve_cases
from packlab.errors import ConfigError
from packlab.types import Case

#: Version of the run-directory layout (config.json, episodes.jsonl records).
RUN_FORMAT = "packlab-bench-run-1"
EXEC_BACKENDS = ("process", "ray")
TRANSITION_BACKENDS = ("geometric", "mujoco")
#: config.json keys that must agree for a run directory to be resumed.
IDENTITY_KEYS = ("format", "suite", "cases_sha256", "policies", "policy_args", "seeds", "backend", "difficulties",
                 "physics")


def default_policies(cases: tuple[Case, ...] = ()) -> tuple[str, ...]:
    """Every registered heuristic, then random and the oracle (when every case has a plan).

    VLM policies are registered too but never run unless named: they need models and hardware.
    """
    from packlab.policies.heuristics import SCORERS

    names = (*SCORERS, "random")
    if all(c.gt_plan is not None for c in cases):
        names += ("oracle",)
    return names


def local_cores() -> int:
    """Cores this process may run on (respects CPU affinity, unlike os.cpu_count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _split(text: str | None) -> tuple[str, ...]:
    return () if not text else tuple(t.strip() for t in text.split(",") if t.strip())


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0,1,2"`` or a range ``"0-4"`` -> seeds."""
    seeds: list[int] = []
    for part in _split(text):
        try:
            if "-" in part[1:]:
                lo, hi = part.split("-", 1)
                seeds += range(int(lo), int(hi) + 1)
            else:
                seeds.append(int(part))
        except ValueError:
            raise ConfigError(f"seeds = {text!r}: expected integers like 0,1,2 or 0-2") from None
    return tuple(seeds)


@dataclass(frozen=True, slots=True)
class RunConfig:
    """What a bench run should do; empty fields mean "the default" and are filled by ``resolve``."""

    cases: str = DEFAULT_SUITE  # a registered suite name or a case file (JSON, JSONL, parquet)
    policies: tuple[str, ...] = ()  # empty: default_policies()
    seeds: tuple[int, ...] = (0, 1, 2)  # run seeds: buffer shuffle and policy randomness
    backend: str = "mujoco"
    difficulties: tuple[str, ...] = ()  # empty: every difficulty in the cases
    out: str = ""  # empty: runs/bench-<suite>
    workers: int = 0  # 0: all local cores
    exec_backend: str = "process"
    progress: bool = True
    retry_errors: bool = False  # rerun episodes recorded as failed (the new record supersedes)
    #: PhysicsConfig fields to change from the engine's defaults (mujoco only), e.g.
    #: (("max_settle_steps", 1000),). Part of the run's identity: they change the scores.
    physics_overrides: tuple[tuple[str, Any], ...] = ()
    #: Keyword arguments of policy factories, (policy, key, value), e.g.
    #: (("vlm", "model", "runs/sft/final"),). Part of the run's identity.
    policy_args: tuple[tuple[str, str, Any], ...] = ()

    def __post_init__(self) -> None:
        if not self.seeds:
            raise ConfigError("seeds: give at least one run seed")
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, int) or s < 0:
                raise ConfigError(f"seeds: {s!r} is not a non-negative integer")
        if len(set(self.seeds)) != len(self.seeds):
            raise ConfigError(f"seeds = {list(self.seeds)}: a seed is repeated")
        if self.backend not in TRANSITION_BACKENDS:
            raise ConfigError(f"backend = {self.backend!r}: unknown; choose one of {', '.join(TRANSITION_BACKENDS)}")
        if self.exec_backend not in EXEC_BACKENDS:
            raise ConfigError(f"backend-exec = {self.exec_backend!r}: unknown; choose one of {', '.join(EXEC_BACKENDS)}")
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 0:
            raise ConfigError(f"workers = {self.workers!r}: must be a whole number >= 0 (0 = all cores)")
        if len(set(self.policies)) != len(self.policies):
            raise ConfigError(f"policies = {','.join(self.policies)}: a policy is repeated")
        if self.policies:
            from packlab.policies import available_policies

            known = available_policies()
            for name in self.policies:
                if name not in known:
                    raise ConfigError(f"policies: {name!r} is not a registered policy; available: {', '.join(known)}")
        if len(set(self.difficulties)) != len(self.difficulties):
            raise ConfigError(f"difficulty = {','.join(self.difficulties)}: a difficulty is repeated")
        for name, key, _ in self.policy_args:
            if self.policies and name not in self.policies:
                raise ConfigError(f"policy-arg {name}:{key}: policy {name!r} is not among the policies to run")
        if self.physics_overrides and self.backend != "mujoco":
            raise ConfigError(f"physics = {dict(self.physics_overrides)!r}: only the mujoco backend has physics settings")


@dataclass(frozen=True, slots=True)
class ResolvedRun:
    """A RunConfig with every default filled in and its cases loaded and selected."""

    config: RunConfig
    source: CaseSource
    cases: tuple[Case, ...]  # the selected cases (after --difficulty)
    policies: tuple[str, ...]
    difficulties: tuple[str, ...]
    out: Path
    workers: int
    physics: dict[str, Any] | None = field(default=None)  # PhysicsConfig fields (mujoco) or None

    def to_json(self) -> dict[str, Any]:
        """The run directory's config.json: identity keys first, then how it was executed."""
        return {
            "format": RUN_FORMAT,
            "suite": self.source.label,
            "cases_origin": self.source.origin,
            "cases_sha256": self.source.sha256,
            "n_cases": len(self.cases),
            "policies": list(self.policies),
            "policy_args": self.policy_kwargs(),
            "seeds": list(self.config.seeds),
            "backend": self.config.backend,
            "difficulties": list(self.difficulties),
            "physics": self.physics,
            "execution": {"workers": self.workers, "exec_backend": self.config.exec_backend},
        }

    def policy_kwargs(self) -> dict[str, dict[str, Any]]:
        """Factory keyword arguments by policy name (only policies that have some)."""
        out: dict[str, dict[str, Any]] = {}
        for name, key, value in self.config.policy_args:
            out.setdefault(name, {})[key] = value
        return out

    def physics_config(self) -> Any:
        """The PhysicsConfig to build backends with (None for the geometric backend)."""
        return physics_from_json(self.physics)


def physics_from_json(fields: dict[str, Any] | None) -> Any:
    """A config.json ``physics`` entry back to a PhysicsConfig (None stays None)."""
    if not fields:
        return None
    from packlab.sim.physics.mujoco_backend import PhysicsConfig

    try:
        return PhysicsConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})
    except TypeError as exc:  # a field this version of the engine does not know
        raise ConfigError(f"config.json: field 'physics' = {fields!r}: {exc}") from None


def _typed(text: str) -> Any:
    """A command-line value as the type it looks like: bool, int, float, else the string."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text.strip()


def parse_physics(items: list[str] | tuple[str, ...]) -> tuple[tuple[str, Any], ...]:
    """``["max_settle_steps=1000", "sleep=false"]`` -> typed overrides (ints, floats, bools)."""
    out = []
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"physics = {item!r}: expected KEY=VALUE, e.g. max_settle_steps=1000")
        out.append((key.strip(), _typed(text)))
    return tuple(out)


def parse_policy_args(items: list[str] | tuple[str, ...]) -> tuple[tuple[str, str, Any], ...]:
    """``["vlm:model=runs/sft/final"]`` -> ((policy, key, typed value), ...)."""
    out = []
    for item in items:
        name, sep, rest = item.partition(":")
        key, sep2, text = rest.partition("=")
        if not (sep and sep2 and name.strip() and key.strip()):
            raise ConfigError(f"policy-arg = {item!r}: expected POLICY:KEY=VALUE, e.g. vlm:model=runs/sft/final")
        out.append((name.strip(), key.strip(), _typed(text)))
    return tuple(out)


def _physics_fields(backend: str, overrides: tuple[tuple[str, Any], ...] = ()) -> dict[str, Any] | None:
    if backend != "mujoco":
        return None
    from packlab.sim.physics.mujoco_backend import PhysicsConfig

    known = {f.name for f in dataclasses.fields(PhysicsConfig)}
    for key, _ in overrides:
        if key not in known:
            raise ConfigError(f"physics: {key!r} is not a PhysicsConfig field; known: {', '.join(sorted(known))}")
    try:
        cfg = PhysicsConfig(**dict(overrides))
    except TypeError as exc:
        raise ConfigError(f"physics = {dict(overrides)!r}: {exc}") from None
    # Resolved and saved in full so a run states the exact engine settings it was scored with.
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(cfg).items()}


def resolve(config: RunConfig) -> ResolvedRun:
    """Load the cases, select difficulties and fill defaults (ConfigError on anything wrong)."""
    source = resolve_cases(config.cases)
    present = difficulty_order([c.difficulty for c in source.cases])
    if config.difficulties:
        for d in config.difficulties:
            if d not in present:
                raise ConfigError(f"difficulty = {d!r}: no such cases in {source.label}; present: {', '.join(present)}")
        difficulties = tuple(d for d in present if d in config.difficulties)
    else:
        difficulties = tuple(present)
    cases = tuple(c for c in source.cases if c.difficulty in difficulties)
    policies = config.policies or default_policies(cases)
    for name, key, _ in config.policy_args:
        if name not in policies:
            raise ConfigError(f"policy-arg {name}:{key}: policy {name!r} is not among the policies to run "
                              f"({', '.join(policies)})")
    out = Path(config.out) if config.out else Path("runs") / f"bench-{source.label}"
    workers = config.workers or local_cores()
    return ResolvedRun(config, source, cases, tuple(policies), difficulties, out, workers,
                       _physics_fields(config.backend, config.physics_overrides))


def check_resumable(saved: dict[str, Any], current: dict[str, Any], path: Path) -> None:
    """ConfigError unless a run directory's saved config has the same identity as this run."""
    for key in IDENTITY_KEYS:
        old, new = saved.get(key), current.get(key)
        if old == new:
            continue
        if isinstance(old, dict) and isinstance(new, dict):
            # Name the differing entries, not two whole dicts (physics has ~20 fields).
            diffs = [f"'{key}.{k}' = {old.get(k, '<absent>')!r} here, {new.get(k, '<absent>')!r} now"
                     for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
            what = "; ".join(diffs[:3]) + (f"; and {len(diffs) - 3} more" if len(diffs) > 3 else "")
        else:
            what = f"'{key}' = {old!r} here, {new!r} now"
        raise ConfigError(
            f"{path}: field {what}; a run directory holds one configuration: use another --out "
            f"(or delete the directory)"
        )


__all__ = [
    "EXEC_BACKENDS",
    "IDENTITY_KEYS",
    "RUN_FORMAT",
    "ResolvedRun",
    "RunConfig",
    "check_resumable",
    "default_policies",
    "local_cores",
    "parse_physics",
    "parse_policy_args",
    "parse_seeds",
    "physics_from_json",
    "resolve",
]
