"""Several bench runs side by side: one Table-2-style table whose rows are (run, method).

Used for ablations, where each variant is its own run directory (``vlm`` with ``image=blank`` and
``vlm`` with the full context both record under the policy name ``vlm``). Runs are only comparable
on the same cases, seeds, physics backend and observation / execution modes (issue 15), so a
mismatch is an error naming the run and field.
Each summary.json is read as a typed ``RunSummary`` with its version checked (older ones
migrate; see ``packlab.core.records``).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import msgspec

from packlab.bench.table import render_markdown
from packlab.core.errors import PacklabError
from packlab.core.records import (
    MetricCells,
    NotJSON,
    PolicyCounts,
    RunSummary,
    SensingModes,
    summary_from_json,
)
from packlab.viz.labels import display_name

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
    counts: dict[str, PolicyCounts] = {}
    errors = []
    for label, s in zip(labels, summaries):
        for p in s.policies:
            row = label if len(s.policies) == 1 else f"{label}: {display_name(p)}"
            policies.append(row)
            table[row] = s.table[p]
            counts[row] = s.counts[p]
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
        counts=counts,
        errors=tuple(errors),
    )


def _show(value: object) -> str:
    """A field's value as the JSON it was read from (lists, not tuples)."""
    if isinstance(value, SensingModes):
        return repr(msgspec.structs.asdict(value))
    return repr(list(value)) if isinstance(value, tuple) else repr(value)


def compare_markdown(
    run_dirs: Sequence[str | os.PathLike[str]], labels: Sequence[str] | None = None
) -> str:
    """The comparison as Markdown, laid out as a run's table.md."""
    names = list(labels) if labels else [Path(d).name for d in run_dirs]
    return render_markdown(merge_summaries([load_summary(d) for d in run_dirs], names))
