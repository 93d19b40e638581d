"""Records -> the numbers of a bench run (pure; the runner and the report both call this).

Aggregation, chosen to match the paper's Table 2 and stated here once:

* A case's score for one seed is that episode's metric (Overall per episode = SR x C, so the
  table's Overall is the mean of per-episode products, not the product of the means).
* A difficulty's score for one seed is the mean over its cases; ``average`` is the mean of the
  difficulty scores (equal weight per difficulty; with equal case counts, the mean over cases).
* Each cell reports the mean over seeds of those per-seed scores and their spread: the sample
  standard deviation across seeds (0 with a single seed).
* Settling (physics backends): ``counts`` has per method the placements whose settle hit the
  per-placement cap (``unsettled_steps``), the episodes scored while boxes still moved because
  the final settle hit its cap (``not_at_rest``; such episodes stay in the means), and the
  largest residual speeds at scoring.
* Answer formats (policies that read a model's text answer, whose steps carry
  ``format_event``): ``counts[method].answer_formats`` counts the steps whose answer was the
  JSON action (``strict_json``), held it among other text (``extra_text``) or held none
  (``parse_fail``), the steps asked a second time (``reasked``) and those a forced set-aside
  replaced (``forced``); absent for other methods.
* Reused episodes (``reused_from_seed``: copies of a seed-free policy's episode,
  ``packlab.bench.reuse``) count as any other in the means and counters, and in ``counts`` as
  ``reused_episodes``; times (per decision, per step, per episode) count played episodes only.
* Failed episodes (``status: "error"``) are left out of the means and counted in ``counts`` and
  ``errors``; the table flags a method with failures, since its mean covers fewer episodes.

* Space utilization (``packlab.metrics.space_utilization``): per episode, packed
  volume / container volume; an online-protocol record carries it (counted up to the first
  box that fits nowhere), a buffer-protocol record is scored from its inside volume and its
  case's container (``container_mm3``; without the cases, buffer runs have no utilization).
  Aggregated like the three metrics (cells, per-case cells, intervals), in its own table
  section; absent from a method none of whose episodes has it.
* Intervals (``run_intervals``, written to summary.json under ``intervals``): per method, group
  and metric a 95 % percentile bootstrap interval of the cell's mean over cases, computed from
  ``per_case`` by ``packlab.bench.intervals`` (cases resampled within each level, the average kept
  as the mean of the levels; seeds resampled within each case too for methods whose scores vary
  across seeds on some case). Fixed resample count and generator seed: the same records give the
  same intervals.

Records are sorted by key before any sum, so the result does not depend on the order in which
parallel workers finished, and the summary of records read back from disk equals the live one.

The result is a ``packlab.core.records.RunSummary`` (summary.json, with its ``format``); a
missing mean (no finished episode) is None, written as null.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Iterable, Mapping, Sequence
from typing import TypedDict

import msgspec
from msgspec import UNSET, Struct, UnsetType

from packlab.bench.decision_times import decision_times
from packlab.bench.describe import difficulty_order
from packlab.bench.intervals import (
    BOOTSTRAP_SEED,
    CONFIDENCE,
    N_RESAMPLES,
    CaseScores,
    bootstrap_interval,
    varies_over_seeds,
)
from packlab.core.records import (
    SUMMARY_FORMAT,
    AnswerFormats,
    CaseCells,
    Cell,
    DecisionTimes,
    EpisodeError,
    EpisodeOk,
    EpisodeRecord,
    ErrorEntry,
    JsonObject,
    MetricCells,
    PolicyCounts,
    RunConfigHead,
    RunSummary,
    SensingModes,
    StepRecord,
    Timing,
)
from packlab.metrics import AVERAGE, METRICS, UTILIZATION

AGGREGATION = (
    "per-seed mean over cases (average: mean of difficulties); mean and sample std over seeds"
)


def _mean(values: Sequence[float]) -> float:
    return math.fsum(values) / len(values) if values else float("nan")


def _std(values: Sequence[float]) -> float:
    """Sample standard deviation (n - 1); 0 for fewer than two values."""
    if len(values) < 2:
        return 0.0
    m = _mean(values)
    return math.sqrt(math.fsum((v - m) ** 2 for v in values) / (len(values) - 1))


def _number(value: float) -> float | None:
    """JSON has no NaN; a missing mean (no finished episode) is None (written as null)."""
    return None if math.isnan(value) else value


def _cell(per_seed: dict[str, float]) -> Cell:
    values = list(per_seed.values())
    return Cell(_number(_mean(values)), _number(_std(values)), per_seed)


def _metric_cells(per_metric: dict[str, dict[str, float]]) -> MetricCells:
    cells = MetricCells(*(_cell(per_metric[m]) for m in METRICS))
    if per_metric.get(UTILIZATION):
        cells = msgspec.structs.replace(cells, space_utilization=_cell(per_metric[UTILIZATION]))
    return cells


def episode_utilization(record: EpisodeOk, container_mm3: Mapping[str, int] | None) -> float | None:
    """An episode's space utilization: the record's own (online protocol), else its inside
    volume over its case's container volume (buffer protocol; None when that is unknown)."""
    carried = record.metrics.space_utilization
    if not isinstance(carried, UnsetType):
        return float(carried)
    volume = None if container_mm3 is None else container_mm3.get(record.case_id)
    return None if not volume else record.metrics.inside_volume_mm3 / volume


def _scored(metrics: Sequence[str], cases: dict[str, dict[int, dict[str, float]]]) -> list[str]:
    """The metrics to aggregate: the three, and utilization where some episode has it."""
    extra = any(UTILIZATION in by_seed for seeds in cases.values() for by_seed in seeds.values())
    return [*metrics, UTILIZATION] if extra else list(metrics)


def _timing(t: Timing, name: str) -> float:
    value = getattr(t, name)
    return 0.0 if value is UNSET or value is None else float(value)


def _counts(mine: list[EpisodeOk], n_errors: int, levels: Sequence[str]) -> PolicyCounts:
    steps = [s for r in mine for s in r.steps]
    # Times count played episodes only: a copy (``reused_from_seed``) carries its lead's times.
    played = [r for r in mine if r.reused_from_seed is UNSET]
    decisions = sum(int(_timing(r.timing, "decisions")) for r in played)
    policy_s = math.fsum(_timing(r.timing, "policy_s") for r in played)
    env_s = math.fsum(_timing(r.timing, "env_s") for r in played)
    reused = len(mine) - len(played)
    return PolicyCounts(
        episodes=len(mine),
        errors=n_errors,
        steps=len(steps),
        # A deliberate set-aside (Action.set_aside, reason "set_aside") is a decision, not a
        # mistake: it shows under "set aside", never as an invalid action.
        invalid_steps=sum(1 for s in steps if not s.valid and s.reason != "set_aside"),
        set_aside=sum(r.metrics.n_set_aside for r in mine),
        unsettled_steps=sum(r.metrics.unsettled_steps for r in mine),
        not_at_rest=sum(1 for r in mine if r.metrics.at_rest is False),
        max_residual_linear_mps=max((r.metrics.residual_linear_mps for r in mine), default=0.0),
        max_residual_angular_radps=max(
            (r.metrics.residual_angular_radps for r in mine), default=0.0
        ),
        decision_ms=1000.0 * policy_s / decisions if decisions else None,
        step_ms=1000.0 * env_s / decisions if decisions else None,
        episode_s=_number(_mean([_timing(r.timing, "episode_s") for r in played])),
        **_perception_counts(mine),
        **_answer_counts(steps),
        **_decision_counts(played, levels),
        **_skill_counts(mine),
        reused_episodes=reused if reused else UNSET,
    )


class _AnswerCounts(TypedDict, total=False):
    """The ``PolicyCounts`` field of methods that read a model's text answer."""

    answer_formats: AnswerFormats


def _answer_counts(steps: Sequence[StepRecord]) -> _AnswerCounts:
    """How the method's answers were read, in steps; none when no step carries a format event
    (the method reads no text answer, or its records predate the key)."""
    events = Counter(s.format_event for s in steps if s.format_event is not UNSET)
    if not events:
        return {}
    return {
        "answer_formats": AnswerFormats(
            strict_json=events["strict_json"],
            extra_text=events["extra_text"],
            parse_fail=events["parse_fail"],
            reasked=sum(1 for s in steps if s.reasked is True),
            forced=sum(1 for s in steps if s.forced is not UNSET),
        )
    }


class _SkillCounts(TypedDict, total=False):
    """The ``PolicyCounts`` field of noisy-execution runs."""

    skill_per_episode: dict[str, float]


def _skill_counts(mine: list[EpisodeOk]) -> _SkillCounts:
    """The place skill's counts per episode (noisy-execution records carry them in their
    metrics; none for other runs and older records): by kind, plus the skill's placements
    (the steps that carry a ``skill`` entry)."""
    carried = [r for r in mine if r.metrics.skill is not UNSET]
    if not carried:
        return {}
    totals: dict[str, float] = {
        "placements": float(sum(s.skill is not UNSET for r in carried for s in r.steps))
    }
    for r in carried:
        skill = r.metrics.skill
        assert not isinstance(skill, UnsetType)
        for kind, count in skill.items():
            totals[kind] = totals.get(kind, 0.0) + count
    return {"skill_per_episode": {k: v / len(carried) for k, v in sorted(totals.items())}}


class _DecisionCounts(TypedDict, total=False):
    """The ``PolicyCounts`` field of runs whose records time each decision."""

    decision_times: dict[str, DecisionTimes]


def _decision_counts(mine: list[EpisodeOk], levels: Sequence[str]) -> _DecisionCounts:
    times = decision_times(mine, levels)
    return {} if times is None else {"decision_times": times}


class _PerceptionCounts(TypedDict, total=False):
    """The ``PolicyCounts`` fields of perceived runs."""

    replans_per_episode: float
    missed_per_episode: float
    looked_again_per_episode: float
    dims_error_mm: float | None
    yaw_error_deg: float | None
    heightmap_mae_mm: float | None


class _RunFields(TypedDict, total=False):
    """The ``RunSummary`` fields taken from config.json."""

    suite: str | None
    backend: str | None
    n_cases: int | None
    cases_sha256: str | None
    sensing: SensingModes
    protocol: str
    lookahead: int
    policy_args: dict[str, JsonObject]


def _run_fields(meta: RunConfigHead, policies: Sequence[str]) -> _RunFields:
    """The summary's fields taken from the run's config.json."""
    run: _RunFields = {
        "suite": meta.suite,
        "backend": meta.backend,
        "n_cases": meta.n_cases,
        "cases_sha256": meta.cases_sha256,
    }
    # Only for runs with a perceived or noisy mode: exact summaries are unchanged.
    if meta.sensing is not None:
        run["sensing"] = meta.sensing
    if meta.protocol is not None:  # absent: a run made before the choice (buffer)
        run["protocol"] = meta.protocol
    if meta.lookahead is not None:
        run["lookahead"] = meta.lookahead
    # The options of the policies summarized (row labels); none: the summary is unchanged.
    given = meta.policy_args or {}
    options = {p: given[p] for p in policies if p in given}
    if options:
        run["policy_args"] = options
    return run


def _perception_counts(mine: list[EpisodeOk]) -> _PerceptionCounts:
    """Perceived runs' counters; none for exact runs: their summary is unchanged."""
    replans = [r.metrics.replans for r in mine if r.metrics.replans is not UNSET]
    if not replans:
        return {}
    seen = [s.perception for r in mine for s in r.steps if s.perception is not UNSET]
    dims = [v for p in seen for v in p.dims_error_mm if v is not None]
    yaws = [v for p in seen for v in p.yaw_error_deg if v is not None]
    maes = [p.heightmap_mae_mm for p in seen if p.heightmap_mae_mm is not None]
    missed = [r.metrics.missed for r in mine if r.metrics.missed is not UNSET]
    counts: _PerceptionCounts = {"replans_per_episode": math.fsum(replans) / len(replans)}
    if missed:
        counts["missed_per_episode"] = math.fsum(missed) / len(missed)
        # Records carry looked_again only where it happened: absent counts as 0.
        again = [0 if r.metrics.looked_again is UNSET else r.metrics.looked_again for r in mine]
        counts["looked_again_per_episode"] = math.fsum(again) / len(again)
    counts["dims_error_mm"] = _number(_mean(dims))
    counts["yaw_error_deg"] = _number(_mean(yaws))
    counts["heightmap_mae_mm"] = _number(_mean(maes))
    return counts


#: Scores by (policy, difficulty) -> case -> seed -> metric.
Scores = dict[tuple[str, str], dict[str, dict[int, dict[str, float]]]]


def _policy_cells(
    value: Scores, policy: str, seeds: list[int], difficulties: list[str]
) -> tuple[dict[str, MetricCells], dict[str, CaseCells]]:
    """One policy's table cells (per difficulty and the average) and its per-case cells."""
    per_case: dict[str, CaseCells] = {}
    by_group: dict[str, dict[str, dict[str, float]]] = {}  # group -> metric -> seed -> score
    every_case = {c: v for d in difficulties for c, v in value.get((policy, d), {}).items()}
    metrics = _scored(METRICS, every_case)
    for d in difficulties:
        cases = value.get((policy, d), {})
        by_group[d] = {}
        for m in metrics:
            by_group[d][m] = {}
            for s in seeds:
                scores = [cases[c][s][m] for c in sorted(cases) if m in cases[c].get(s, {})]
                if scores:
                    by_group[d][m][str(s)] = _mean(scores)
        for c in sorted(cases):
            seeds_of_case = [s for s in seeds if s in cases[c]]
            cells = {
                m: _cell({str(s): cases[c][s][m] for s in seeds_of_case if m in cases[c][s]})
                for m in metrics
            }
            per_case[c] = CaseCells(d, *(cells[m] for m in METRICS))
            if UTILIZATION in cells and cells[UTILIZATION].per_seed:
                per_case[c] = msgspec.structs.replace(
                    per_case[c], space_utilization=cells[UTILIZATION]
                )
    by_group[AVERAGE] = {}
    for m in metrics:
        by_group[AVERAGE][m] = {}
        for s in seeds:
            parts = [by_group[d][m][str(s)] for d in difficulties if str(s) in by_group[d][m]]
            if len(parts) == len(difficulties) and parts:
                by_group[AVERAGE][m][str(s)] = _mean(parts)
    return {g: _metric_cells(per_metric) for g, per_metric in by_group.items()}, per_case


def summarize(
    records: Iterable[EpisodeRecord],
    policies: Sequence[str] | None = None,
    seeds: Sequence[int] | None = None,
    difficulties: Sequence[str] | None = None,
    meta: RunConfigHead | None = None,
    container_mm3: Mapping[str, int] | None = None,
) -> RunSummary:
    """The summary of a run's records; see the module docstring for the rules.

    ``policies`` / ``seeds`` / ``difficulties`` fix the order (and selection) of rows and
    columns; by default they are taken from the records. ``meta`` (the run's config.json) names
    the suite, backend and cases; ``container_mm3`` (container volume by case id) scores the
    space utilization of records that do not carry it (buffer protocol).
    """
    recs = sorted(records, key=lambda r: r.key)
    if policies is None:
        policies = list(dict.fromkeys(r.policy for r in recs))
    if seeds is None:
        seeds = sorted({r.seed for r in recs})
    if difficulties is None:
        difficulties = difficulty_order([r.difficulty for r in recs])
    policies, seeds, difficulties = list(policies), [int(s) for s in seeds], list(difficulties)
    wanted = set(policies)
    recs = [
        r for r in recs if r.policy in wanted and r.seed in seeds and r.difficulty in difficulties
    ]
    ok = [r for r in recs if isinstance(r, EpisodeOk)]
    errors = [r for r in recs if isinstance(r, EpisodeError)]

    # metric value by (policy, difficulty, case, seed)
    value: Scores = defaultdict(lambda: defaultdict(dict))
    for r in ok:
        scores = {m: float(getattr(r.metrics, m)) for m in METRICS}
        utilization = episode_utilization(r, container_mm3)
        if utilization is not None:
            scores[UTILIZATION] = utilization
        value[(r.policy, r.difficulty)][r.case_id][r.seed] = scores

    table: dict[str, dict[str, MetricCells]] = {}
    per_case: dict[str, dict[str, CaseCells]] = {}
    for p in policies:
        table[p], per_case[p] = _policy_cells(value, p, seeds, difficulties)

    counts = {
        p: _counts(
            [r for r in ok if r.policy == p],
            sum(1 for r in errors if r.policy == p),
            difficulties,
        )
        for p in policies
    }
    run = {} if meta is None else _run_fields(meta, policies)
    return RunSummary(
        format=SUMMARY_FORMAT,
        **run,
        policies=tuple(policies),
        seeds=tuple(seeds),
        difficulties=tuple(difficulties),
        metrics=tuple(METRICS),
        aggregation=AGGREGATION,
        table=table,
        per_case=per_case,
        counts=counts,
        errors=tuple(ErrorEntry(r.case_id, r.seed, r.policy, r.error) for r in errors),
    )


#: How a method's intervals resampled: cases only (its scores are the same for every seed on
#: every case) or cases and then seeds within each case (the two-level bootstrap).
RESAMPLED_CASES = "cases"
RESAMPLED_CASES_SEEDS = "cases, then seeds within each case"
INTERVAL_METHOD = (
    "percentile bootstrap of the mean over cases of each case's mean over seeds; cases resampled "
    "within each level (average: mean of the levels' resampled means)"
)


class PolicyIntervals(Struct, frozen=True):
    """One method's intervals: ``cells[group][metric]`` is ``[low, high]`` (None: no scores)."""

    resampled: str  # RESAMPLED_CASES or RESAMPLED_CASES_SEEDS
    cells: dict[str, dict[str, tuple[float, float] | None]]


class RunIntervals(Struct, frozen=True, kw_only=True):
    """summary.json ``intervals``: the bootstrap's settings and every method's intervals."""

    confidence: float
    resamples: int
    seed: int
    method: str
    policies: dict[str, PolicyIntervals]

    def bounds(self, policy: str, group: str, metric: str) -> tuple[float, float] | None:
        row = self.policies.get(policy)
        return None if row is None else row.cells.get(group, {}).get(metric)


def _strata(cases: dict[str, CaseCells], levels: Sequence[str], metric: str) -> list[CaseScores]:
    return [
        {
            c: _case_cell(cells, metric).per_seed
            for c, cells in cases.items()
            if cells.difficulty == d
        }
        for d in levels
    ]


def _case_cell(cells: CaseCells, metric: str) -> Cell:
    value = getattr(cells, metric)
    if isinstance(value, UnsetType):  # a case with no utilization: no scores for it
        return Cell(None, None, {})
    assert isinstance(value, Cell), metric
    return value


def interval_metrics(cases: Mapping[str, CaseCells]) -> tuple[str, ...]:
    """The metrics a method has intervals for: the three, and utilization where known."""
    known = any(not isinstance(c.space_utilization, UnsetType) for c in cases.values())
    return (*METRICS, UTILIZATION) if known else METRICS


def policy_intervals(summary: RunSummary, policy: str) -> PolicyIntervals:
    """A method's intervals from its per-case cells (none for summaries without them)."""
    cases = summary.per_case.get(policy, {})
    stochastic = varies_over_seeds(
        _case_cell(cells, m).per_seed for cells in cases.values() for m in METRICS
    )
    groups = [(d, [d]) for d in summary.difficulties]
    groups.append((AVERAGE, list(summary.difficulties)))
    out: dict[str, dict[str, tuple[float, float] | None]] = {}
    for group, levels in groups:
        out[group] = {}
        for m in interval_metrics(cases):
            found = bootstrap_interval(_strata(cases, levels, m), over_seeds=stochastic)
            out[group][m] = None if found is None else (found.low, found.high)
    return PolicyIntervals(RESAMPLED_CASES_SEEDS if stochastic else RESAMPLED_CASES, out)


def run_intervals(summary: RunSummary) -> RunIntervals:
    """Every method's intervals (see the module docstring); a pure function of ``per_case``."""
    return RunIntervals(
        confidence=CONFIDENCE,
        resamples=N_RESAMPLES,
        seed=BOOTSTRAP_SEED,
        method=INTERVAL_METHOD,
        policies={p: policy_intervals(summary, p) for p in summary.policies},
    )


__all__ = [
    "AGGREGATION",
    "AVERAGE",
    "METRICS",
    "RESAMPLED_CASES",
    "RESAMPLED_CASES_SEEDS",
    "PolicyIntervals",
    "RunIntervals",
    "episode_utilization",
    "interval_metrics",
    "policy_intervals",
    "run_intervals",
    "summarize",
]
