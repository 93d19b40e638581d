"""Several bench runs side by side: one Table-2-style table whose rows are (run, method).

Used for ablations, where each variant is its own run directory (``vlm`` with ``image=blank`` and
``vlm`` with the full context both record under the policy name ``vlm``). Runs are only comparable
on the same cases, seeds, physics backend and observation / execution modes (issue 15), so a
mismatch is an error naming the run and field.
Each summary.json is read as a typed ``RunSummary`` with its version checked (older ones
migrate; see ``packlab.core.records``).

Under the table, every row after the first is set against the first (the reference: the first
run's first method, so the order of the run directories picks it): the paired difference of
Overall, row minus reference, per level and on average, over the (case, seed) units both have
(paired by case, each case's differences averaged over its common seeds), with a 95 % paired
bootstrap interval (``packlab.bench.intervals``; seeds resampled within each case too when
either method's scores vary across seeds). A difference counts as significant only where its
interval excludes 0.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import msgspec

from packlab.bench.intervals import Difference, paired_difference, varies_over_seeds
from packlab.bench.table import render_markdown
from packlab.core.errors import PacklabError
from packlab.core.records import (
    CaseCells,
    MetricCells,
    NotJSON,
    PolicyCounts,
    RunSummary,
    SensingModes,
    summary_from_json,
)
from packlab.metrics import AVERAGE
from packlab.viz.labels import display_name, group_title

#: Summary fields that must agree for rows of different runs to share one table.
#: ``sensing`` (observation / execution / noise, issue 15) is absent for exact runs.
MUST_MATCH = ("cases_sha256", "seeds", "backend", "difficulties", "sensing")


def load_summary(run_dir: str | os.PathLike[str]) -> RunSummary:
    path = Path(run_dir) / "summary.json"
    if not path.is_file():
        raise PacklabError(
            f"{path}: no summary.json (run packlab bench or packlab bench report first)"
        )
    try:
        return summary_from_json(path.read_bytes(), str(path))
    except NotJSON as e:
        raise PacklabError(f"{e}; not valid JSON") from None


def _field(summary: RunSummary, name: str) -> object:
    value = getattr(summary, name)
    if name == "sensing" and value in (None, msgspec.UNSET):
        return "exact"  # both modes exact: written nowhere, shown as such
    return None if value is msgspec.UNSET else value


def merge_summaries(summaries: Sequence[RunSummary], labels: Sequence[str]) -> RunSummary:
    """One summary whose policies are ``"<label>: <method>"`` (or just the label for one-method
    runs), in the order given; table, counts and errors are carried over per row."""
    if not summaries:
        raise PacklabError("bench compare: no runs given")
    if len(labels) != len(summaries):
        raise PacklabError(f"bench compare: {len(labels)} labels for {len(summaries)} runs")
    if len(set(labels)) != len(labels):
        raise PacklabError(f"bench compare: labels must differ, got {list(labels)}")
    first = summaries[0]
    for label, s in zip(labels[1:], summaries[1:]):
        for field in MUST_MATCH:
            if _field(s, field) != _field(first, field):
                raise PacklabError(
                    f"bench compare: run {label!r} has {field} = {_show(_field(s, field))}, "
                    f"but run {labels[0]!r} has {_show(_field(first, field))}"
                )
    policies: list[str] = []
    table: dict[str, dict[str, MetricCells]] = {}
    per_case: dict[str, dict[str, CaseCells]] = {}
    counts: dict[str, PolicyCounts] = {}
    errors = []
    for label, s in zip(labels, summaries):
        for p in s.policies:
            row = label if len(s.policies) == 1 else f"{label}: {display_name(p)}"
            policies.append(row)
            table[row] = s.table[p]
            counts[row] = s.counts[p]
            if p in s.per_case:  # the intervals and paired differences are made from these
                per_case[row] = s.per_case[p]
        errors += [msgspec.structs.replace(e, run=label) for e in s.errors]
    return RunSummary(
        format=first.format,
        suite=first.suite,
        backend=first.backend,
        sensing=first.sensing,
        n_cases=first.n_cases,
        policies=tuple(policies),
        seeds=first.seeds,
        difficulties=first.difficulties,
        table=table,
        per_case=per_case,
        counts=counts,
        errors=tuple(errors),
    )


def _show(value: object) -> str:
    """A field's value as the JSON it was read from (lists, not tuples)."""
    if isinstance(value, SensingModes):
        return repr(msgspec.structs.asdict(value))
    return repr(list(value)) if isinstance(value, tuple) else repr(value)


def _overall_by_level(summary: RunSummary, row: str) -> list[dict[str, dict[str, float]]]:
    """One row's Overall per level: case -> seed -> score, in the summary's level order."""
    cases = summary.per_case.get(row, {})
    return [
        {c: cells.overall.per_seed for c, cells in cases.items() if cells.difficulty == d}
        for d in summary.difficulties
    ]


def paired_differences(
    summary: RunSummary, row: str, reference: str
) -> dict[str, Difference | None]:
    """Overall of ``row`` minus ``reference`` per level and on average (``AVERAGE``), paired
    over common (case, seed) units; None where the two share no unit (or lack per-case cells)."""
    a, b = _overall_by_level(summary, row), _overall_by_level(summary, reference)
    over_seeds = varies_over_seeds([*_seed_scores(a), *_seed_scores(b)])
    out: dict[str, Difference | None] = {}
    for i, d in enumerate(summary.difficulties):
        out[d] = paired_difference([a[i]], [b[i]], over_seeds=over_seeds)
    out[AVERAGE] = paired_difference(a, b, over_seeds=over_seeds) if a else None
    return out


def _seed_scores(strata: list[dict[str, dict[str, float]]]) -> list[dict[str, float]]:
    return [seeds for stratum in strata for seeds in stratum.values()]


def _format_difference(diff: Difference | None) -> str:
    if diff is None:
        return "-"
    lo, hi = diff.interval.low, diff.interval.high
    text = f"{diff.estimate:+.3f} [{lo:+.3f}, {hi:+.3f}]"
    return f"**{text}**" if diff.significant else text


def _verdict(diff: Difference | None) -> str:
    if diff is None:
        return "-"
    if not diff.significant:
        return "no (interval includes 0)"
    return "yes, higher" if diff.estimate > 0 else "yes, lower"


def differences_markdown(summary: RunSummary, reference: str | None = None) -> str:
    """The paired-difference table: every other row against ``reference`` (default: the
    first row)."""
    if len(summary.policies) < 2:
        return ""
    reference = summary.policies[0] if reference is None else reference
    if reference not in summary.policies:
        raise PacklabError(
            f"bench compare: reference {reference!r} is not a row; rows: {list(summary.policies)}"
        )
    groups = list(summary.difficulties)
    if len(groups) > 1:
        groups.append(AVERAGE)
    header = ["Row", "cases paired"] + [f"{group_title(g)} Overall diff" for g in groups]
    header.append(f"{group_title(groups[-1])} differs?")
    lines = [
        f"### Paired differences: each row minus {reference}",
        "",
        (
            "Overall, row minus reference, over the (case, seed) units both have (paired by "
            "case, seeds averaged within a case); [low, high]: 95 % paired bootstrap interval "
            "over cases (seeds resampled within each case when either method's scores vary "
            "across seeds). **Bold** = significant: the interval excludes 0; otherwise the "
            "two are not shown to differ."
        ),
        "",
        "| " + " | ".join(header) + " |",
        "| --- |" + " ---: |" * (len(header) - 2) + " --- |",
    ]
    for row in (r for r in summary.policies if r != reference):
        diffs = paired_differences(summary, row, reference)
        last = diffs.get(groups[-1])
        cells = [row, "-" if last is None else str(last.n_cases)]
        cells += [_format_difference(diffs.get(g)) for g in groups]
        cells.append(_verdict(last))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def compare_markdown(
    run_dirs: Sequence[str | os.PathLike[str]], labels: Sequence[str] | None = None
) -> str:
    """The comparison as Markdown, laid out as a run's table.md, then the paired differences
    of every row against the first."""
    names = list(labels) if labels else [Path(d).name for d in run_dirs]
    merged = merge_summaries([load_summary(d) for d in run_dirs], names)
    text = render_markdown(merged)
    diffs = differences_markdown(merged)
    return f"{text}\n{diffs}" if diffs else text
