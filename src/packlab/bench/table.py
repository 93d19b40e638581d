"""Summary -> the Table-2-style Markdown table (and a run-details table), pure string building.

Each results cell is the mean over seeds with its 95 % bootstrap interval over cases
(``packlab.bench.summary.run_intervals``): ``0.961 [0.930, 0.987]``. The spread over run seeds
is its own, labelled column (Average Overall), since for policies that play every seed alike it
is 0 and says nothing about how sure the mean is.

A row is labelled with its method and the options it ran with that change what it measures
(:func:`row_name`: ``endpoint (reference prompt, image=blank)``). Methods that read a model's
text answer get an "Answer format" table: how their answers were read, in steps.
"""

from __future__ import annotations

from msgspec import UNSET, UnsetType

from packlab.bench.decision_times import decision_time_table
from packlab.bench.summary import RESAMPLED_CASES, RunIntervals, run_intervals
from packlab.core.records import AnswerFormats, Cell, JsonObject, RunSummary, SensingModes
from packlab.metrics import AVERAGE, METRICS, UTILIZATION
from packlab.viz.labels import METRIC_SHORT, group_title, policy_label


def policy_options(summary: RunSummary, policy: str) -> JsonObject | None:
    """The ``--policy-arg`` options ``policy`` ran with (None: none recorded)."""
    args = summary.policy_args
    return None if isinstance(args, UnsetType) else args.get(policy)


def row_name(summary: RunSummary, policy: str) -> str:
    """How a row of ``summary`` is labelled in table.md, report.html and comparisons: the
    method's display name with the options that change what it measures, e.g.
    ``endpoint (reference prompt)`` (``packlab.viz.labels.policy_label``)."""
    return policy_label(policy, policy_options(summary, policy))


def format_cell(
    cell: Cell | None, digits: int = 3, bounds: tuple[float, float] | None = None
) -> str:
    """``"0.812 [0.790, 0.833]"``: mean over seeds and its 95 % bootstrap interval; the mean
    alone when there is no interval (a summary without per-case cells); ``-`` when nothing ran."""
    if cell is None or cell.mean is None:
        return "-"
    if bounds is None:
        return f"{cell.mean:.{digits}f}"
    return f"{cell.mean:.{digits}f} [{bounds[0]:.{digits}f}, {bounds[1]:.{digits}f}]"


def format_spread(cell: Cell | None, digits: int = 3) -> str:
    """The sample std of the per-seed scores (``-`` with fewer than two seeds scored)."""
    if cell is None or cell.std is None or len(cell.per_seed) < 2:
        return "-"
    return f"{cell.std:.{digits}f}"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _cell(summary: RunSummary, policy: str, group: str, metric: str) -> Cell | None:
    cells = summary.table[policy].get(group)
    return None if cells is None else cells.cell(metric)


#: The results table's last column: the spread of the last group's Overall over run seeds.
SPREAD_COLUMN = "Overall sd over seeds"


def results_table(
    summary: RunSummary, digits: int = 3, intervals: RunIntervals | None = None
) -> str:
    """Rows = methods; column groups = difficulties and the average; SR, Compactness, Overall,
    each ``mean [95 % interval]``; then the Overall's sample std over seeds (several seeds).
    The note under the table (``interval_note``) names the methods whose intervals also
    resampled seeds."""
    intervals = run_intervals(summary) if intervals is None else intervals
    groups = list(summary.difficulties)
    if len(groups) > 1:
        groups.append(AVERAGE)
    spread = len(summary.seeds) > 1 and bool(groups)
    header = ["Method"] + [f"{group_title(g)} {METRIC_SHORT[m]}" for g in groups for m in METRICS]
    if spread:
        header.append(f"{group_title(groups[-1])} {SPREAD_COLUMN}")
    lines = [_row(header), _row(["---"] + ["---:"] * (len(header) - 1))]
    for p in summary.policies:
        flag = " *" if summary.counts[p].errors else ""
        cells = [f"{row_name(summary, p)}{flag}"]
        cells += [
            format_cell(_cell(summary, p, g, m), digits, intervals.bounds(p, g, m))
            for g in groups
            for m in METRICS
        ]
        if spread:
            cells.append(format_spread(_cell(summary, p, groups[-1], "overall"), digits))
        lines.append(_row(cells))
    return "\n".join(lines)


def interval_note(summary: RunSummary, intervals: RunIntervals) -> str:
    """One paragraph under the results table: how the intervals were computed."""
    both = [
        row_name(summary, p)
        for p in summary.policies
        if p in intervals.policies and intervals.policies[p].resampled != RESAMPLED_CASES
    ]
    text = (
        f"[low, high]: {intervals.confidence * 100:.0f} % bootstrap interval of the mean "
        f"({intervals.resamples} resamples, generator seed {intervals.seed}): cases resampled "
        "within each level, the average kept as the mean of the levels"
    )
    if both:
        names = ", ".join(both)
        text += f"; for {names} (scores vary across seeds) seeds also resampled within each case"
    if not summary.per_case:
        text += "; none here: this summary has no per-case scores (rebuild it with bench report)"
    return text + "."


def utilization_table(summary: RunSummary, intervals: RunIntervals) -> str:
    """Per method, the space utilization (packed volume / container volume) per level
    and on average, each ``mean [95 % interval]``; empty when no method has it."""
    rows = [
        p
        for p in summary.policies
        if any(
            not isinstance(cells.space_utilization, UnsetType)
            for cells in summary.table[p].values()
        )
    ]
    if not rows:
        return ""
    groups = list(summary.difficulties)
    if len(groups) > 1:
        groups.append(AVERAGE)
    lines = [_row(["Method", *(group_title(g) for g in groups)])]
    lines.append(_row(["---"] + ["---:"] * len(groups)))
    for p in rows:
        cells = []
        for g in groups:
            found = summary.table[p].get(g)
            value = None if found is None else found.space_utilization
            cell = None if isinstance(value, UnsetType) else value
            cells.append(format_cell(cell, 3, intervals.bounds(p, g, UTILIZATION)))
        lines.append(_row([row_name(summary, p), *cells]))
    return "\n".join(lines)


#: The utilization section's title: what is counted, and up to where.
UTILIZATION_TITLE = (
    "### Space utilization (packed volume / container volume; online protocol: up to the "
    "first box that fits nowhere)"
)


def details_table(summary: RunSummary) -> str:
    """Per method: episodes, failures, invalid actions, objects set aside, settling, time per step.

    ``invalid actions``: steps the episode refused (bad id, footprint outside, unparsable
    answer); a deliberate set-aside is not one. ``set aside``: boxes left unpacked for any
    reason (deliberate, after an invalid action, or not found by perception).

    ``unsettled steps``: placements whose settle hit the per-placement cap; ``not at rest``:
    episodes scored while boxes still moved (the final settle hit its cap). Summaries written
    before these counts existed show their ``capped_placements`` (migrated to
    ``unsettled_steps``) and ``-``.
    """
    header = [
        "Method",
        "episodes",
        "errors",
        "invalid actions",
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
                    row_name(summary, p),
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


#: The place skill's counts in the order table.md shows them (``place_skill.SkillReport``);
#: kinds a newer skill adds follow in name order.
SKILL_KINDS = (
    "placements",
    "descended",
    "slid",
    "slid_off_edge",
    "turned",
    "probed",
    "stopped_high",
    "retried",
    "budget_spent",
    "lifted",
    "seated",
    "push_missed",
    "seat_turned",
)


def skill_table(summary: RunSummary) -> str:
    """Per method of a noisy-execution run: how often per episode the place skill had to act
    and how (``PolicyCounts.skill_per_episode``); empty when no method has the counts."""
    counts = {
        p: c
        for p in summary.policies
        if not isinstance(c := summary.counts[p].skill_per_episode, UnsetType)
    }
    if not counts:
        return ""
    seen = {k for c in counts.values() for k in c}
    kinds = [k for k in SKILL_KINDS if k in seen] + sorted(seen - set(SKILL_KINDS))
    lines = [_row(["Method", *kinds]), _row(["---"] + ["---:"] * len(kinds))]
    for p, c in counts.items():
        lines.append(_row([row_name(summary, p), *(f"{c.get(k, 0.0):.2f}" for k in kinds)]))
    return "\n".join(lines)


#: The answer-format table's columns: ``AnswerFormats`` field and heading.
ANSWER_FORMAT_COLUMNS = (
    ("strict_json", "strict JSON"),
    ("extra_text", "extra text"),
    ("parse_fail", "parse failures"),
    ("reasked", "re-asks"),
    ("forced", "forced set-asides"),
)
#: The answer-format section's title: what each column counts.
ANSWER_FORMAT_TITLE = (
    "### Answer format (steps: the answer was the JSON action, held it among other text, or "
    "held none; asked a second time; replaced by a forced set-aside)"
)


def answer_formats(summary: RunSummary) -> dict[str, AnswerFormats]:
    """The methods of ``summary`` that read a model's text answer, with their counts."""
    return {
        p: c
        for p in summary.policies
        if not isinstance(c := summary.counts[p].answer_formats, UnsetType)
    }


def answer_format_table(summary: RunSummary) -> str:
    """Per method that reads a model's text answer: its steps by how the answer was read, the
    re-asks and the forced set-asides (``PolicyCounts.answer_formats``); empty when no method
    has the counts."""
    rows = answer_formats(summary)
    if not rows:
        return ""
    lines = [_row(["Method", *(title for _, title in ANSWER_FORMAT_COLUMNS)])]
    lines.append(_row(["---"] + ["---:"] * len(ANSWER_FORMAT_COLUMNS)))
    for p, c in rows.items():
        counts = [str(getattr(c, field)) for field, _ in ANSWER_FORMAT_COLUMNS]
        lines.append(_row([row_name(summary, p), *counts]))
    return "\n".join(lines)


def reuse_note(summary: RunSummary) -> str:
    """One line on the episodes copied instead of played (``packlab.bench.reuse``), per
    method; "" when none was."""
    reused = {
        p: n for p in summary.policies if isinstance(n := summary.counts[p].reused_episodes, int)
    }
    if not reused:
        return ""
    total = sum(c.episodes for c in summary.counts.values())
    rows = ", ".join(f"{row_name(summary, p)} {n}" for p, n in reused.items())
    lead = min(summary.seeds) if summary.seeds else 0
    return (
        f"Reused: {sum(reused.values())} of {total} episodes ({rows}) are copies of seed "
        f"{lead}'s episode of the same case, not played: these methods play the same episode "
        "for every run seed. Times count played episodes only; --no-reuse plays every seed."
    )


def size_prior_note(summary: RunSummary) -> str:
    """``", size prior grid"`` for a run with perceived observation (the prior on box sizes
    perception was given; absent from its summary: ``grid``, the only one before it was a
    choice), empty otherwise: a prior the robot is given is named wherever its figures are."""
    sensing = summary.sensing
    if not isinstance(sensing, SensingModes) or sensing.observation != "perceived":
        return ""
    prior = sensing.size_prior if isinstance(sensing.size_prior, str) else "grid"
    return f", size prior {prior}"


def headline(summary: RunSummary) -> str:
    seeds = ",".join(str(s) for s in summary.seeds)
    n_cases = summary.n_cases if isinstance(summary.n_cases, int) else None
    cases = f", {n_cases} cases" if n_cases is not None else ""
    # An absent suite or backend reads as a default; a null one prints as None (as it always has).
    suite = "bench" if summary.suite is UNSET else summary.suite
    backend = "?" if summary.backend is UNSET else summary.backend
    # Named only when online: buffer tables read as they always have.
    protocol = ""
    if summary.protocol == "online":
        k = summary.lookahead if isinstance(summary.lookahead, int) else 1
        protocol = f", protocol online (BPP-{k})"
    elif summary.protocol == "offline":
        protocol = ", protocol offline (every box shown)"
    return (
        f"{suite}: backend {backend}{protocol}{size_prior_note(summary)}, seeds {seeds}{cases}; "
        f"mean over seeds [95 % bootstrap interval over cases]"
    )


def render_markdown(summary: RunSummary, intervals: RunIntervals | None = None) -> str:
    """The whole table.md: headline, results table, interval note, failure note, details."""
    intervals = run_intervals(summary) if intervals is None else intervals
    parts = [f"## {headline(summary)}", "", results_table(summary, intervals=intervals), ""]
    parts += [interval_note(summary, intervals), ""]
    if summary.errors:
        n = len(summary.errors)
        parts += [
            (
                f"\\* {n} episode(s) failed and are left out of the means; "
                "see summary.json 'errors' and the tracebacks in episodes.jsonl."
            ),
            "",
        ]
    utilization = utilization_table(summary, intervals)
    if utilization:
        parts += [UTILIZATION_TITLE, "", utilization, ""]
    parts += ["### Run details", "", details_table(summary), ""]
    reused = reuse_note(summary)
    if reused:
        parts += [reused, ""]
    formats = answer_format_table(summary)
    if formats:
        parts += [ANSWER_FORMAT_TITLE, "", formats, ""]
    skill = skill_table(summary)
    if skill:
        parts += [
            "### Place skill (per episode: placements it made, and how often it had to recover)",
            "",
            skill,
            "",
        ]
    if any(summary.counts[p].decision_times is not UNSET for p in summary.policies):
        parts += [
            "### Decision time (ms per decision, wall; CPU: the process's)",
            "",
            decision_time_table(summary, lambda p: row_name(summary, p)),
            "",
        ]
    return "\n".join(parts)


__all__ = [
    "ANSWER_FORMAT_COLUMNS",
    "SPREAD_COLUMN",
    "answer_format_table",
    "answer_formats",
    "details_table",
    "format_cell",
    "format_spread",
    "headline",
    "interval_note",
    "policy_options",
    "render_markdown",
    "results_table",
    "reuse_note",
    "row_name",
    "skill_table",
    "utilization_table",
]
