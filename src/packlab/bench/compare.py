"""Several bench runs side by side: one Table-2-style table whose rows are (run, method).

Used for ablations, where each variant is its own run directory (``vlm`` with ``image=blank`` and
``vlm`` with the full context both record under the policy name ``vlm``). Runs are only comparable
on the same cases, seeds and physics backend, so a mismatch is an error naming the run and field.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from packlab.bench.table import render_markdown
from packlab.core.errors import PacklabError
from packlab.viz.labels import display_name

#: Summary fields that must agree for rows of different runs to share one table.
MUST_MATCH = ("cases_sha256", "seeds", "backend", "difficulties")


def load_summary(run_dir: str | os.PathLike[str]) -> dict[str, Any]:
    path = Path(run_dir) / "summary.json"
    if not path.is_file():
        raise PacklabError(f"{path}: no summary.json (run packlab bench or packlab bench report first)")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise PacklabError(f"{path}: not valid JSON ({e})") from None


def merge_summaries(summaries: Sequence[dict[str, Any]], labels: Sequence[str]) -> dict[str, Any]:
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
            if s.get(field) != first.get(field):
                raise PacklabError(
                    f"bench compare: run {label!r} has {field} = {s.get(field)!r}, "
                    f"but run {labels[0]!r} has {first.get(field)!r}"
                )
    merged: dict[str, Any] = {k: first.get(k) for k in ("suite", "backend", "n_cases", "seeds", "difficulties")}
    merged.update(policies=[], table={}, counts={}, errors=[])
    for label, s in zip(labels, summaries):
        for p in s["policies"]:
            row = label if len(s["policies"]) == 1 else f"{label}: {display_name(p)}"
            merged["policies"].append(row)
            merged["table"][row] = s["table"][p]
            merged["counts"][row] = s["counts"][p]
        merged["errors"] += [dict(e, run=label) for e in s.get("errors", [])]
    return merged


def compare_markdown(run_dirs: Sequence[str | os.PathLike[str]], labels: Sequence[str] | None = None) -> str:
    """The comparison as Markdown, laid out as a run's table.md."""
    names = list(labels) if labels else [Path(d).name for d in run_dirs]
    return render_markdown(merge_summaries([load_summary(d) for d in run_dirs], names))
