"""What a bench run asks for: ``RunConfig``, its limits and the parsers of its flags.

Light to import (the standard library and ``packlab.core`` only): ``packlab bench --help`` builds
its options from these fields and constants (``packlab.cli.options.add_field``) without loading
an engine, a policy or a report. Resolving a config (loading cases, filling defaults, the run
directory's ``config.json``) is :mod:`packlab.bench.config`, which re-exports everything here.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

from packlab.core.choices import (
    DEFAULT_NOISE,
    DEFAULT_PROTOCOL,
    DEFAULT_REMAINING,
    DEFAULT_SEGMENTATION,
    DEFAULT_SIDES,
    DEFAULT_SIZE_PRIOR,
    HEURISTICS,
    EpisodeProtocol,
    ExecutionMode,
    Executor,
    NoisePreset,
    ObservationMode,
    PhysicsBackend,
    RemainingMode,
    Segmentation,
    SideNames,
    SizePrior,
    did_you_mean,
    require_choice,
)
from packlab.core.errors import ConfigError
from packlab.core.packing_protocol import DEFAULT_LOOKAHEAD, PackingProtocol
from packlab.executors import check_concurrency

#: The suite a bench run plays unless ``--cases`` names another (``packlab.bench.suites``).
DEFAULT_SUITE = "packlab-bench-v1"
#: The shipped learned policies in the default table, in the paper's Table 2 order. They play
#: their ONNX graphs on ONNX Runtime (core install); a user's own models are named with
#: ``--policies`` and ``--policy-arg NAME:model=DIR``.
LEARNED_DEFAULTS = ("vlm", "irbpp", "tapnet")
#: What a run plays without ``--policies``: every heuristic, the planner at its fast budget, the
#: shipped learned policies, random, and the oracle (dropped when a case has no plan:
#: ``packlab.bench.config.default_policies``). ``--policies``' help prints this very tuple.
DEFAULT_POLICIES = (*HEURISTICS, "plan-fast", *LEARNED_DEFAULTS, "random", "oracle")
#: The one default policy that needs every case to carry its perfect plan.
NEEDS_PLAN = "oracle"
#: The interactive reports' file names (``packlab.bench.html_report``): a run's, and a
#: comparison's when neither ``--html FILE`` nor ``--out`` names it.
REPORT_HTML = "report.html"
COMPARE_HTML = "compare.html"
#: The policy registry's module and entry-point group (packlab.policies.registry).
POLICY_REGISTRY = "packlab.policies.registry"
POLICY_ENTRY_POINTS = "packlab.policies"
#: Limits of a run's size, checked while the flags are parsed (before anything is allocated):
#: ``--seeds 0-100000000`` must be an error, not a process that eats memory until it dies.
MAX_SEEDS = 1000  # run seeds per run (each seed reruns every case x policy)
#: Largest run seed: the buffer shuffle folds run seeds to 32 bits (sim/buffer.py), so two
#: seeds that differ only above bit 31 would be the same episode under two names.
MAX_SEED_VALUE = 2**32 - 1
MAX_WORKERS = 512  # local worker processes (each holds an engine, maybe a model)
#: Per-episode wall-clock limit by default. The slowest measured episodes are about 20 s (a
#: small VLM on CPU, 24 decisions); 30 minutes leaves two orders of magnitude for large models
#: and slow servers, yet a stuck episode costs one worker half an hour, not the whole run.
DEFAULT_EPISODE_TIMEOUT_S = 1800.0
#: Consecutive transport-error episodes (EndpointUnavailable) after which a run stops.
DEFAULT_MAX_TRANSPORT_FAILURES = 3
#: Longest --episode-timeout / --deadline accepted (30 days): longer is a typo; 0 means none.
MAX_TIME_LIMIT_S = 30 * 24 * 3600.0


def _split(text: str | None) -> tuple[str, ...]:
    return () if not text else tuple(t.strip() for t in text.split(",") if t.strip())


def parse_names(text: str | None, flag: str) -> tuple[str, ...]:
    """A comma-separated list flag: absent (None) -> () meaning "the default set"; given but
    empty (``--policies ,`` or ``""``) is an error rather than a silent "run everything"."""
    if text is None:
        return ()
    names = _split(text)
    if not names:
        raise ConfigError(
            f"{flag} = {text!r}: empty list; name at least one "
            f"(or leave out --{flag} for the default)"
        )
    return names


def _seed_value(text: str, whole: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise ConfigError(f"seeds = {whole!r}: expected integers like 0,1,2 or 0-2") from None
    if not 0 <= value <= MAX_SEED_VALUE:
        raise ConfigError(
            f"seeds = {whole!r}: {value} is out of range; run seeds are 0..{MAX_SEED_VALUE}"
        )
    return value


def _seed_part(part: str, whole: str) -> range:
    """One comma-separated item: ``"3"`` or an inclusive range ``"0-4"``, as a lazy range."""
    lo_text, dash, hi_text = part.partition("-")
    if not dash:
        value = _seed_value(part, whole)
        return range(value, value + 1)
    if not lo_text.strip():  # "-3": a negative number, not a range
        raise ConfigError(
            f"seeds = {whole!r}: {part!r} is negative; run seeds are 0..{MAX_SEED_VALUE}"
        )
    lo, hi = _seed_value(lo_text, whole), _seed_value(hi_text, whole)
    if hi < lo:
        raise ConfigError(f"seeds = {whole!r}: range {part!r} runs backwards; write {hi}-{lo}")
    return range(lo, hi + 1)


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0,1,2"`` or a range ``"0-4"`` (inclusive) -> seeds; at most MAX_SEEDS of them.

    Ranges stay lazy until the total is known to be within the limit, so a huge range is an
    error in microseconds instead of a list that exhausts memory.
    """
    parts = [_seed_part(part, text) for part in _split(text)]
    total = sum(len(r) for r in parts)
    if total > MAX_SEEDS:
        raise ConfigError(f"seeds = {text!r}: {total} seeds; at most {MAX_SEEDS} per run")
    return tuple(seed for r in parts for seed in r)


def _check_time_limit(flag: str, value: float | None) -> None:
    if value is None:
        return
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or not 0 < value <= MAX_TIME_LIMIT_S
    ):
        raise ConfigError(
            f"{flag} = {value!r}: must be a number of seconds in (0, {MAX_TIME_LIMIT_S:.0f}] "
            f"(0 on the command line means no limit)"
        )


def time_limit_arg(value: float | None) -> float | None:
    """A --episode-timeout / --deadline flag value: 0 (or None) means no limit (None)."""
    return None if value is None or value == 0 else value


@dataclass(frozen=True, slots=True)
class RunConfig:
    """What a bench run should do; empty fields mean "the default" and are filled by ``resolve``."""

    cases: str = DEFAULT_SUITE  # a registered suite name or a case file (JSON, JSONL, parquet)
    policies: tuple[str, ...] = ()  # empty: default_policies()
    seeds: tuple[int, ...] = (0, 1, 2)  # run seeds: buffer shuffle and policy randomness
    backend: PhysicsBackend = "mujoco"  # the transition backend
    difficulties: tuple[str, ...] = ()  # empty: every difficulty in the cases
    out: str = ""  # empty: runs/bench-<suite>
    workers: int = 0  # 0: all local cores (Ray: CPUs of a Ray it starts itself)
    #: Where episodes run (packlab.executors): "process" (a local pool; in this process with
    #: one worker) or "ray". Not part of the identity: the records are the same on either.
    executor: Executor = "process"
    #: Episodes each worker runs at once, one thread each (1: one after another). Pays where
    #: episodes wait on a model server, which then sees up to workers x concurrency requests
    #: to batch. Not part of the identity: each episode's record is the same at any value.
    concurrency: int = 1
    progress: bool = True
    retry_errors: bool = False  # rerun episodes recorded as failed (the new record supersedes)
    #: Play a policy that is free of the run seed in this run's modes once per case (the lowest
    #: seed) and copy that episode to the other seeds (``packlab.bench.reuse``); False plays
    #: every seed. Not part of the identity: the records are the same either way, times aside.
    reuse: bool = True
    #: A running cell service (``packlab cell serve``) whose policies play the episodes: the
    #: bench sends each step's rendered depth images and calibrations, the service answers
    #: (``packlab.cell.via_cell``). None: the policies play in the bench's processes. Not part
    #: of the identity: the records are the same either way, times aside and a tie the policy
    #: breaks by the order the boxes are listed in (docs/cell.md).
    via_cell: str | None = None
    #: PhysicsConfig fields to change from the engine's defaults (mujoco only), e.g.
    #: (("max_settle_steps", 1000),). Part of the run's identity: they change the scores.
    physics_overrides: tuple[tuple[str, Any], ...] = ()
    #: Keyword arguments of policy factories, (policy, key, value), e.g.
    #: (("vlm", "model", "runs/sft/final"),). Part of the run's identity.
    policy_args: tuple[tuple[str, str, Any], ...] = ()
    #: Wall-clock limit of one episode (None: no limit); an episode past it is recorded as an
    #: error of kind "timeout" and the run goes on. Not part of the identity.
    episode_timeout_s: float | None = DEFAULT_EPISODE_TIMEOUT_S
    #: Stop the run after this many consecutive transport-error episodes (0: never).
    max_transport_failures: int = DEFAULT_MAX_TRANSPORT_FAILURES
    #: Wall-clock limit of this invocation (None: none): no new work after it, workers stopped.
    deadline_s: float | None = None
    #: What policies observe: the exact state, or what the simulated depth cameras
    #: perceive under the ``noise`` preset. Part of the identity when not exact.
    observation: ObservationMode = "exact"
    #: How placements are executed: exactly, or with the ``noise`` preset's robot noise (mujoco
    #: backend only). Part of the identity when not exact.
    execution: ExecutionMode = "exact"
    #: The sensor and robot noise preset of the two modes above (``packlab.sim.modes``).
    noise: NoisePreset = DEFAULT_NOISE
    #: Perceived observation: how the buffer's boxes are told apart, from the depth image (as
    #: a robot must) or by the simulator's masks (``truth``, an ablation). Part of the identity
    #: of perceived runs.
    segmentation: Segmentation = DEFAULT_SEGMENTATION
    #: Perceived observation: what perception assumes of box sizes. ``grid`` (the default)
    #: snaps lengths and widths to the container's cell and heights to its height step, the
    #: grids every generated case's sizes lie on (a prior of the generator, not of real
    #: cartons); ``none`` shows the raw estimates rounded to whole millimetres. Part of the
    #: identity of perceived runs.
    size_prior: SizePrior = DEFAULT_SIZE_PRIOR
    #: Exact observation: how a box's sides are named, longer side first (as perception does:
    #: no hint of the layout's orientation) or as the catalogue does (the reference paper's
    #: protocol). Always part of the identity; a run directory without it used the catalogue's.
    sides: SideNames = DEFAULT_SIDES
    #: Whether observations carry ``remaining`` (``core.choices.RemainingMode``): part of the
    #: identity when hidden.
    remaining: RemainingMode = DEFAULT_REMAINING
    #: The episode protocol (``packlab.core.packing_protocol``): packlab's ``buffer``
    #: or the field's ``online`` (see ``lookahead`` boxes in arrival order, place the first).
    #: Always part of the identity; a run directory without it used ``buffer``.
    protocol: EpisodeProtocol = DEFAULT_PROTOCOL
    #: Online protocol: how many boxes are shown (1: BPP-1). Part of the identity there.
    lookahead: int = DEFAULT_LOOKAHEAD

    def __post_init__(self) -> None:
        if not self.seeds:
            raise ConfigError("seeds: give at least one run seed")
        if len(self.seeds) > MAX_SEEDS:
            raise ConfigError(f"seeds: {len(self.seeds)} seeds; at most {MAX_SEEDS} per run")
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s <= MAX_SEED_VALUE:
                raise ConfigError(f"seeds: {s!r} is not a non-negative integer <= {MAX_SEED_VALUE}")
        if len(set(self.seeds)) != len(self.seeds):
            raise ConfigError(f"seeds = {list(self.seeds)}: a seed is repeated")
        require_choice(self.backend, PhysicsBackend, "backend")
        require_choice(self.executor, Executor, "executor")
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 0:
            raise ConfigError(
                f"workers = {self.workers!r}: must be a whole number >= 0 (0 = all cores)"
            )
        if self.workers > MAX_WORKERS:
            raise ConfigError(f"workers = {self.workers}: at most {MAX_WORKERS}")
        check_concurrency(self.concurrency)
        _check_time_limit("episode-timeout", self.episode_timeout_s)
        _check_time_limit("deadline", self.deadline_s)
        n = self.max_transport_failures
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ConfigError(
                f"max-transport-failures = {n!r}: must be a whole number >= 0 (0 = never stop)"
            )
        if len(set(self.policies)) != len(self.policies):
            raise ConfigError(f"policies = {','.join(self.policies)}: a policy is repeated")
        if self.policies:
            # The registry loads the built-in policies (numpy and more): only when names are given.
            known = policy_names()
            for name in self.policies:
                if name not in known:
                    raise ConfigError(
                        f"policies: {name!r} is not a registered policy"
                        f"{did_you_mean(name, known)}; available: {', '.join(known)}"
                    )
        if len(set(self.difficulties)) != len(self.difficulties):
            raise ConfigError(
                f"difficulty = {','.join(self.difficulties)}: a difficulty is repeated"
            )
        for name, key, _ in self.policy_args:
            if self.policies and name not in self.policies:
                raise ConfigError(
                    f"policy-arg {name}:{key}: policy {name!r} is not among the policies to run"
                )
        _check_sensing(self)
        if self.via_cell is not None and self.observation != "perceived":
            raise ConfigError(
                f"via-cell = {self.via_cell!r}: the service sees only depth images; add "
                "--observation perceived (with --execution noisy: the honest robot path)"
            )
        if self.via_cell is not None and self.segmentation != "depth":
            raise ConfigError(
                f"via-cell = {self.via_cell!r}: the service segments the buffer from depth; "
                "drop --segmentation truth"
            )
        self.packing_protocol()  # ConfigError for an unknown name or a stray --lookahead
        if self.protocol == "online" and self.observation != "exact":
            raise ConfigError(
                "protocol = 'online': exact observation only (a camera shows the buffer as a "
                "pile, not as a queue); drop --observation perceived"
            )
        if self.physics_overrides and self.backend != "mujoco":
            raise ConfigError(
                f"physics = {dict(self.physics_overrides)!r}: "
                "only the mujoco backend has physics settings"
            )

    def packing_protocol(self) -> PackingProtocol:
        """The protocol episodes follow, as one typed value."""
        return PackingProtocol(self.protocol, self.lookahead)


def policy_names() -> list[str]:
    """Every policy name that can be made, without importing ``packlab.policies`` (its package
    loads numpy: a quarter of a second before a typo's one-line error). A policy registered at
    run time (``register_policy``) lives in an already imported registry, which then answers;
    otherwise the entry points are the whole list."""
    registry = sys.modules.get(POLICY_REGISTRY)
    if registry is not None:
        return list(registry.available_policies())
    return sorted({ep.name for ep in entry_points(group=POLICY_ENTRY_POINTS)})


def _check_sensing(config: RunConfig) -> None:
    """The sensing modes: known names, noise only where a mode uses it, noisy on mujoco."""
    require_choice(config.observation, ObservationMode, "observation")
    require_choice(config.execution, ExecutionMode, "execution")
    require_choice(config.noise, NoisePreset, "noise")
    require_choice(config.segmentation, Segmentation, "segmentation")
    require_choice(config.sides, SideNames, "sides")
    require_choice(config.remaining, RemainingMode, "remaining")
    require_choice(config.size_prior, SizePrior, "size-prior")
    if config.observation == "perceived" and config.sides != "longer-first":
        raise ConfigError(
            f"sides = {config.sides!r}: perceived observation always names sides longer first "
            "(a camera cannot see which side a catalogue calls l)"
        )
    if config.observation == "exact" and config.segmentation != DEFAULT_SEGMENTATION:
        raise ConfigError(
            f"segmentation = {config.segmentation!r}: only used with --observation perceived"
        )
    if config.observation == "exact" and config.size_prior != DEFAULT_SIZE_PRIOR:
        raise ConfigError(
            f"size-prior = {config.size_prior!r}: only used with --observation perceived "
            "(exact observation shows the true sizes)"
        )
    if config.execution == "noisy" and config.backend != "mujoco":
        raise ConfigError(
            f"execution = 'noisy': the {config.backend} backend places boxes on whole cells "
            "and cannot execute noisy drops; use --backend mujoco"
        )
    exact = config.observation == "exact" and config.execution == "exact"
    if exact and config.noise != DEFAULT_NOISE:
        raise ConfigError(
            f"noise = {config.noise!r}: only used with --observation perceived or --execution noisy"
        )


def check_out_dir(out: Path) -> None:
    """ConfigError unless ``out`` is a directory or can be created as one (checked before
    anything is written, so a bad --out leaves no half-made run behind)."""
    if out.exists() and not out.is_dir():
        raise ConfigError(
            f"out = {str(out)!r}: exists and is not a directory; give a directory "
            f"(an existing run directory is resumed)"
        )
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ConfigError(f"out = {str(out)!r}: {str(parent)!r} is a file, not a directory")
            if not os.access(parent, os.W_OK | os.X_OK) and not out.exists():
                raise ConfigError(
                    f"out = {str(out)!r}: cannot create it, {str(parent)!r} is not writable"
                )
            return


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
            raise ConfigError(
                f"policy-arg = {item!r}: expected POLICY:KEY=VALUE, e.g. vlm:model=runs/sft/final"
            )
        out.append((name.strip(), key.strip(), _typed(text)))
    return tuple(out)


__all__ = [
    "COMPARE_HTML",
    "DEFAULT_EPISODE_TIMEOUT_S",
    "DEFAULT_MAX_TRANSPORT_FAILURES",
    "DEFAULT_POLICIES",
    "DEFAULT_SIZE_PRIOR",
    "DEFAULT_SUITE",
    "LEARNED_DEFAULTS",
    "MAX_SEEDS",
    "MAX_SEED_VALUE",
    "MAX_TIME_LIMIT_S",
    "MAX_WORKERS",
    "NEEDS_PLAN",
    "REPORT_HTML",
    "RunConfig",
    "SizePrior",
    "check_out_dir",
    "parse_names",
    "parse_physics",
    "parse_policy_args",
    "parse_seeds",
    "policy_names",
    "time_limit_arg",
]
