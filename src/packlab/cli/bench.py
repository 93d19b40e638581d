"""``packlab bench``: run the benchmark (resumable), describe a suite, or rebuild a run's report.

Exit codes (packlab.core.errors): 0 every planned episode has an ok record; 1 the run finished but
some episodes of this configuration ended in error (the count is on the last line of stderr);
2 bad input, nothing run; 3 the run stopped early (circuit breaker, --deadline), records kept
and the table written for what finished; 130 interrupted.

This module holds the flags only (light: ``packlab bench --help`` loads no engine); what the
commands do is :mod:`packlab.cli.bench_run`, imported when one runs.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from functools import partial

from packlab.bench.options import (
    COMPARE_HTML,
    DEFAULT_POLICIES,
    MAX_SEEDS,
    NEEDS_PLAN,
    RunConfig,
    parse_names,
    parse_physics,
    parse_policy_args,
    parse_seeds,
    time_limit_arg,
)
from packlab.cli.bench_checks import check_before_loading, check_cases
from packlab.cli.options import add_field, config_kwargs

#: What the commands do (runner, reports, comparisons), imported when one of them runs.
RUN_MODULE = "packlab.cli.bench_run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run every (case, policy, seed) episode, append records to OUT/episodes.jsonl and "
        "write summary.json, table.md and figures. Rerun the same command to resume."
    )
    _add_case_options(p)
    _add_run_options(p)
    _add_cell_options(p)
    _add_limit_options(p)
    _add_sensing_options(p)
    _add_protocol_options(p)
    p.add_argument("--describe", action="store_true", help="print the cases' statistics and exit")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    add_wide(p)
    p.add_argument(
        "--no-html",
        action="store_true",
        help="skip report.html, the interactive report (written by default)",
    )
    p.set_defaults(func=run)
    _add_subcommands(p)


def add_wide(p: argparse.ArgumentParser) -> None:
    """``--wide``: print the whole table (as table.md) rather than the 120-column view."""
    p.add_argument(
        "--wide",
        action="store_true",
        help="print the whole table (SR, Compactness and intervals per level, run details), "
        "as table.md has it; default: Overall per level and Average Overall with its interval, "
        "best first, in 120 columns",
    )


def _add_case_options(p: argparse.ArgumentParser) -> None:
    """What is run: cases, policies, seeds, backend, difficulties."""
    add_field(
        p,
        RunConfig,
        "cases",
        "--cases",
        help="a bundled suite name, a case file (JSON, JSONL, reference parquet) or a "
        "reference benchmark directory (<dir>/<difficulty>/test.parquet); "
        "default {default}",
    )
    add_field(
        p,
        RunConfig,
        "policies",
        "--policies",
        parse=partial(parse_names, flag="policies"),
        help=policies_help(),
    )
    add_field(
        p,
        RunConfig,
        "seeds",
        "--seeds",
        parse=parse_seeds,
        help=f"run seeds, e.g. 0,1,2 or 0-4 (default {{default}}; at most {MAX_SEEDS})",
    )
    add_field(p, RunConfig, "backend", "--backend", help="transition backend; default {default}")
    add_field(
        p,
        RunConfig,
        "difficulties",
        "--difficulty",
        parse=partial(parse_names, flag="difficulty"),
        help="comma-separated difficulties to run (default: all)",
    )


def policies_help() -> str:
    """``--policies``' help, read from the default list itself (it once said "every heuristic,
    random, oracle" while the default ran eleven methods)."""
    return (
        f"comma-separated policy names (default: {', '.join(DEFAULT_POLICIES)}; "
        f"{NEEDS_PLAN} only when every case has its perfect plan)"
    )


def _add_sensing_options(p: argparse.ArgumentParser) -> None:
    """The robot-cell modes: perceived observations and noisy execution (part of the identity)."""
    add_field(
        p,
        RunConfig,
        "observation",
        "--observation",
        help="what policies observe: the exact state or what simulated depth cameras "
        "perceive (under --noise); default {default}",
    )
    add_field(
        p,
        RunConfig,
        "execution",
        "--execution",
        help="execute placements exactly or with --noise's robot noise (mujoco only); "
        "default {default}",
    )
    add_field(
        p,
        RunConfig,
        "noise",
        "--noise",
        help="sensor and robot noise preset of the two modes above; default {default}",
    )
    add_field(
        p,
        RunConfig,
        "segmentation",
        "--segmentation",
        help="with --observation perceived: tell the buffer's boxes apart from the depth image "
        "(as a robot must) or by the simulator's masks (truth, an ablation); default {default}",
    )
    add_field(
        p,
        RunConfig,
        "size_prior",
        "--size-prior",
        help="with --observation perceived: what perception assumes of box sizes; grid: "
        "lengths and widths snap to the container's cell (25 mm), heights to its height step "
        "(2 mm), the grids every generated case lies on (a prior real cartons do not share); "
        "none: the raw estimates rounded to the nearest whole mm (ties to even); "
        "default {default}",
    )
    add_field(
        p,
        RunConfig,
        "sides",
        "--sides",
        help="exact observation: name a box's sides longer side first, as perception does, or "
        "as the catalogue does (catalogue: the reference paper's protocol; the suites' generator "
        "names l after the side a box lies along x in its perfect layout, a hint no robot has); "
        "perceived observation always names them longer first; default {default}",
    )
    add_field(
        p,
        RunConfig,
        "remaining",
        "--remaining",
        help="whether observations carry the count of boxes still to come (an extension of "
        "the reference's observation: a robot cell knows its order's size; hidden: the "
        "ablation without it); default {default}",
    )


def _add_protocol_options(p: argparse.ArgumentParser) -> None:
    """The episode protocol: packlab's buffered one or the field's online one (in the identity)."""
    add_field(
        p,
        RunConfig,
        "protocol",
        "--protocol",
        help="buffer: the case's buffer_size boxes shown shuffled, place any (packlab's); "
        "online: the next --lookahead boxes shown in arrival order, place the first, the "
        "episode ends at the first box that fits nowhere (the field's BPP-1 / BPP-k); "
        "offline: every box shown, place any (the reference that measures what the buffer or "
        "the online protocol costs); default {default}",
    )
    add_field(
        p,
        RunConfig,
        "lookahead",
        "--lookahead",
        help="with --protocol online: boxes shown, in arrival order (1: BPP-1); default {default}",
    )


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """Where and how it runs: output, workers, executor, policy and physics settings, retries."""
    add_field(
        p,
        RunConfig,
        "out",
        "--out",
        help="run directory (default runs/bench-<suite>, plus -perceived/-noisy and the noise "
        "preset when those modes are on, -catalogue with --sides catalogue); an existing one "
        "is resumed",
    )
    add_field(
        p,
        RunConfig,
        "workers",
        "--workers",
        help="parallel workers (0 = all local cores; 1 = in this process); default {default}",
    )
    add_field(
        p,
        RunConfig,
        "executor",
        "--executor",
        help="where episodes run: a local process pool or Ray (needs the ray extra); "
        "default {default}",
    )
    add_field(
        p,
        RunConfig,
        "concurrency",
        "--concurrency",
        metavar="N",
        help="episodes each worker runs at once, one thread each: a served model then sees up "
        "to workers x N requests to batch (not part of the run's identity); default {default}",
    )
    add_field(
        p,
        RunConfig,
        "policy_args",
        "--policy-arg",
        parse=parse_policy_args,
        action="append",
        metavar="POLICY:KEY=VALUE",
        help="a policy factory argument, e.g. vlm:model=runs/sft/final (repeatable)",
    )
    add_field(
        p,
        RunConfig,
        "physics_overrides",
        "--physics",
        parse=parse_physics,
        action="append",
        metavar="KEY=VALUE",
        help="change a mujoco PhysicsConfig field for this run (repeatable; part of the "
        "run's identity)",
    )
    add_field(
        p,
        RunConfig,
        "retry_errors",
        "--retry-errors",
        help="rerun episodes recorded as failed (transport errors are rerun anyway)",
    )
    add_field(
        p,
        RunConfig,
        "reuse",
        "--no-reuse",
        help="play every seed: by default a policy that plays the same episode for every run "
        "seed (exact modes; e.g. the heuristics and the oracle) is played for the lowest seed "
        "and copied to the others",
    )


def _add_cell_options(p: argparse.ArgumentParser) -> None:
    """Where the policies play: in the bench's processes, or in a running cell service."""
    add_field(
        p,
        RunConfig,
        "via_cell",
        "--via-cell",
        metavar="URL",
        help="play the policies through the cell service at URL (started with `packlab cell "
        "serve`; needs the cell extra): each step sends only the rendered depth images and "
        "camera calibrations, and the answer is carried out here; needs --observation "
        "perceived; the records are the in-process run's but where the policy breaks a tie "
        "by the order boxes are listed in (docs/cell.md); not part of the run's identity",
    )


def _add_limit_options(p: argparse.ArgumentParser) -> None:
    """Time limits, the circuit breaker and the progress bar."""
    add_field(
        p,
        RunConfig,
        "episode_timeout_s",
        "--episode-timeout",
        type=float,
        parse=time_limit_arg,
        metavar="SECONDS",
        help="wall-clock limit of one episode, recorded as an error of kind timeout "
        "(default {default}; 0 = none)",
    )
    add_field(
        p,
        RunConfig,
        "max_transport_failures",
        "--max-transport-failures",
        metavar="N",
        help="stop the run after N consecutive episodes whose model server was unreachable "
        "(default {default}; 0 = never)",
    )
    add_field(
        p,
        RunConfig,
        "deadline_s",
        "--deadline",
        type=float,
        parse=time_limit_arg,
        metavar="SECONDS",
        help="stop this invocation after SECONDS (records kept, exit code 3; rerun to "
        "resume); default {default}",
    )
    add_field(p, RunConfig, "progress", "--no-progress", help="no progress bar on stderr")


def _add_subcommands(p: argparse.ArgumentParser) -> None:
    """``bench report`` and ``bench compare``."""
    sub = p.add_subparsers(dest="bench_command", metavar="{report,compare}")
    _add_report_parser(sub)
    _add_compare_parser(sub)


def _add_report_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser(
        "report",
        help="rebuild summary, table and figures of a run from its records",
        description="Rebuild summary.json, table.md and the figures of a run directory from "
        "its files alone (config.json, cases.jsonl, episodes.jsonl).",
    )
    r.add_argument("dir", help="a bench run directory")
    r.add_argument(
        "--case",
        help="episode id for the side-by-side packing figure (default: a typical hard case)",
    )
    r.add_argument("--seed", type=int, help="run seed of that figure (default: the first seed)")
    r.add_argument("--no-figures", action="store_true", help="tables only (no PNG figures)")
    add_wide(r)
    r.add_argument(
        "--html",
        action="store_true",
        help="also write DIR/report.html, the interactive report",
    )
    r.set_defaults(func=run_report)


def _add_compare_parser(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser(
        "compare",
        help="one table over several runs (ablations, checkpoints)",
        description="Put the results of several run directories (same cases, seeds and "
        "backend) in one table; rows are named by run.",
    )
    c.add_argument("dirs", nargs="+", help="bench run directories")
    c.add_argument("--labels", help="comma-separated row labels (default: the directory names)")
    c.add_argument("--out", help="also write the Markdown to this file (the whole table)")
    add_wide(c)
    c.add_argument(
        "--reference",
        metavar="NAME",
        help="the row the paired differences are taken against, named as the table prints it "
        "(e.g. 'runs-learned: Proposer (index 0)'); default: the first row",
    )
    c.add_argument(
        "--html",
        nargs="?",
        const="",
        metavar="FILE",
        help=f"also write the interactive report over the runs to FILE (default: --out with "
        f".html, else {COMPARE_HTML})",
    )
    c.set_defaults(func=run_compare)


def config_from_args(args: argparse.Namespace) -> RunConfig:
    """The RunConfig the flags describe; a flag left out leaves the field's default."""
    return RunConfig(**config_kwargs(args, "bench", RunConfig))


def run(args: argparse.Namespace) -> int:
    """``packlab bench``: run (or ``--describe``) the cases; the exit code says how it ended."""
    # Every flag checked here, before RUN_MODULE's imports (engine, reports: seconds) and before
    # anything is written: a typo costs a fraction of a second, not a run directory.
    if args.describe:
        check_cases(args.cases)
    else:
        check_before_loading(config_from_args(args))
    return int(importlib.import_module(RUN_MODULE).run(args))


def run_report(args: argparse.Namespace) -> int:
    """``packlab bench report DIR``."""
    return int(importlib.import_module(RUN_MODULE).run_report(args))


def run_compare(args: argparse.Namespace) -> int:
    """``packlab bench compare DIR...``."""
    return int(importlib.import_module(RUN_MODULE).run_compare(args))


if __name__ == "__main__":  # pragma: no cover
    from packlab.cli.main import main

    sys.exit(main(["bench", *sys.argv[1:]]))
