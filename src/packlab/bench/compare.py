"""Several bench runs side by side: one Table-2-style table whose rows are (run, method).

Used for ablations, where each variant is its own run directory (``vlm`` with ``image=blank`` and
``vlm`` with the full context both record under the policy name ``vlm``). Runs are only comparable
on the same cases, seeds, difficulties and physics backend (:data:`MUST_MATCH`); a mismatch is
refused in the user's words: which setting differs, its value in both runs, what compare needs.
The documented ablations of how a run senses and acts (:data:`ABLATIONS`: ``--sides``,
``--segmentation``, ``--observation``, ``--execution``, ``--noise``) may differ: each run's rows
are then labelled with its setting, e.g. ``paper (sides catalogue): DBLF`` (the reference
paper's protocol) and ``ours (sides longer-first): DBLF``. Runs made before side names were
always recorded read as the catalogue's (exact observation). Policy options label rows the same
way: a method's options that differ between the runs holding it (``--policy-arg
endpoint:image=blank`` in one run only: ``blank (image=blank)`` and ``full (image=default)``),
beside those every label names (the prompt protocol and context ablations,
``packlab.viz.labels.policy_label``). Options of how a policy runs (deadlines, threads, the
server's URL) are never named.
Each summary.json is read as a typed ``RunSummary`` with its version checked (older ones
migrate; see ``packlab.core.records``).

Under the table, every row after the first is set against the first (the reference: the first
run's first method, so the order of the run directories picks it): the paired difference of
Overall, row minus reference, per level and on average, over the (case, seed) units both have
(paired by case, each case's differences averaged over its common seeds), with a 95 % paired
bootstrap interval (``packlab.bench.intervals``; seeds resampled within each case too when
either method's scores vary across seeds). A difference counts as significant only where its
interval excludes 0, and only where each level pairs at least :data:`MIN_RELIABLE_CASES` cases:
with fewer, a bootstrap over cases has next to nothing to resample (one case per level collapses
the interval to a point), so such intervals are marked unreliable and never called significant.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import msgspec

from packlab.bench.intervals import Difference, paired_difference, varies_over_seeds
from packlab.bench.table import policy_options, render_markdown
from packlab.core.choices import UNRECORDED_SIDES
from packlab.core.errors import PacklabError
from packlab.core.packing_protocol import PackingProtocol, saved_protocol
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
from packlab.viz.labels import display_name, group_title, option_settings, with_settings

#: Summary fields that must agree for rows of different runs to share one table, with the words
#: and flag a user knows them by.
MUST_MATCH: dict[str, tuple[str, str]] = {
    "cases_sha256": ("cases", "--cases"),
    "seeds": ("seeds", "--seeds"),
    "backend": ("backend", "--backend"),
    "difficulties": ("difficulties", "--difficulty"),
}
#: The sensing settings (summary ``sensing``) a comparison may vary: documented
#: ablations, each run's rows labelled with its value. Field -> its value when not recorded
#: (None: the setting does not apply to that run, e.g. segmentation of an exact observation).
#: ``sides`` not recorded is the catalogue's in exact observation (runs made before it was
#: always recorded, ``UNRECORDED_SIDES``) and longer first in perceived observation;
#: ``size_prior`` not recorded is ``grid`` in perceived observation (perception snapped every
#: size to the grids before the prior was a choice) and does not apply to exact observation.
ABLATIONS: dict[str, str | None] = {
    "observation": "exact",
    "execution": "exact",
    "noise": None,
    "segmentation": None,
    "sides": UNRECORDED_SIDES,
    "size_prior": None,
}
#: Fewest paired cases per level for an interval to be read: below it the bootstrap over cases
#: resamples too few units (1 case: a point) and a difference is not called significant.
MIN_RELIABLE_CASES = 5
#: The footnote mark of an unreliable interval and the footnote itself.
UNRELIABLE_MARK = "†"
UNRELIABLE_NOTE = (
    f"{UNRELIABLE_MARK} fewer than {MIN_RELIABLE_CASES} cases per level: intervals not "
    "reliable, significance not marked."
)


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
    return None if value is msgspec.UNSET else value


def sensing_settings(summary: RunSummary) -> dict[str, str | None]:
    """The run's :data:`ABLATIONS` settings as a user set them (defaults filled in; None where
    a setting does not apply), whatever summary.json left out."""
    sensing = summary.sensing
    recorded = (
        msgspec.structs.asdict(sensing)
        if isinstance(sensing, SensingModes)
        else {}  # absent: both modes exact, sides the catalogue's (an older run)
    )
    out: dict[str, str | None] = {}
    for name, default in ABLATIONS.items():
        value = recorded.get(name, msgspec.UNSET)
        if name == "sides" and out["observation"] == "perceived":
            default = "longer-first"  # perception always named them so
        if name == "size_prior" and out["observation"] == "perceived":
            default = "grid"  # perception snapped every size before the prior was a choice
        out[name] = default if value is msgspec.UNSET or value is None else str(value)
    if out["observation"] == "exact" and out["execution"] == "exact":
        out["noise"] = None  # a preset only the perceived and noisy modes use
    return out


def _shown(name: str, value: object) -> str:
    """A MUST_MATCH value as a user reads it: seeds as typed, a digest shortened."""
    if value is None:
        return "not recorded"
    if isinstance(value, (tuple, list)):
        return ",".join(map(str, value)) or "none"
    if name == "cases_sha256":
        return f"sha256 {str(value)[:12]}..."
    return str(value)


def summary_protocol(summary: RunSummary) -> PackingProtocol:
    """The protocol a summary records (absent: buffer, runs made before the choice)."""
    return saved_protocol({"protocol": _field(summary, "protocol"), **_lookahead(summary)})


def _lookahead(summary: RunSummary) -> dict[str, object]:
    value = _field(summary, "lookahead")
    return {} if value is None else {"lookahead": value}


def _check_comparable(summaries: Sequence[RunSummary], labels: Sequence[str]) -> None:
    first = summaries[0]
    for label, s in zip(labels[1:], summaries[1:]):
        for field, (words, flag) in MUST_MATCH.items():
            mine, theirs = _field(s, field), _field(first, field)
            if mine == theirs:
                continue
            if field == "cases_sha256":  # the suite's name says more than a digest
                mine = f"{s.suite} ({_shown(field, mine)})"
                theirs = f"{first.suite} ({_shown(field, theirs)})"
            else:
                mine, theirs = _shown(field, mine), _shown(field, theirs)
            raise PacklabError(
                f"bench compare: runs {labels[0]!r} and {label!r} differ in {words} "
                f"({flag}): {theirs} in {labels[0]!r}, {mine} in {label!r}; compare needs "
                "the same cases, seeds, difficulties and backend in every run (rerun one with "
                f"the other's {flag})"
            )


def _ablation_settings(summaries: Sequence[RunSummary]) -> list[list[str]]:
    """Per run, the sensing settings and protocol that differ between the runs, e.g.
    ``["sides longer-first"]``; empty lists when none differs."""
    settings = [sensing_settings(s) for s in summaries]
    # The protocol too: the same cases under the buffer, online and offline
    # protocols are what measures the cost of seeing only part of the sequence.
    for st, s in zip(settings, summaries):
        st["protocol"] = summary_protocol(s).label
    names = [*ABLATIONS, "protocol"]
    varying = [name for name in names if len({str(st[name]) for st in settings}) > 1]
    return [
        [f"{name.replace('_', ' ')} {st[name]}" for name in varying if st[name] is not None]
        for st in settings
    ]


def _ablation_labels(summaries: Sequence[RunSummary], labels: Sequence[str]) -> list[str]:
    """Each run's label, with the settings that differ between the runs appended, e.g.
    ``"lf (sides longer-first)"``; unchanged when no setting differs."""
    return [with_settings(lb, st) for lb, st in zip(labels, _ablation_settings(summaries))]


def _option_key(options: Mapping[str, object], key: str) -> str:
    """An option's value, comparable across runs (absent differs from every value)."""
    return json.dumps(options[key], sort_keys=True) if key in options else "<not set>"


def differing_options(summaries: Sequence[RunSummary]) -> dict[str, list[str]]:
    """Per method: the ``--policy-arg`` options whose values differ between the runs that
    hold it (set in one and not in another counts), by name."""
    held: dict[str, list[Mapping[str, object]]] = {}
    for s in summaries:
        for p in s.policies:
            held.setdefault(p, []).append(policy_options(s, p) or {})
    return {
        p: [
            key
            for key in sorted({k for o in runs for k in o})
            if len({_option_key(o, key) for o in runs}) > 1
        ]
        for p, runs in held.items()
    }


def row_names(summaries: Sequence[RunSummary], labels: Sequence[str]) -> list[str]:
    """The rows of a comparison, run by run and method by method: ``"<run>: <method>"``, or the
    run's label alone for a one-method run, each named with the sensing settings that differ
    between the runs and the method's options (those every label names and those that differ
    between the runs holding it): ``"blank (image=blank)"``."""
    differing = differing_options(summaries)
    rows = []
    for label, sensing, s in zip(labels, _ablation_settings(summaries), summaries):
        for p in s.policies:
            options = option_settings(policy_options(s, p), differing[p])
            if len(s.policies) == 1:
                rows.append(with_settings(label, [*sensing, *options]))
            else:
                method = with_settings(display_name(p), options)
                rows.append(f"{with_settings(label, sensing)}: {method}")
    return rows


def merge_summaries(summaries: Sequence[RunSummary], labels: Sequence[str]) -> RunSummary:
    """One summary whose policies are ``"<label>: <method>"`` (or just the label for one-method
    runs), in the order given and named by :func:`row_names`; table, counts and errors are
    carried over per row."""
    if not summaries:
        raise PacklabError("bench compare: no runs given")
    if len(labels) != len(summaries):
        raise PacklabError(f"bench compare: {len(labels)} labels for {len(summaries)} runs")
    if len(set(labels)) != len(labels):
        raise PacklabError(f"bench compare: labels must differ, got {list(labels)}")
    first = summaries[0]
    _check_comparable(summaries, labels)
    rows = iter(row_names(summaries, labels))
    labels = _ablation_labels(summaries, labels)
    same_sensing = len({repr(sensing_settings(s)) for s in summaries}) == 1
    same_protocol = len({summary_protocol(s) for s in summaries}) == 1
    policies: list[str] = []
    table: dict[str, dict[str, MetricCells]] = {}
    per_case: dict[str, dict[str, CaseCells]] = {}
    counts: dict[str, PolicyCounts] = {}
    errors = []
    for label, s in zip(labels, summaries):
        for p in s.policies:
            row = next(rows)
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
        # Runs of different settings: the rows say which is which, the merged run has none.
        sensing=first.sensing if same_sensing else msgspec.UNSET,
        # Runs of different protocols: the rows say which is which (labels), the merged has none.
        protocol=first.protocol if same_protocol else msgspec.UNSET,
        lookahead=first.lookahead if same_protocol else msgspec.UNSET,
        n_cases=first.n_cases,
        policies=tuple(policies),
        seeds=first.seeds,
        difficulties=first.difficulties,
        table=table,
        per_case=per_case,
        counts=counts,
        errors=tuple(errors),
    )


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


def reliable_groups(diffs: dict[str, Difference | None]) -> dict[str, bool]:
    """Per group of :func:`paired_differences`: whether its interval may be read, i.e. every
    level it covers pairs at least :data:`MIN_RELIABLE_CASES` cases (the average: every level)."""
    levels = {g: d.n_cases >= MIN_RELIABLE_CASES for g, d in diffs.items() if d and g != AVERAGE}
    out = dict(levels)
    if AVERAGE in diffs and diffs[AVERAGE] is not None:
        out[AVERAGE] = bool(levels) and all(levels.values())
    return out


def judged_significant(diff: Difference | None, reliable: bool) -> bool:
    """Significant, and from enough cases to say so."""
    return diff is not None and reliable and diff.significant


def _format_difference(diff: Difference | None, reliable: bool = True) -> str:
    if diff is None:
        return "-"
    lo, hi = diff.interval.low, diff.interval.high
    text = f"{diff.estimate:+.3f} [{lo:+.3f}, {hi:+.3f}]"
    if not reliable:
        return text + UNRELIABLE_MARK
    return f"**{text}**" if diff.significant else text


def _verdict(diff: Difference | None, reliable: bool = True) -> str:
    if diff is None:
        return "-"
    if not reliable:
        return f"not judged (fewer than {MIN_RELIABLE_CASES} cases a level)"
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
    any_unreliable = False
    for row in (r for r in summary.policies if r != reference):
        diffs = paired_differences(summary, row, reference)
        reliable = reliable_groups(diffs)
        any_unreliable |= not all(reliable.values())
        last = diffs.get(groups[-1])
        cells = [row, "-" if last is None else str(last.n_cases)]
        cells += [_format_difference(diffs.get(g), reliable.get(g, True)) for g in groups]
        cells.append(_verdict(last, reliable.get(groups[-1], True)))
        lines.append("| " + " | ".join(cells) + " |")
    if any_unreliable:
        lines += ["", UNRELIABLE_NOTE]
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
