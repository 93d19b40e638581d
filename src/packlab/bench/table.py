"""Summary -> the Table-2-style Markdown table (and a run-details table), pure string building."""

from __future__ import annotations

from typing import Any

from packlab.metrics import AVERAGE, METRICS
from packlab.viz.labels import METRIC_SHORT, display_name, group_title


def format_cell(cell: dict[str, Any] | None, digits: int = 3) -> str:
    """``"0.812 ± 0.010"``: mean over seeds ± sample std across seeds; ``-`` when nothing ran."""
    if not cell or cell.get("mean") is None:
        return "-"
    return f"{cell['mean']:.{digits}f} ± {cell['std']:.{digits}f}"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def results_table(summary: dict[str, Any], digits: int = 3) -> str:
    """Rows = methods; column groups = difficulties and the average; SR, Compactness, Overall."""
    groups = [*summary["difficulties"], AVERAGE] if len(summary["difficulties"]) > 1 else summary["difficulties"]
    header = ["Method"] + [f"{group_title(g)} {METRIC_SHORT[m]}" for g in groups for m in METRICS]
    lines = [_row(header), _row(["---"] + ["---:"] * (len(header) - 1))]
    for p in summary["policies"]:
        flag = " *" if summary["counts"][p]["errors"] else ""
        cells = [f"{display_name(p)}{flag}"]
        cells += [format_cell(summary["table"][p].get(g, {}).get(m), digits) for g in groups for m in METRICS]
        lines.append(_row(cells))
    return "\n".join(lines)


def details_table(summary: dict[str, Any]) -> str:
    """Per method: episodes, failures, invalid steps, objects set aside, settling, time per decision.

    ``unsettled steps``: placements whose settle hit the per-placement cap; ``not at rest``:
    episodes scored while boxes still moved (the final settle hit its cap). Summaries written
    before these counts existed show their ``capped_placements`` and ``-``.
    """
    header = ["Method", "episodes", "errors", "invalid steps", "set aside", "unsettled steps",
              "not at rest", "ms / decision", "ms / env step", "s / episode"]
    lines = [_row(header), _row(["---"] + ["---:"] * (len(header) - 1))]

    def num(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for p in summary["policies"]:
        c = summary["counts"][p]
        lines.append(_row([display_name(p), str(c["episodes"]), str(c["errors"]), str(c["invalid_steps"]),
                           str(c["set_aside"]), num(c.get("unsettled_steps", c.get("capped_placements")), "d"),
                           num(c.get("not_at_rest"), "d"), num(c["decision_ms"], ".2f"),
                           num(c["step_ms"], ".2f"), num(c["episode_s"], ".3f")]))
    return "\n".join(lines)


def headline(summary: dict[str, Any]) -> str:
    seeds = ",".join(str(s) for s in summary["seeds"])
    n_cases = summary.get("n_cases")
    cases = f", {n_cases} cases" if n_cases is not None else ""
    return (f"{summary.get('suite', 'bench')}: backend {summary.get('backend', '?')}, seeds {seeds}{cases}; "
            f"mean over seeds ± sample std across seeds")


def render_markdown(summary: dict[str, Any]) -> str:
    """The whole table.md: headline, results table, failure note, details table."""
    parts = [f"## {headline(summary)}", "", results_table(summary), ""]
    if summary["errors"]:
        n = len(summary["errors"])
        parts += [(f"\\* {n} episode(s) failed and are left out of the means; see summary.json 'errors' "
                   "and the tracebacks in episodes.jsonl."), ""]
    parts += ["### Run details", "", details_table(summary), ""]
    return "\n".join(parts)


__all__ = ["details_table", "format_cell", "headline", "render_markdown", "results_table"]
