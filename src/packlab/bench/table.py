"""Summary -> the Table-2-style Markdown table (and a run-details table), pure string building."""

from __future__ import annotations

from msgspec import UNSET

from packlab.core.records import Cell, RunSummary
from packlab.metrics import AVERAGE, METRICS
from packlab.viz.labels import METRIC_SHORT, display_name, group_title


def format_cell(cell: Cell | None, digits: int = 3) -> str:
    """``"0.812 ± 0.010"``: mean over seeds ± sample std across seeds; ``-`` when nothing ran."""
    if cell is None or cell.mean is None:
        return "-"
    return f"{cell.mean:.{digits}f} ± {cell.std or 0.0:.{digits}f}"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _cell(summary: RunSummary, policy: str, group: str, metric: str) -> Cell | None:
    cells = summary.table[policy].get(group)
    return None if cells is None else cells.cell(metric)


def results_table(summary: RunSummary, digits: int = 3) -> str:
    """Rows = methods; column groups = difficulties and the average; SR, Compactness, Overall."""
    groups = list(summary.difficulties)
    if len(groups) > 1:
        groups.append(AVERAGE)
    header = ["Method"] + [f"{group_title(g)} {METRIC_SHORT[m]}" for g in groups for m in METRICS]
    lines = [_row(header), _row(["---"] + ["---:"] * (len(header) - 1))]
    for p in summary.policies:
        flag = " *" if summary.counts[p].errors else ""
        cells = [f"{display_name(p)}{flag}"]
        cells += [format_cell(_cell(summary, p, g, m), digits) for g in groups for m in METRICS]
        lines.append(_row(cells))
    return "\n".join(lines)


def details_table(summary: RunSummary) -> str:
    """Per method: episodes, failures, invalid steps, objects set aside, settling, time per step.

    ``unsettled steps``: placements whose settle hit the per-placement cap; ``not at rest``:
    episodes scored while boxes still moved (the final settle hit its cap). Summaries written
    before these counts existed show their ``capped_placements`` (migrated to
    ``unsettled_steps``) and ``-``.
    """
    header = [
        "Method",
        "episodes",
        "errors",
        "invalid steps",
        "set aside",
        "unsettled steps",
        "not at rest",
        "ms / decision",
        "ms / env step",
        "s / episode",
    ]
    lines = [_row(header), _row(["---"] + ["---:"] * (len(header) - 1))]

    def num(v: float | None, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for p in summary.policies:
        c = summary.counts[p]
        lines.append(
            _row(
                [
                    display_name(p),
                    str(c.episodes),
                    str(c.errors),
                    str(c.invalid_steps),
                    str(c.set_aside),
                    num(c.unsettled_steps, "d"),
                    num(c.not_at_rest, "d"),
                    num(c.decision_ms, ".2f"),
                    num(c.step_ms, ".2f"),
                    num(c.episode_s, ".3f"),
                ]
            )
        )
    return "\n".join(lines)


def headline(summary: RunSummary) -> str:
    seeds = ",".join(str(s) for s in summary.seeds)
    n_cases = summary.n_cases if isinstance(summary.n_cases, int) else None
    cases = f", {n_cases} cases" if n_cases is not None else ""
    # An absent suite or backend reads as a default; a null one prints as None (as it always has).
    suite = "bench" if summary.suite is UNSET else summary.suite
    backend = "?" if summary.backend is UNSET else summary.backend
    return (
        f"{suite}: backend {backend}, seeds {seeds}{cases}; "
        f"mean over seeds ± sample std across seeds"
    )


def render_markdown(summary: RunSummary) -> str:
    """The whole table.md: headline, results table, failure note, details table."""
    parts = [f"## {headline(summary)}", "", results_table(summary), ""]
    if summary.errors:
        n = len(summary.errors)
        parts += [
            (
                f"\\* {n} episode(s) failed and are left out of the means; "
                "see summary.json 'errors' and the tracebacks in episodes.jsonl."
            ),
            "",
        ]
    parts += ["### Run details", "", details_table(summary), ""]
    return "\n".join(parts)


__all__ = ["details_table", "format_cell", "headline", "render_markdown", "results_table"]
