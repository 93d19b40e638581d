"""``packlab bench``: run the benchmark (resumable), describe a suite, or rebuild a run's report.

Exit codes (packlab.core.errors): 0 every planned episode has an ok record; 1 the run finished but
some episodes of this configuration ended in error (the count is on the last line of stderr);
2 bad input, nothing run; 3 the run stopped early (circuit breaker, --deadline), records kept
and the table written for what finished; 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from packlab.bench.config import (
    DEFAULT_EPISODE_TIMEOUT_S,
    DEFAULT_MAX_TRANSPORT_FAILURES,
    EXEC_BACKENDS,
    MAX_SEEDS,
    TRANSITION_BACKENDS,
    RunConfig,
    parse_names,
    parse_physics,
    parse_policy_args,
    parse_seeds,
    time_limit_arg,
)
from packlab.bench.suites import DEFAULT_SUITE
from packlab.core.errors import EXIT_ABORTED, EXIT_EPISODE_ERRORS, EXIT_OK, ConfigError

if TYPE_CHECKING:  # the runner imports the engine; load it only when a run starts
    from packlab.bench.runner import BenchOutcome


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bench", help="run PackLab-Bench (or any case file) and print a Table-2-style table",
        description="Run every (case, policy, seed) episode, append records to OUT/episodes.jsonl and "
                    "write summary.json, table.md and figures. Rerun the same command to resume.",
    )
    p.add_argument("--cases", default=DEFAULT_SUITE,
                   help=f"a bundled suite name, a case file (JSON, JSONL, reference parquet) or a reference "
                        f"benchmark directory (<dir>/<difficulty>/test.parquet); default {DEFAULT_SUITE}")
    p.add_argument("--policies", help="comma-separated policy names (default: every heuristic, random, oracle)")
    p.add_argument("--seeds", default="0,1,2",
                   help=f"run seeds, e.g. 0,1,2 or 0-4 (default 0,1,2; at most {MAX_SEEDS})")
    p.add_argument("--backend", choices=TRANSITION_BACKENDS, default="mujoco", help="transition backend")
    p.add_argument("--difficulty", help="comma-separated difficulties to run (default: all)")
    p.add_argument("--out", help="run directory (default runs/bench-<suite>); an existing one is resumed")
    p.add_argument("--workers", type=int, default=0, help="parallel workers (0 = all local cores)")
    p.add_argument("--backend-exec", choices=EXEC_BACKENDS, default="process",
                   help="where episodes run: local process pool or Ray (needs the ray extra)")
    p.add_argument("--policy-arg", action="append", default=[], metavar="POLICY:KEY=VALUE",
                   help="a policy factory argument, e.g. vlm:model=runs/sft/final (repeatable)")
    p.add_argument("--physics", action="append", default=[], metavar="KEY=VALUE",
                   help="change a mujoco PhysicsConfig field for this run (repeatable; part of the run's identity)")
    p.add_argument("--retry-errors", action="store_true",
                   help="rerun episodes recorded as failed (transport errors are rerun anyway)")
    p.add_argument("--episode-timeout", type=float, default=DEFAULT_EPISODE_TIMEOUT_S, metavar="SECONDS",
                   help=f"wall-clock limit of one episode, recorded as an error of kind timeout "
                        f"(default {DEFAULT_EPISODE_TIMEOUT_S:g}; 0 = none)")
    p.add_argument("--max-transport-failures", type=int, default=DEFAULT_MAX_TRANSPORT_FAILURES, metavar="N",
                   help=f"stop the run after N consecutive episodes whose model server was unreachable "
                        f"(default {DEFAULT_MAX_TRANSPORT_FAILURES}; 0 = never)")
    p.add_argument("--deadline", type=float, default=0, metavar="SECONDS",
                   help="stop this invocation after SECONDS (records kept, exit code 3; rerun to resume); "
                        "default none")
    p.add_argument("--describe", action="store_true", help="print the cases' statistics and exit")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.set_defaults(func=run)

    sub = p.add_subparsers(dest="bench_command", metavar="{report,compare}")
    r = sub.add_parser("report", help="rebuild summary, table and figures of a run from its records",
                       description="Rebuild summary.json, table.md and the figures of a run directory from "
                                   "its files alone (config.json, cases.jsonl, episodes.jsonl).")
    r.add_argument("dir", help="a bench run directory")
    r.add_argument("--case", help="episode id for the side-by-side packing figure (default: a typical hard case)")
    r.add_argument("--seed", type=int, help="run seed of that figure (default: the first seed)")
    r.add_argument("--no-figures", action="store_true", help="tables only")
    r.set_defaults(func=run_report)
    c = sub.add_parser("compare", help="one table over several runs (ablations, checkpoints)",
                       description="Put the results of several run directories (same cases, seeds and "
                                   "backend) in one table; rows are named by run.")
    c.add_argument("dirs", nargs="+", help="bench run directories")
    c.add_argument("--labels", help="comma-separated row labels (default: the directory names)")
    c.add_argument("--out", help="also write the Markdown to this file")
    c.set_defaults(func=run_compare)


def config_from_args(args: argparse.Namespace) -> RunConfig:
    return RunConfig(
        cases=args.cases,
        policies=parse_names(args.policies, "policies"),
        seeds=parse_seeds(args.seeds),
        backend=args.backend,
        difficulties=parse_names(args.difficulty, "difficulty"),
        out=args.out or "",
        workers=args.workers,
        exec_backend=args.backend_exec,
        progress=not args.no_progress,
        retry_errors=args.retry_errors,
        physics_overrides=parse_physics(args.physics),
        policy_args=parse_policy_args(args.policy_arg),
        episode_timeout_s=time_limit_arg(args.episode_timeout),
        max_transport_failures=args.max_transport_failures,
        deadline_s=time_limit_arg(args.deadline),
    )


def describe(cases: str) -> int:
    from packlab.bench.describe import describe_cases, format_description
    from packlab.bench.suites import resolve_cases

    source = resolve_cases(cases)
    print(format_description(f"{source.label} ({source.origin}, sha256 {source.sha256[:12]}...)",
                             describe_cases(source.cases)))
    return 0


def run(args: argparse.Namespace) -> int:
    if args.describe:
        return describe(args.cases)
    config = config_from_args(args)  # every flag checked before anything is loaded or written
    from packlab.bench.runner import run_bench

    outcome = run_bench(config, figures=not args.no_figures)
    print(outcome.table_md)
    resumed = f", {outcome.already_done} already done" if outcome.already_done else ""
    failed = f", {outcome.failed} failed" if outcome.failed else ""
    print(f"{outcome.run_dir}: {outcome.ran} episodes run in {outcome.wall_s:.1f} s{resumed}{failed}; "
          f"{len(outcome.outputs)} outputs written", file=sys.stderr)
    code, last_line = exit_status(outcome)
    if last_line:
        print(last_line, file=sys.stderr)
    return code


def exit_status(outcome: BenchOutcome) -> tuple[int, str]:
    """The exit code of a finished bench invocation and the line that explains it ("" for 0)."""
    episodes = outcome.run_dir / "episodes.jsonl"
    if outcome.aborted:
        return EXIT_ABORTED, (f"packlab bench: error: {outcome.aborted}; {outcome.recorded} of {outcome.planned} "
                              f"episodes recorded (kept in {episodes}); rerun the same command to resume")
    if outcome.recorded < outcome.planned:  # cannot happen unless an executor stopped silently
        return EXIT_ABORTED, (f"packlab bench: error: {outcome.planned - outcome.recorded} of {outcome.planned} "
                              f"episodes have no record; rerun the same command to resume")
    if outcome.errors:
        return EXIT_EPISODE_ERRORS, (f"packlab bench: {outcome.errors} of {outcome.planned} episodes ended in error "
                                     f"(see {episodes}; rerun with --retry-errors)")
    return EXIT_OK, ""


def run_report(args: argparse.Namespace) -> int:
    from packlab.bench.report import build_report

    _, table_md, paths = build_report(args.dir, figures=not args.no_figures, case_id=args.case, seed=args.seed)
    print(table_md)
    for path in paths:
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    from packlab.cli.main import main

    sys.exit(main(["bench", *sys.argv[1:]]))


def run_compare(args: argparse.Namespace) -> int:
    from packlab.bench.compare import compare_markdown

    labels = [x.strip() for x in args.labels.split(",")] if args.labels else None
    out = Path(args.out) if args.out else None
    if out is not None and out.is_dir():  # checked before the work, not after it
        raise ConfigError(f"out = {args.out!r}: is a directory; give the Markdown file to write")
    text = compare_markdown(args.dirs, labels)
    print(text)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
    return 0
