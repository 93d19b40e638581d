"""What ``packlab bench``, ``bench report`` and ``bench compare`` do once their flags are parsed
(:mod:`packlab.cli.bench` defines the flags and imports this module when a command runs).

Exit codes (packlab.core.errors): 0 every planned episode has an ok record; 1 the run finished but
some episodes of this configuration ended in error (the count is on the last line of stderr);
2 bad input, nothing run; 3 the run stopped early (circuit breaker, --deadline), records kept
and the table written for what finished; 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from packlab.bench.compare import (
    compare_markdown,
    differences_markdown,
    load_summary,
    merge_summaries,
)
from packlab.bench.describe import describe_cases, format_description
from packlab.bench.html_report import build_html_report, write_compare_html
from packlab.bench.options import COMPARE_HTML, REPORT_HTML
from packlab.bench.report import TABLE_FILE, build_report
from packlab.bench.runner import BenchOutcome, run_bench
from packlab.bench.suites import resolve_cases
from packlab.bench.table import render_markdown
from packlab.bench.terminal import terminal_text
from packlab.cli.bench import config_from_args
from packlab.core.errors import EXIT_ABORTED, EXIT_EPISODE_ERRORS, EXIT_OK, ConfigError


def describe(cases: str) -> int:
    source = resolve_cases(cases)
    print(
        format_description(
            f"{source.label} ({source.origin}, sha256 {source.sha256[:12]}...)",
            describe_cases(source.cases),
        )
    )
    return 0


def run(args: argparse.Namespace) -> int:
    if args.describe:
        return describe(args.cases)
    config = config_from_args(args)  # every flag checked before anything is loaded or written
    outcome = run_bench(config, figures=not args.no_figures, html=not args.no_html)
    wide = getattr(args, "wide", False)
    print(
        outcome.table_md
        if wide
        else terminal_text(outcome.summary, table_file=outcome.run_dir / TABLE_FILE)
    )
    # The report's path and any note first: the run's line and the exit reason stay the last.
    for path in outcome.outputs:
        if path.name == REPORT_HTML:
            print(f"interactive report: {path}", file=sys.stderr)
    for note in outcome.notes:
        print(f"packlab bench: note: {note}", file=sys.stderr)
    resumed = f", {outcome.already_done} already done" if outcome.already_done else ""
    failed = f", {outcome.failed} failed" if outcome.failed else ""
    # Copies of a seed-free policy's episode (packlab.bench.reuse), written instead of played.
    reused = f" ({outcome.reused} copied from another seed)" if outcome.reused else ""
    print(
        f"{outcome.run_dir}: {outcome.ran} episodes run{reused} in {outcome.wall_s:.1f} s"
        f"{resumed}{failed}; "
        f"{len(outcome.outputs)} outputs written",
        file=sys.stderr,
    )
    code, last_line = exit_status(outcome)
    if last_line:
        print(last_line, file=sys.stderr)
    return code


def exit_status(outcome: BenchOutcome) -> tuple[int, str]:
    """The exit code of a finished bench invocation and the line that explains it ("" for 0)."""
    episodes = outcome.run_dir / "episodes.jsonl"
    if outcome.aborted:
        return EXIT_ABORTED, (
            f"packlab bench: error: {outcome.aborted}; {outcome.recorded} of {outcome.planned} "
            f"episodes recorded (kept in {episodes}); rerun the same command to resume"
        )
    if outcome.recorded < outcome.planned:  # cannot happen unless an executor stopped silently
        return EXIT_ABORTED, (
            f"packlab bench: error: {outcome.planned - outcome.recorded} of {outcome.planned} "
            f"episodes have no record; rerun the same command to resume"
        )
    if outcome.errors:
        return EXIT_EPISODE_ERRORS, (
            f"packlab bench: {outcome.errors} of {outcome.planned} episodes ended in error "
            f"(see {episodes}; rerun with --retry-errors)"
        )
    return EXIT_OK, ""


def run_report(args: argparse.Namespace) -> int:
    summary, table_md, paths = build_report(
        args.dir, figures=not args.no_figures, case_id=args.case, seed=args.seed
    )
    if args.html:
        paths.append(build_html_report(args.dir))
    table_file = Path(args.dir) / TABLE_FILE
    print(
        table_md if getattr(args, "wide", False) else terminal_text(summary, table_file=table_file)
    )
    for path in paths:
        print(f"wrote {path}", file=sys.stderr)
    return 0


def compare_text(
    dirs: list[str], labels: list[str] | None, reference: str | None, wide: bool = True
) -> str:
    """The comparison's Markdown, its paired differences against ``reference`` (a row as the
    table names it; None: the first row). A name that is no row is a ConfigError naming the
    flag and the rows. ``wide=False``: the 120-column results table a terminal prints."""
    if reference is None and wide:
        return compare_markdown(dirs, labels)
    names = labels if labels else [Path(d).name for d in dirs]
    merged = merge_summaries([load_summary(d) for d in dirs], names)
    if reference is not None and reference not in merged.policies:
        rows = ", ".join(repr(r) for r in merged.policies)
        raise ConfigError(f"--reference {reference!r}: not a row of this comparison; rows: {rows}")
    text = render_markdown(merged) if wide else terminal_text(merged)
    diffs = differences_markdown(merged, reference)
    return f"{text}\n{diffs}" if diffs else text


def run_compare(args: argparse.Namespace) -> int:
    labels = [x.strip() for x in args.labels.split(",")] if args.labels else None
    out = Path(args.out) if args.out else None
    if out is not None and out.is_dir():  # checked before the work, not after it
        raise ConfigError(f"out = {args.out!r}: is a directory; give the Markdown file to write")
    text = compare_text(args.dirs, labels, args.reference)
    html = None
    if args.html is not None:
        html = Path(args.html or (out.with_suffix(".html") if out is not None else COMPARE_HTML))
        html = write_compare_html(args.dirs, html, labels)
    wide = getattr(args, "wide", False)
    print(text if wide else compare_text(args.dirs, labels, args.reference, wide=False))
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
    if html is not None:
        print(f"wrote {html}", file=sys.stderr)
    return 0
