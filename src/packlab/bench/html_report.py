"""``report.html``: the interactive report of a run (or of several, ``bench compare --html``).

Built from the run directory's files alone, like the rest of the report (``packlab.bench.
report``): config.json, cases.jsonl and episodes.jsonl, through ``packlab.viz.report_data``
and ``packlab.viz.report_html``. Written at the end of every ``packlab bench`` run (unless
``--no-html``) and by ``packlab bench report DIR --html``. Without plotly (the ``report``
extra) nothing is written and the caller gets ``ReportUnavailable`` to turn into a note.

The 95 % bootstrap intervals (``packlab.bench.summary.run_intervals``) go into the page's data:
each method's cells carry ``[mean, std, low, high]`` (the page's script reads the first two),
``intervals`` holds them in summary.json's layout per run. The page opens on one calm line, the
best method and its Average Overall with its interval (``headline_text``); its notes are kept
for what needs the reader's attention (failed episodes, replays missing or approximate). A
comparison adds the paired differences to the first row under its table. The replay opens on
the best method against the best heuristic (``replay_pair``).

Rows are labelled as in table.md and ``bench compare`` (``packlab.bench.table.row_name``,
``packlab.bench.compare.row_names``). Methods that read a model's text answer carry their
answer-format counts (``PolicyCounts.answer_formats``) in their row's ``counts``, and the page's
details table shows them in the columns ``details_extra`` lists (``with_answer_formats``).
"""

from __future__ import annotations

import os
from collections.abc import Collection, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from msgspec import UnsetType

from packlab.bench.compare import (
    UNRELIABLE_MARK,
    UNRELIABLE_NOTE,
    merge_summaries,
    paired_differences,
    reliable_groups,
)
from packlab.bench.config import run_sides
from packlab.bench.options import COMPARE_HTML, REPORT_HTML
from packlab.bench.records import EPISODES_FILE
from packlab.bench.report import RunFiles, config_head, load_run, pick_showcase_case, summary_of
from packlab.bench.summary import RunIntervals, run_intervals
from packlab.bench.table import ANSWER_FORMAT_COLUMNS, headline, row_name
from packlab.bench.terminal import CEILING, ranked_policies
from packlab.core.choices import SideNames
from packlab.core.errors import ConfigError
from packlab.core.records import EpisodeRecord, RunConfigHead, RunSummary, to_builtins
from packlab.core.types import Case
from packlab.metrics import AVERAGE, METRICS
from packlab.policies.heuristics import SCORERS
from packlab.viz.labels import group_title
from packlab.viz.report_data import Method, ReportRun, report_data, row_colours
from packlab.viz.report_html import ReportUnavailable, render_report_html

NO_CASES = "The run directory has no cases.jsonl: episodes are scored but cannot be replayed."


def now_stamp() -> str:
    """The build time as the page shows it (UTC, to the second)."""
    return datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _write_atomic(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path


def _groups(summary: RunSummary) -> list[str]:
    groups = list(summary.difficulties)
    return groups + [AVERAGE] if len(groups) > 1 else groups


def headline_text(
    summary: RunSummary, intervals: RunIntervals, ceilings: Collection[str] = (CEILING,)
) -> str:
    """The page's first line: the best method (the oracle, a ceiling, aside: ``ceilings`` are
    its rows) and its Overall with its 95 % interval; the table below says the rest ("" when
    nothing was scored)."""
    groups = _groups(summary)
    ranked = [p for p in ranked_policies(summary) if p not in ceilings]
    if not groups or not ranked:
        return ""
    best, last = ranked[0], groups[-1]
    cells = summary.table[best].get(last)
    mean = None if cells is None else cells.overall.mean
    if mean is None:
        return ""
    bounds = intervals.bounds(best, last, "overall")
    shown = f"{mean:.3f}" if bounds is None else f"{mean:.3f} [{bounds[0]:.3f}, {bounds[1]:.3f}]"
    return f"Best: {row_name(summary, best)}, {group_title(last)} Overall {shown}."


def replay_pair(ranked: Sequence[int], policies: Sequence[str]) -> list[int]:
    """The replay's opening panes, as row indices: the best row (``ranked``: rows best first,
    the oracle left out) on the left, the best heuristic's on the right (the next best row
    when the best is itself the best heuristic, or there is none)."""
    if not ranked:
        return [0, 1 if len(policies) > 1 else 0]
    best = ranked[0]
    others = list(ranked[1:])
    heuristic = next((i for i in others if policies[i] in SCORERS), None)
    right = heuristic if heuristic is not None else (others[0] if others else best)
    return [best, right]


def difference_notes(merged: RunSummary) -> list[str]:
    """Per row after the first: its paired Overall difference to the first, on average."""
    if len(merged.policies) < 2 or not merged.difficulties:
        return []
    ref, last = merged.policies[0], _groups(merged)[-1]
    notes = []
    for row in merged.policies[1:]:
        diffs = paired_differences(merged, row, ref)
        diff = diffs.get(last)
        if diff is None:
            continue
        lo, hi = diff.interval.low, diff.interval.high
        if not reliable_groups(diffs).get(last, True):  # too few cases to call it either way
            verdict = f"not judged: {UNRELIABLE_NOTE.removeprefix(UNRELIABLE_MARK).strip()}"
        else:
            verdict = "significant" if diff.significant else "not significant (interval includes 0)"
        notes.append(
            f"{row} minus {ref}, {group_title(last)} Overall: {diff.estimate:+.3f} "
            f"[{lo:+.3f}, {hi:+.3f}] over {diff.n_cases} paired cases: {verdict}"
        )
    return notes


def with_intervals(
    data: dict[str, Any], summaries: Sequence[RunSummary], intervals: Sequence[RunIntervals]
) -> dict[str, Any]:
    """``report_data``'s dict with each method's cells extended by ``low, high`` (None where
    there is none) and summary.json's ``intervals`` of each run."""
    for m in data["methods"]:
        summary, found = summaries[m["run"]], intervals[m["run"]]
        bounds = [found.bounds(m["policy"], g, k) for g in _groups(summary) for k in METRICS]
        m["cells"] = [
            # rounded as report_data rounds the means (6 places: the page's data stays small)
            None if c is None else [*c, *((None, None) if b is None else (round(x, 6) for x in b))]
            for c, b in zip(m["cells"], bounds)
        ]
    data["intervals"] = [to_builtins(i) for i in intervals]
    return data


def with_answer_formats(data: dict[str, Any], summaries: Sequence[RunSummary]) -> dict[str, Any]:
    """``report_data``'s dict with each text-answer method's answer-format counts in its row's
    ``counts`` (keys as in ``AnswerFormats``) and, when some row has them, their columns under
    ``details_extra`` (``[key, title, decimals]``, as the page's details table lists columns)."""
    found = False
    for m in data["methods"]:
        counts = summaries[m["run"]].counts.get(m["policy"])
        formats = None if counts is None else counts.answer_formats
        if formats is None or isinstance(formats, UnsetType):
            continue
        found = True
        m["counts"].update({key: getattr(formats, key) for key, _ in ANSWER_FORMAT_COLUMNS})
    if found:
        data["details_extra"] = [[key, title, 0] for key, title in ANSWER_FORMAT_COLUMNS]
    return data


def head_sides(head: RunConfigHead) -> SideNames:
    """The side names a run showed, from its config head (``run_sides``)."""
    return run_sides({"sensing": to_builtins(head.sensing)} if head.sensing else {})


def run_html(
    config: RunConfigHead | Mapping[str, object],
    records: Sequence[EpisodeRecord],
    cases: Sequence[Case],
    summary: RunSummary | None = None,
    generated: str | None = None,
) -> str:
    """The report page of one run (``summary``: the run's, computed when not given)."""
    head = config_head(config)
    summary = summary if summary is not None else summary_of(head, records, cases)
    policies = list(summary.policies)
    colours = row_colours(policies, distinct=False)
    methods = [Method(row_name(summary, p), 0, p, colour) for p, colour in zip(policies, colours)]
    intervals = run_intervals(summary)
    ranked = [policies.index(p) for p in ranked_policies(summary) if p != CEILING]
    data = report_data(
        [ReportRun("", summary, tuple(records), tuple(cases), head_sides(head))],
        methods,
        title=f"packlab bench report: {head.suite or 'cases'}",
        subtitle=headline(summary),
        headline=headline_text(summary, intervals),
        initial_case=pick_showcase_case(summary, cases),
        replay=replay_pair(ranked, policies),
        notes=[] if cases else [NO_CASES],
    )
    data = with_answer_formats(with_intervals(data, [summary], [intervals]), [summary])
    return render_report_html(data, generated or now_stamp())


def write_run_html(
    run_dir: str | os.PathLike[str],
    config: RunConfigHead | Mapping[str, object],
    records: Sequence[EpisodeRecord],
    cases: Sequence[Case],
    summary: RunSummary | None = None,
    generated: str | None = None,
) -> Path:
    """Write ``report.html`` into the run directory; ReportUnavailable without plotly."""
    text = run_html(config, records, cases, summary, generated)
    return _write_atomic(Path(run_dir) / REPORT_HTML, text)


def build_html_report(run_dir: str | os.PathLike[str], generated: str | None = None) -> Path:
    """``packlab bench report DIR --html``: the page of a run directory, from its files."""
    run = load_run(run_dir)
    if not run.records:
        raise ConfigError(f"{run.run_dir / EPISODES_FILE}: no records; nothing to report")
    return write_run_html(run.run_dir, run.config, run.records, run.cases, generated=generated)


def compare_html(
    run_dirs: Sequence[str | os.PathLike[str]],
    labels: Sequence[str] | None = None,
    generated: str | None = None,
) -> str:
    """One page over several runs (same cases, seeds and backend, as ``bench compare``): rows
    are ``"<run>: <method>"``, named and checked as the Markdown comparison names them."""
    names = list(labels) if labels else [Path(d).name for d in run_dirs]
    runs: list[RunFiles] = [load_run(d) for d in run_dirs]
    summaries = [summary_of(r.config, r.records, r.cases) for r in runs]
    merged = merge_summaries(summaries, names)  # checks labels and that the runs compare
    pairs = [(i, p) for i, s in enumerate(summaries) for p in s.policies]
    colours = row_colours([p for _, p in pairs], distinct=True)
    # Named as the Markdown comparison names its rows (merge_summaries: the same order).
    methods = [
        Method(row, i, p, colour) for row, (i, p), colour in zip(merged.policies, pairs, colours)
    ]
    report_runs = [
        ReportRun(name, s, tuple(r.records), r.cases, head_sides(r.config))
        for name, s, r in zip(names, summaries, runs)
    ]
    listed = ", ".join(f"{n} ({r.run_dir})" for n, r in zip(names, runs))
    intervals = [run_intervals(s) for s in summaries]
    rows = [m.name for m in methods]
    ceilings = {m.name for m in methods if m.policy == CEILING}
    ranked = [rows.index(r) for r in ranked_policies(merged) if r not in ceilings]
    data = report_data(
        report_runs,
        methods,
        title="packlab bench compare: " + ", ".join(names),
        subtitle=f"{headline(merged)}; runs: {listed}",
        headline=headline_text(merged, run_intervals(merged), ceilings),
        initial_case=pick_showcase_case(summaries[0], runs[0].cases),
        replay=replay_pair(ranked, [m.policy for m in methods]),
        notes=[f"run {n}: {NO_CASES}" for n, r in zip(names, runs) if not r.cases],
        differences=difference_notes(merged),
    )
    data = with_answer_formats(with_intervals(data, summaries, intervals), summaries)
    return render_report_html(data, generated or now_stamp())


def write_compare_html(
    run_dirs: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    labels: Sequence[str] | None = None,
    generated: str | None = None,
) -> Path:
    """Write the comparison page to ``out``; ReportUnavailable without plotly."""
    out = Path(out)
    if out.is_dir():
        raise ConfigError(f"html = {str(out)!r}: is a directory; give the HTML file to write")
    return _write_atomic(out, compare_html(run_dirs, labels, generated))


__all__ = [
    "COMPARE_HTML",
    "REPORT_HTML",
    "ReportUnavailable",
    "build_html_report",
    "compare_html",
    "headline_text",
    "now_stamp",
    "replay_pair",
    "run_html",
    "write_compare_html",
    "write_run_html",
]
