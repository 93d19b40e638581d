"""``packlab viz``: pictures of recorded episodes, and episodes sent to the Rerun viewer.

``packlab viz episode RECORDS --case ID --policy NAME [--seed S] --out PNG`` draws one packing
and the heightmap after each step. RECORDS is a bench run directory or its episodes.jsonl; the
case comes from the run's cases.jsonl (or ``--cases``), and the step heightmaps from replaying
the recorded actions (records keep actions, not heightmaps).

``packlab viz rerun RECORDS --case ID --policy NAME [--seed S]`` sends a recorded episode to the
Rerun viewer step by step, and ``packlab viz rerun --live --policy NAME --case ID [--cases
SUITE] [--backend B]`` runs a fresh episode and streams it as it is played. Without ``--spawn``
or ``--connect`` the recording is saved as an .rrd file (``rerun FILE.rrd`` opens it); with
them it is streamed to a viewer, and saved instead when no viewer can be reached. Needs the
``viewer`` extra (rerun-sdk). docs/viewer.md shows what a recording holds.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
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
)
from packlab.bench.records import CASES_FILE, CONFIG_FILE, EPISODES_FILE, iter_ok, read_records
from packlab.bench.replay import replay_record
from packlab.cases import load_cases
from packlab.core.choices import PhysicsBackend, choices
from packlab.core.errors import ConfigError
from packlab.core.records import EpisodeOk
from packlab.core.types import Case
from packlab.policies import make_policy
from packlab.viz.plots import save_figure
from packlab.viz.render import episode_figure
from packlab.viz.rerun_export import DEFAULT_VIEWER_URL, Exported, ViewerTarget
from packlab.viz.rerun_export import export_live as rerun_live
from packlab.viz.rerun_export import export_replay as rerun_replay

#: Heightmap tiles drawn at most: episode_figure's own default, stated there.
MAX_STEPS = inspect.signature(episode_figure).parameters["max_steps"].default
#: Where ``viz rerun --live`` saves its .rrd files unless told (records go beside their run).
LIVE_RRD_DIR = Path("runs") / "rerun"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="viz_command", required=True)
    _add_episode_parser(sub)
    _add_rerun_parser(sub)


def _add_episode_parser(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser(
        "episode",
        help="one packing and its step-by-step heightmaps",
        description="Draw one recorded episode: the final packing in 3D and the heightmap "
        "after each step, replayed from the recorded actions.",
    )
    _add_record_options(e)
    e.add_argument("--out", required=True, help="PNG file to write")
    e.add_argument(
        "--max-steps",
        type=int,
        default=MAX_STEPS,
        help="heightmap tiles at most (default %(default)s)",
    )
    e.set_defaults(func=run_episode_figure)


def _add_record_options(p: argparse.ArgumentParser, live: bool = False) -> None:
    """RECORDS, --case, --policy, --seed and --cases: which episode."""
    p.add_argument(
        "records",
        nargs="?" if live else None,
        help="a bench run directory or its episodes.jsonl" + (" (not with --live)" if live else ""),
    )
    p.add_argument("--case", required=True, help="episode id of the case")
    p.add_argument(
        "--policy",
        *(["--policies"] if live else []),
        required=True,
        help="policy name as recorded" + (" (with --live: the one to run)" if live else ""),
    )
    p.add_argument(
        "--seed",
        type=int,
        help="run seed (default: the smallest recorded"
        + ("; with --live the bench's first default seed)" if live else ")"),
    )
    p.add_argument(
        "--cases",
        help="case file holding the case (default: cases.jsonl beside the records"
        + (
            "; with --live a bundled suite name or case file, default the bench's)" if live else ")"
        ),
    )


def _add_rerun_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "rerun",
        help="send an episode to the Rerun viewer, or save it as an .rrd file",
        description="Send a recorded episode (RECORDS), or a live one (--live), to the Rerun "
        "viewer step by step: boxes at their settled poses, the buffer, the chosen action, "
        "the heightmap and the policy's latency on a 'step' timeline. Saves an .rrd file "
        "unless --spawn or --connect streams it to a viewer. Needs the viewer extra.",
    )
    _add_record_options(r, live=True)
    r.add_argument(
        "--resimulate",
        action="store_true",
        help="step a record's actions again on its backend even when it holds per-step poses",
    )
    r.add_argument("--live", action="store_true", help="run the policy now and stream it")
    r.add_argument(
        "--backend",
        choices=choices(PhysicsBackend),
        help="with --live: the transition backend (default: the bench's)",
    )
    r.add_argument(
        "--physics",
        action="append",
        metavar="KEY=VALUE",
        help="with --live on mujoco: change a PhysicsConfig field (repeatable)",
    )
    r.add_argument(
        "--policy-arg",
        action="append",
        metavar="POLICY:KEY=VALUE",
        help="with --live: a policy factory argument, e.g. vlm:model=runs/sft/final",
    )
    r.add_argument(
        "--out",
        help="the .rrd file (default: RUN/rerun/CASE_POLICY_seedS.rrd for records, "
        f"{LIVE_RRD_DIR}/CASE_POLICY_seedS_BACKEND.rrd with --live); with --spawn or "
        "--connect it is written as well",
    )
    view = r.add_mutually_exclusive_group()
    view.add_argument("--spawn", action="store_true", help="start a viewer and stream to it")
    view.add_argument(
        "--connect",
        nargs="?",
        const=DEFAULT_VIEWER_URL,
        metavar="URL",
        help=f"stream to a running viewer (default URL {DEFAULT_VIEWER_URL})",
    )
    r.set_defaults(func=run_rerun)


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
    if record.backend == "mujoco" and cfg_path.is_file():
        # Replay with the engine settings the run was scored with.
        physics = physics_from_json(json.loads(cfg_path.read_text(encoding="utf-8")).get("physics"))
    return RecordedEpisode(record, case, physics, episodes, run_dir)


def run_episode_figure(args: argparse.Namespace) -> int:
    found = _recorded_episode(args)
    record, case = found.record, found.case
    replay = replay_record(case, record, found.physics)
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
    target = _viewer_target(args, found.run_dir / "rerun" / name)
    return rerun_replay(
        found.case, record, target, str(found.episodes), found.physics, args.resimulate
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
    default_out = LIVE_RRD_DIR / f"{args.case}_{args.policy}_seed{seed}_{config.backend}.rrd"
    target = _viewer_target(args, default_out)
    run = resolve(dataclasses.replace(config, out=str(target.out.parent)))
    case = next((c for c in run.cases if c.episode_id == args.case), None)
    if case is None:
        raise ConfigError(f"cases = {run.source.origin!r}: no case with episode_id {args.case!r}")
    policy = make_policy(args.policy, **run.policy_kwargs().get(args.policy, {}))
    return rerun_live(case, policy, args.policy, target, seed, config.backend, run.physics_config())
