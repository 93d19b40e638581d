"""The bench run configuration: what to run (``RunConfig``) and its resolved form (``ResolvedRun``).

``RunConfig`` is what a user asks for (defaults left empty); ``resolve`` fills the defaults,
loads and filters the cases and returns a ``ResolvedRun`` whose ``to_json()`` is written as the
run directory's ``config.json``. The *identity* part of that file (cases digest, policies,
seeds, backend, difficulties, physics) decides the records; a rerun into the same directory must
match it, which is what makes resuming safe. The *execution* part (workers, executor) may change
between a killed run and its resumption.

``RunConfig``, its limits and its flag parsers live in the light :mod:`packlab.bench.options`
(``packlab bench --help`` reads them without loading an engine) and are re-exported here.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from packlab.bench.describe import difficulty_order
from packlab.bench.options import (
    DEFAULT_EPISODE_TIMEOUT_S,
    DEFAULT_MAX_TRANSPORT_FAILURES,
    DEFAULT_POLICIES,
    DEFAULT_SIZE_PRIOR,
    DEFAULT_SUITE,
    LEARNED_DEFAULTS,
    MAX_SEED_VALUE,
    MAX_SEEDS,
    MAX_TIME_LIMIT_S,
    MAX_WORKERS,
    NEEDS_PLAN,
    RunConfig,
    check_out_dir,
    parse_names,
    parse_physics,
    parse_policy_args,
    parse_seeds,
    time_limit_arg,
)
from packlab.bench.suites import CaseSource, resolve_cases
from packlab.core.choices import (
    DEFAULT_REMAINING,
    DEFAULT_SIDES,
    UNRECORDED_SIDES,
    ObservationMode,
    SideNames,
    require_choice,
)
from packlab.core.errors import ConfigError
from packlab.core.packing_protocol import PackingProtocol, saved_protocol
from packlab.core.records import RUN_FORMAT
from packlab.core.types import Case
from packlab.sim.modes import EpisodeModes, episode_modes
from packlab.sim.physics.mujoco_backend import PhysicsConfig

#: RUN_FORMAT (packlab.core.records, with the record types): the version of the run-directory
#: layout (config.json, episodes.jsonl records). A run-1 directory cannot be resumed (its
#: heuristic episodes were played under the old tie rule); the identity check refuses it by this
#: field. Reports still read run-1 records (they migrate).
#: config.json keys that must agree for a run directory to be resumed.
IDENTITY_KEYS = (
    "format",
    "suite",
    "cases_sha256",
    "policies",
    "policy_args",
    "seeds",
    "backend",
    "difficulties",
    "physics",
    # Observation, execution and side names: compared as ``saved_sensing``
    # reads them, so directories made before the entry (or its ``sides``) was always written
    # resume under the settings they were made with, and only under those.
    "sensing",
    # The episode protocol: compared as ``saved_protocol`` reads the two keys
    # together (absent: buffer), with its own one-line refusal (``check_resumable``).
    "protocol",
    "lookahead",
)


def default_policies(
    cases: tuple[Case, ...] = (),
    observation: ObservationMode = "exact",
    online: bool = False,
) -> tuple[str, ...]:
    """:data:`DEFAULT_POLICIES` (packlab.bench.options): every heuristic, the planner at its fast
    budget (``plan-fast``), the shipped learned policies (:data:`LEARNED_DEFAULTS`), then random
    and the oracle (when every case has a plan and observation is exact: perceived mode shows
    boxes under fresh ids, which name no step of a plan).

    ``plan`` at its default budget is left to ``--policies``: it would take the default run past
    five minutes on two cores; so are the other registered policies (the text-answer ``vlm-small``,
    ``endpoint``, the proposer, the RL random floors). The online protocol leaves the oracle out
    too: its plan places boxes in the layout's order, not in arrival order.
    """
    if not online and observation == "exact" and all(c.gt_plan is not None for c in cases):
        return DEFAULT_POLICIES
    return tuple(n for n in DEFAULT_POLICIES if n != NEEDS_PLAN)


def local_cores() -> int:
    """Cores this process may run on (respects CPU affinity, unlike os.cpu_count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def sensing_identity(config: RunConfig) -> dict[str, str]:
    """config.json's ``sensing`` entry: the modes, the noise preset, ``segmentation`` and
    ``size_prior`` in perceived runs and always ``sides`` (see :func:`saved_sensing` for entries
    written before they were always there)."""
    identity: dict[str, str] = {"observation": config.observation, "execution": config.execution}
    identity["noise"] = config.noise
    if config.observation == "perceived":
        identity["segmentation"] = config.segmentation
        identity["size_prior"] = config.size_prior
    identity["sides"] = config.sides
    if config.remaining != DEFAULT_REMAINING:  # absent: shown, as every run before the switch
        identity["remaining"] = config.remaining
    return identity


def saved_sensing(entry: object) -> dict[str, str]:
    """A config.json ``sensing`` entry as this version writes it, from any version's: left out
    (runs made before the modes existed, or exact runs made before side names were always
    recorded) it was both modes exact; ``sides`` left out was the catalogue's in exact observation
    (:data:`UNRECORDED_SIDES`) and longer first in perceived observation (perception always
    named them so). ``size_prior`` left out of a perceived entry was ``grid`` (perception
    snapped every size to the grids before the prior was a choice). ``noise`` is dropped where
    both modes are exact: nothing used it."""
    out = {str(k): str(v) for k, v in entry.items()} if isinstance(entry, dict) else {}
    out.setdefault("observation", "exact")
    out.setdefault("execution", "exact")
    out.setdefault("sides", UNRECORDED_SIDES if out["observation"] == "exact" else "longer-first")
    if out["observation"] == "perceived":
        out.setdefault("size_prior", DEFAULT_SIZE_PRIOR)
    if out["observation"] == "exact" and out["execution"] == "exact":
        out.pop("noise", None)
    return out


def run_sides(saved_config: dict[str, Any] | None) -> SideNames:
    """The side names a run's records were made with, from its config.json (None: no
    config.json, records of this version: :data:`DEFAULT_SIDES`). Replays step the recorded
    actions under these names: a rotation is relative to the sides the policy was shown."""
    if saved_config is None:
        return DEFAULT_SIDES
    sides = saved_sensing(saved_config.get("sensing"))["sides"]
    require_choice(sides, SideNames, "sensing.sides")
    return cast(SideNames, sides)


def default_out(label: str, config: RunConfig) -> Path:
    """``runs/bench-<suite>``; with a perceived or noisy mode its names are appended
    (``runs/bench-<suite>-perceived-noisy-stereo``), and ``-catalogue`` with the catalogue's side
    names, so running the modes one after another with no ``--out`` gives each its own run
    directory instead of a refused resume."""
    modes = [m for m in (config.observation, config.execution) if m != "exact"]
    hidden = ["remaining-hidden"] if config.remaining != DEFAULT_REMAINING else []
    if config.protocol == "online":  # its own directory: a run directory holds one protocol
        hidden.append(f"online-k{config.lookahead}")
    if config.protocol == "offline":
        hidden.append("offline")
    if not modes:
        suffix = [] if config.sides == DEFAULT_SIDES else [config.sides]
        return Path("runs") / "-".join(["bench", label, *suffix, *hidden])
    ablation = ["truth-masks"] if config.segmentation == "truth" else []
    if config.observation == "perceived" and config.size_prior != DEFAULT_SIZE_PRIOR:
        ablation.append(f"size-prior-{config.size_prior}")
    return Path("runs") / "-".join(["bench", label, *modes, config.noise, *ablation, *hidden])


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
            "sensing": sensing_identity(self.config),
            **self.config.packing_protocol().identity(),
            "execution": {
                "workers": self.workers,
                "executor": self.config.executor,
                "concurrency": self.config.concurrency,
                "reuse": self.config.reuse,
                **({"via_cell": self.config.via_cell} if self.config.via_cell else {}),
                "episode_timeout_s": self.config.episode_timeout_s,
                "max_transport_failures": self.config.max_transport_failures,
                "deadline_s": self.config.deadline_s,
            },
        }

    def policy_kwargs(self) -> dict[str, dict[str, Any]]:
        """Factory keyword arguments by policy name (only policies that have some)."""
        out: dict[str, dict[str, Any]] = {}
        for name, key, value in self.config.policy_args:
            out.setdefault(name, {})[key] = value
        return out

    def episode_modes(self) -> EpisodeModes:
        """The perceiver and execution noise episodes run with (both None when exact), and
        the protocol."""
        c = self.config
        modes = episode_modes(
            c.observation,
            c.execution,
            c.noise,
            c.segmentation,
            c.sides,
            c.remaining,
            size_prior=c.size_prior,
        )
        return dataclasses.replace(modes, protocol=c.packing_protocol())

    def physics_config(self) -> Any:
        """The PhysicsConfig to build backends with (None for the geometric backend)."""
        return physics_from_json(self.physics)


#: PhysicsConfig fields added after runs were recorded, each with the value that reproduces the
#: settle those runs were made with: a saved ``physics`` entry without them reads as having these
#: (to resume it and to replay its records).
PHYSICS_ADDED = {
    "rest_check_steps": 1,
    "freeze": False,
    "freeze_still_steps": 10,
    "freeze_margin_mm": 10.0,
    "freeze_speed_fraction": 0.3,
}


def saved_physics(fields: dict[str, Any] | None) -> dict[str, Any] | None:
    """A config.json ``physics`` entry with the fields added since it was written filled in."""
    return {**PHYSICS_ADDED, **fields} if fields else fields


def physics_from_json(fields: dict[str, Any] | None) -> Any:
    """A config.json ``physics`` entry back to a PhysicsConfig (None stays None)."""
    if not fields:
        return None
    try:
        filled = {**PHYSICS_ADDED, **fields}
        values: dict[str, Any] = {}
        for k, v in filled.items():
            values[k] = tuple(v) if isinstance(v, list) else v
        return PhysicsConfig(**values)
    except TypeError as exc:  # a field this version of the engine does not know
        raise ConfigError(f"config.json: field 'physics' = {fields!r}: {exc}") from None


def _physics_fields(
    backend: str, overrides: tuple[tuple[str, Any], ...] = ()
) -> dict[str, Any] | None:
    if backend != "mujoco":
        return None
    known = {f.name for f in dataclasses.fields(PhysicsConfig)}
    for key, _ in overrides:
        if key not in known:
            raise ConfigError(
                f"physics: {key!r} is not a PhysicsConfig field; known: {', '.join(sorted(known))}"
            )
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
                raise ConfigError(
                    f"difficulty = {d!r}: no such cases in {source.label}; "
                    f"present: {', '.join(present)}"
                )
        difficulties = tuple(d for d in present if d in config.difficulties)
    else:
        difficulties = tuple(present)
    cases = tuple(c for c in source.cases if c.difficulty in difficulties)
    policies = config.policies or default_policies(
        cases, config.observation, config.protocol == "online"
    )
    for name, key, _ in config.policy_args:
        if name not in policies:
            raise ConfigError(
                f"policy-arg {name}:{key}: policy {name!r} is not among the policies to run "
                f"({', '.join(policies)})"
            )
    out = Path(config.out) if config.out else default_out(source.label, config)
    check_out_dir(out)
    workers = config.workers or local_cores()
    return ResolvedRun(
        config,
        source,
        cases,
        tuple(policies),
        difficulties,
        out,
        workers,
        _physics_fields(config.backend, config.physics_overrides),
    )


def protocol_mismatch(old: PackingProtocol, new: PackingProtocol, where: str) -> str:
    """The one-line refusal of mixing protocols (resuming a run directory, comparing runs)."""
    flags = f"--protocol {old.name}"
    if old.online:
        flags = f"--protocol online --lookahead {old.lookahead}"
    return (
        f"{where}: protocol {old.label} there, {new.label} now; scores of different protocols "
        f"are not comparable ({flags} matches it; a run directory made before the choice used "
        "buffer): use another --out"
    )


def check_resumable(saved: dict[str, Any], current: dict[str, Any], path: Path) -> None:
    """ConfigError unless a run directory's saved config has the same identity as this run."""
    old_protocol, new_protocol = saved_protocol(saved), saved_protocol(current)
    if old_protocol != new_protocol:
        raise ConfigError(protocol_mismatch(old_protocol, new_protocol, str(path)))
    for key in IDENTITY_KEYS:
        if key in ("protocol", "lookahead"):
            continue  # compared above, as saved_protocol reads them
        old, new = saved.get(key), current.get(key)
        if key == "sensing":
            old, new = saved_sensing(old), saved_sensing(new)
        if key == "physics":
            old, new = saved_physics(old), saved_physics(new)
        if old == new:
            continue
        if isinstance(old, dict) and isinstance(new, dict):
            # Name the differing entries, not two whole dicts (physics has ~20 fields).
            diffs = [
                f"'{key}.{k}' = {old.get(k, '<absent>')!r} here, {new.get(k, '<absent>')!r} now"
                for k in sorted(set(old) | set(new))
                if old.get(k) != new.get(k)
            ]
            what = "; ".join(diffs[:3]) + (f"; and {len(diffs) - 3} more" if len(diffs) > 3 else "")
        else:
            what = f"'{key}' = {old!r} here, {new!r} now"
        hint = ""
        if (
            key == "sensing"
            and isinstance(old, dict)
            and isinstance(new, dict)
            and old.get("sides") != new.get("sides")
        ):
            hint = (
                f" (--sides {old.get('sides')} resumes it; runs made before side names were "
                "recorded named them as the catalogue does)"
            )
        raise ConfigError(
            f"{path}: field {what}{hint}; a run directory holds one configuration: use another "
            f"--out (or delete the directory)"
        )


__all__ = [
    "DEFAULT_EPISODE_TIMEOUT_S",
    "DEFAULT_MAX_TRANSPORT_FAILURES",
    "DEFAULT_SUITE",
    "IDENTITY_KEYS",
    "LEARNED_DEFAULTS",
    "MAX_SEEDS",
    "MAX_SEED_VALUE",
    "MAX_TIME_LIMIT_S",
    "MAX_WORKERS",
    "RUN_FORMAT",
    "ResolvedRun",
    "RunConfig",
    "check_out_dir",
    "check_resumable",
    "default_policies",
    "local_cores",
    "parse_names",
    "parse_physics",
    "parse_policy_args",
    "parse_seeds",
    "physics_from_json",
    "protocol_mismatch",
    "resolve",
    "run_sides",
    "saved_sensing",
    "sensing_identity",
    "time_limit_arg",
]
