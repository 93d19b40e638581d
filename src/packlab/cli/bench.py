"""``packlab bench``: run the benchmark (resumable), describe a suite, or rebuild a run's report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from packlab.bench.config import (
    EXEC_BACKENDS,
    TRANSITION_BACKENDS,
    RunConfig,
    parse_physics,
    parse_policy_args,
    parse_seeds,
)
from packlab.bench.suites import DEFAULT_SUITE


def _names(text: str | None) -> tuple[str, ...]:
    return () if not text else tuple(t.strip() for t in text.split(",") if t.strip())


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bench", help="run PackLab-Bench (or any case file) and print a Table-2-style table",
        description="Run every (case, policy, seed) episode, append records to OUT/episodes.jsonl and "
                    "write summary.json, table.md and figures. Rerun the same command to resume.",
    )
    p.add_argument("--cases", default=DEFAULT_SUITE,
                   help=f"a bundled suite name or a case file (JSON, JSONL, reference parquet); default {DEFAULT_SUITE}")
    p.add_argument("--policies", help="comma-separated policy names (default: every heuristic, random, oracle)")
    p.add_argument("--seeds", default="0,1,2", help="run seeds, e.g. 0,1,2 or 0-4 (default 0,1,2)")
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
    p.add_argument("--retry-errors", action="store_true", help="rerun episodes recorded as failed")
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
        policies=_names(args.policies),
        seeds=parse_seeds(args.seeds),
        backend=args.backend,
        difficulties=_names(args.difficulty),
        out=args.out or "",
        workers=args.workers,
        exec_backend=args.backend_exec,
        progress=not args.no_progress,
        retry_errors=args.retry_errors,
        physics_overrides=parse_physics(args.physics),
        policy_args=parse_policy_args(args.policy_arg),
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
    from packlab.bench.runner import run_bench

    outcome = run_bench(config_from_args(args), figures=not args.no_figures)
    print(outcome.table_md)
    resumed = f", {outcome.already_done} already done" if outcome.already_done else ""
    failed = f", {outcome.failed} failed" if outcome.failed else ""
    print(f"{outcome.run_dir}: {outcome.ran} episodes run in {outcome.wall_s:.1f} s{resumed}{failed}; "
          f"{len(outcome.outputs)} outputs written", file=sys.stderr)
    return 0


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
    text = compare_markdown(args.dirs, labels)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text, encoding="utf-8")
    return 0
