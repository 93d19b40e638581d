"""The results table as a terminal prints it: at most 120 characters a line, rows best first.

``table.md`` (``packlab.bench.table.render_markdown``) holds every column, each with its
interval: about 400 characters a row with the default 11 methods, unreadable in a terminal.
What ``packlab bench``, ``bench report`` and ``bench compare`` print by default is this view
instead: Overall per level (means), Average Overall with its 95 % interval, the spread over
seeds, rows sorted by Average Overall (the oracle, a ceiling, last). ``--wide`` prints the
whole ``table.md``. Still valid Markdown, padded so its columns line up in a monospace font.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

from packlab.bench.summary import RunIntervals, run_intervals
from packlab.bench.table import (
    format_cell,
    format_spread,
    headline,
    interval_note,
    reuse_note,
)
from packlab.core.records import Cell, RunSummary
from packlab.metrics import AVERAGE
from packlab.viz.labels import display_name, group_title

#: The widest line printed by default (a common terminal width).
WIDTH = 120
#: The row kept last whatever its score: the ground-truth plan is a ceiling, not a competitor.
CEILING = "oracle"
_ELLIPSIS = "…"


def _groups(summary: RunSummary) -> list[str]:
    groups = list(summary.difficulties)
    return groups + [AVERAGE] if len(groups) > 1 else groups


def _overall(summary: RunSummary, policy: str, group: str) -> Cell | None:
    cells = summary.table[policy].get(group)
    return None if cells is None else cells.overall


def ranked_policies(summary: RunSummary) -> list[str]:
    """Policies by their last group's Overall (Average with several levels), best first;
    unscored ones after the scored, the oracle last; ties keep the run's order."""
    groups = _groups(summary)

    def key(item: tuple[int, str]) -> tuple[bool, bool, float, int]:
        i, p = item
        cell = _overall(summary, p, groups[-1]) if groups else None
        mean = None if cell is None else cell.mean
        return (p == CEILING, mean is None, -(mean or 0.0), i)

    return [p for _, p in sorted(enumerate(summary.policies), key=key)]


def _align(rows: Sequence[Sequence[str]], left: int = 1) -> list[str]:
    """Pipe-table lines with padded columns: the first ``left`` columns left-aligned (names),
    the rest right-aligned (numbers); the second line is Markdown's alignment row."""
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    widths = [max(w, 3) for w in widths]  # room for the "---" of the alignment row

    def line(cells: Sequence[str]) -> str:
        padded = [
            c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))
        ]
        return "| " + " | ".join(padded) + " |"

    rule = ["-" * w if i < left else "-" * (w - 1) + ":" for i, w in enumerate(widths)]
    return [line(rows[0]), line(rule), *(line(r) for r in rows[1:])]


def _shorten(name: str, limit: int) -> str:
    return name if len(name) <= limit else name[: max(1, limit - 1)] + _ELLIPSIS


def compact_rows(summary: RunSummary, intervals: RunIntervals, digits: int = 3) -> list[list[str]]:
    """Header and rows: Method, Overall per level (with several levels), the last group's
    Overall with its interval, and its spread over seeds (with several seeds)."""
    groups = _groups(summary)
    if not groups:
        return [["Method"], *([display_name(p)] for p in summary.policies)]
    levels, last = groups[:-1], groups[-1]
    spread = len(summary.seeds) > 1
    header = ["Method", *(group_title(g) for g in levels), f"{group_title(last)} Overall"]
    header += ["sd over seeds"] if spread else []
    rows = [header]
    for p in ranked_policies(summary):
        flag = " *" if summary.counts[p].errors else ""
        row = [f"{display_name(p)}{flag}"]
        row += [format_cell(_overall(summary, p, g), digits) for g in levels]
        row.append(
            format_cell(_overall(summary, p, last), digits, intervals.bounds(p, last, "overall"))
        )
        row += [format_spread(_overall(summary, p, last), digits)] if spread else []
        rows.append(row)
    return rows


def compact_table(
    summary: RunSummary, intervals: RunIntervals | None = None, width: int = WIDTH
) -> str:
    """The table's lines, method names shortened (``…``) only where a line would pass
    ``width``."""
    intervals = run_intervals(summary) if intervals is None else intervals
    rows = compact_rows(summary, intervals)
    lines = _align(rows)
    over = max(len(line) for line in lines) - width
    if over > 0:  # only the names can give way: the numbers are what the table is for
        longest = max(len(r[0]) for r in rows)
        limit = max(len("Method"), longest - over)
        rows = [[_shorten(r[0], limit), *r[1:]] for r in rows]
        lines = _align(rows)
    return "\n".join(lines)


def _legend(summary: RunSummary) -> str:
    groups = _groups(summary)
    if len(groups) < 2:
        return "Rows best first."
    levels = ", ".join(group_title(g) for g in groups[:-1])
    ceiling = ", the oracle (a ceiling) last" if CEILING in summary.policies else ""
    return (
        f"{levels}: Overall per level; {group_title(groups[-1])} Overall with its interval; "
        f"rows by {group_title(groups[-1])} Overall, best first{ceiling}."
    )


def terminal_text(
    summary: RunSummary,
    intervals: RunIntervals | None = None,
    table_file: str | Path | None = None,
    width: int = WIDTH,
) -> str:
    """What a bench command prints by default: headline, compact table, notes, each line at
    most ``width`` characters (a long name aside, where shortening it cannot help).
    ``table_file``: where the whole table is (a run's table.md; None: only ``--wide``)."""
    intervals = run_intervals(summary) if intervals is None else intervals
    prose = [headline(summary), _legend(summary), interval_note(summary, intervals)]
    if summary.errors:
        prose.append(
            f"* {len(summary.errors)} episode(s) failed and are left out of the means; "
            "see summary.json 'errors' and the tracebacks in episodes.jsonl."
        )
    reused = reuse_note(summary)
    if reused:
        prose.append(reused)
    where = f"{table_file} (--wide prints it)" if table_file is not None else "--wide prints them"
    prose.append(f"SR, Compactness and intervals per level, and run details: {where}.")
    wrap = [textwrap.fill(p, width, break_on_hyphens=False, break_long_words=False) for p in prose]
    # Ends with a newline, as table.md does (a comparison appends its differences after it).
    table = compact_table(summary, intervals, width)
    return "\n".join([wrap[0], "", table, "", *wrap[1:], ""])


__all__ = ["CEILING", "WIDTH", "compact_rows", "compact_table", "ranked_policies", "terminal_text"]
