"""``packlab viz``: pictures of recorded episodes.

``packlab viz episode RECORDS --case ID --policy NAME [--seed S] --out PNG`` draws one packing
and the heightmap after each step. RECORDS is a bench run directory or its episodes.jsonl; the
case comes from the run's cases.jsonl (or ``--cases``), and the step heightmaps from replaying
the recorded actions (records keep actions, not heightmaps).
"""

from __future__ import annotations

import argparse
import inspect
import json
import sys
from pathlib import Path

from packlab.bench.config import physics_from_json
from packlab.bench.records import CASES_FILE, CONFIG_FILE, EPISODES_FILE, iter_ok, read_records
from packlab.bench.replay import replay_record
from packlab.cases import load_cases
from packlab.core.errors import ConfigError
from packlab.viz.plots import save_figure
from packlab.viz.render import episode_figure

#: Heightmap tiles drawn at most: episode_figure's own default, stated there.
MAX_STEPS = inspect.signature(episode_figure).parameters["max_steps"].default


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("viz", help="draw recorded episodes")
    sub = p.add_subparsers(dest="viz_command", required=True)
    e = sub.add_parser(
        "episode",
        help="one packing and its step-by-step heightmaps",
        description="Draw one recorded episode: the final packing in 3D and the heightmap "
        "after each step, replayed from the recorded actions.",
    )
    e.add_argument("records", help="a bench run directory or its episodes.jsonl")
    e.add_argument("--case", required=True, help="episode id of the case")
    e.add_argument("--policy", required=True, help="policy name as recorded")
    e.add_argument("--seed", type=int, help="run seed (default: the smallest recorded)")
    e.add_argument(
        "--cases", help="case file holding the case (default: cases.jsonl beside the records)"
    )
    e.add_argument("--out", required=True, help="PNG file to write")
    e.add_argument(
        "--max-steps",
        type=int,
        default=MAX_STEPS,
        help="heightmap tiles at most (default %(default)s)",
    )
    e.set_defaults(func=run_episode_figure)


def _paths(records: str) -> tuple[Path, Path]:
    path = Path(records)
    if path.is_dir():
        return path / EPISODES_FILE, path
    return path, path.parent


def run_episode_figure(args: argparse.Namespace) -> int:
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
    replay = replay_record(case, record, physics)
    if not replay.matches_record:
        print(
            f"packlab viz: warning: the replay scored Overall {replay.overall:.4f}, the record "
            f"{record.metrics.overall:.4f}; the engine or its settings differ from the run's",
            file=sys.stderr,
        )
    path = save_figure(episode_figure(case, record, replay.heightmaps, args.max_steps), args.out)
    print(f"wrote {path}")
    return 0
