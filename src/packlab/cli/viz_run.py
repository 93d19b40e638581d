"""What ``packlab viz episode`` and ``viz rerun`` do (:mod:`packlab.cli.viz` defines their flags
and imports this module when one runs)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from packlab.bench.config import (
    RunConfig,
    parse_physics,
    parse_policy_args,
    physics_from_json,
    resolve,
    run_sides,
)
from packlab.bench.records import CASES_FILE, CONFIG_FILE, EPISODES_FILE, iter_ok, read_records
from packlab.bench.replay import replay_record
from packlab.cases import load_cases
from packlab.cli.viz import RRD_DIR
from packlab.core.choices import DEFAULT_SIDES, SideNames
from packlab.core.errors import ConfigError
from packlab.core.packing_protocol import BUFFER, PackingProtocol, saved_protocol
from packlab.core.records import EpisodeOk
from packlab.core.types import Case
from packlab.policies import make_policy
from packlab.viz.plots import save_figure
from packlab.viz.render import episode_figure
from packlab.viz.rerun_export import Exported, ViewerTarget
from packlab.viz.rerun_export import export_live as rerun_live
from packlab.viz.rerun_export import export_replay as rerun_replay


def _paths(records: str) -> tuple[Path, Path]:
    path = Path(records)
    if path.is_dir():
        return path / EPISODES_FILE, path
    return path, path.parent


@dataclasses.dataclass(frozen=True)
class RecordedEpisode:
    """One finished record with its case and the engine settings it was scored with."""

    record: EpisodeOk
    case: Case
    physics: Any  # PhysicsConfig of a mujoco run (None: geometric, or no config.json)
    episodes: Path
    run_dir: Path
    #: The side names the run showed (its config.json; none: this version's default).
    sides: SideNames = DEFAULT_SIDES
    #: The protocol it ran under (its config.json; none: the buffer protocol).
    protocol: PackingProtocol = BUFFER


def _recorded_episode(args: argparse.Namespace) -> RecordedEpisode:
    episodes, run_dir = _paths(args.records)
    if not episodes.is_file():
        raise ConfigError(f"records = {args.records!r}: no {episodes.name} there")
    mine = [
        r
        for r in iter_ok(read_records(episodes))
        if r.case_id == args.case and r.policy == args.policy
    ]
    if args.seed is not None:
        mine = [r for r in mine if r.seed == args.seed]
    if not mine:
        raise ConfigError(
            f"{episodes}: no finished record of case {args.case!r}, policy {args.policy!r}"
            + (f", seed {args.seed}" if args.seed is not None else "")
        )
    record = min(mine, key=lambda r: r.seed)
    cases_path = Path(args.cases) if args.cases else run_dir / CASES_FILE
    case = next((c for c in load_cases(cases_path) if c.episode_id == args.case), None)
    if case is None:
        raise ConfigError(f"{cases_path}: no case with episode_id {args.case!r}")
    physics = None
    cfg_path = run_dir / CONFIG_FILE
    saved = json.loads(cfg_path.read_text(encoding="utf-8")) if cfg_path.is_file() else None
    if record.backend == "mujoco" and saved is not None:
        # Replay with the engine settings the run was scored with.
        physics = physics_from_json(saved.get("physics"))
    # and the side names it showed: a recorded rotation refers to them.
    return RecordedEpisode(
        record, case, physics, episodes, run_dir, run_sides(saved), saved_protocol(saved)
    )


def run_episode_figure(args: argparse.Namespace) -> int:
    found = _recorded_episode(args)
    record, case = found.record, found.case
    replay = replay_record(case, record, found.physics, found.sides, found.protocol)
    if not replay.matches_record:
        print(
            f"packlab viz: warning: the replay scored Overall {replay.overall:.4f}, the record "
            f"{record.metrics.overall:.4f}; the engine or its settings differ from the run's",
            file=sys.stderr,
        )
    path = save_figure(episode_figure(case, record, replay.heightmaps, args.max_steps), args.out)
    print(f"wrote {path}")
    return 0


def _viewer_target(args: argparse.Namespace, default_out: Path) -> ViewerTarget:
    out = Path(args.out) if args.out else default_out
    if out.suffix != ".rrd":
        raise ConfigError(f"out = {str(out)!r}: a Rerun recording file ends in .rrd")
    streams = args.spawn or args.connect is not None
    return ViewerTarget(
        out, save=not streams or args.out is not None, spawn=args.spawn, connect=args.connect
    )


def _check_mode(args: argparse.Namespace) -> None:
    """RECORDS xor --live; the engine and policy options only with --live."""
    if args.live and args.records is not None:
        raise ConfigError(
            f"records = {args.records!r}: --live runs a new episode; give one or the other"
        )
    if not args.live and args.records is None:
        raise ConfigError("give RECORDS (a bench run directory) or --live")
    live_only = {
        "--backend": args.backend,
        "--physics": args.physics,
        "--policy-arg": args.policy_arg,
    }
    given = [flag for flag, value in live_only.items() if value is not None]
    if not args.live and given:
        raise ConfigError(
            f"{', '.join(given)}: only with --live (a record replays on its own backend)"
        )
    if args.live and args.resimulate:
        raise ConfigError("--resimulate: only for records (a live episode is simulated anyway)")


def run_rerun(args: argparse.Namespace) -> int:
    _check_mode(args)
    exported = _rerun_live(args) if args.live else _rerun_record(args)
    if exported.note:
        print(f"packlab viz: note: {exported.note}", file=sys.stderr)
    if exported.exact is False:
        print(
            "packlab viz: warning: the re-simulated episode differs from the record (the engine "
            "or its settings differ from the run's); the recording shows the re-simulation",
            file=sys.stderr,
        )
    where = [f"saved {exported.saved}"] if exported.saved else []
    where += [f"streamed to {exported.streamed_to}"] if exported.streamed_to else []
    overall = "" if exported.metrics is None else f", Overall {exported.metrics.overall:.4f}"
    print(f"{' and '.join(where)}: {exported.steps} steps ({exported.method}){overall}")
    return 0


def _rerun_record(args: argparse.Namespace) -> Exported:
    found = _recorded_episode(args)
    record = found.record
    name = f"{record.case_id}_{record.policy}_seed{record.seed}.rrd"
    target = _viewer_target(args, RRD_DIR / name)
    return rerun_replay(
        found.case,
        record,
        target,
        str(found.episodes),
        found.physics,
        args.resimulate,
        found.sides,
        found.protocol,
    )


def _rerun_live(args: argparse.Namespace) -> Exported:
    # The bench's own config validates the policy, seed, backend, physics and policy
    # arguments, and resolves the case source and engine settings exactly as a bench run would.
    if "," in args.policy:
        raise ConfigError(f"policy = {args.policy!r}: one policy per recording")
    given: dict[str, Any] = {"policies": (args.policy,)}
    if args.seed is not None:
        given["seeds"] = (args.seed,)
    if args.cases is not None:
        given["cases"] = args.cases
    if args.backend is not None:
        given["backend"] = args.backend
    if args.physics:
        given["physics_overrides"] = parse_physics(args.physics)
    if args.policy_arg:
        given["policy_args"] = parse_policy_args(args.policy_arg)
    config = RunConfig(**given)
    seed = config.seeds[0]
    default_out = RRD_DIR / f"{args.case}_{args.policy}_seed{seed}_{config.backend}.rrd"
    target = _viewer_target(args, default_out)
    run = resolve(dataclasses.replace(config, out=str(target.out.parent)))
    case = next((c for c in run.cases if c.episode_id == args.case), None)
    if case is None:
        raise ConfigError(f"cases = {run.source.origin!r}: no case with episode_id {args.case!r}")
    policy = make_policy(args.policy, **run.policy_kwargs().get(args.policy, {}))
    return rerun_live(case, policy, args.policy, target, seed, config.backend, run.physics_config())
