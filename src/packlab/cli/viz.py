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
import importlib
from pathlib import Path

from packlab.core.choices import PhysicsBackend, choices
from packlab.viz.options import DEFAULT_VIEWER_URL, EPISODE_MAX_STEPS

#: Where ``viz rerun`` saves its .rrd file unless ``--out`` says: the current directory, as a
#: download would; writing into the bench run's directory (as it once did) left a user looking
#: for the file and changed a run directory nobody asked to change.
RRD_DIR = Path(".")
#: What the commands do (replays, figures, Rerun recordings), imported when one runs.
RUN_MODULE = "packlab.cli.viz_run"


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
        default=EPISODE_MAX_STEPS,
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
        help="the .rrd file to save (default: CASE_POLICY_seedS.rrd in the current "
        "directory, CASE_POLICY_seedS_BACKEND.rrd with --live); with --spawn or --connect "
        "it is written only when given (docs/viewer.md)",
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


def run_episode_figure(args: argparse.Namespace) -> int:
    """``packlab viz episode``."""
    return int(importlib.import_module(RUN_MODULE).run_episode_figure(args))


def run_rerun(args: argparse.Namespace) -> int:
    """``packlab viz rerun``."""
    return int(importlib.import_module(RUN_MODULE).run_rerun(args))
