"""Per-decision time of a bench method: mean, 95th percentile and maximum per level (pure).

An episode's mean decision time hides the tail that matters on a robot cell (a planner that
answers in 70 ms on average but once in 2 s stalls the arm), so each step record carries its
own ``decision_s`` (wall) and ``decision_cpu_s`` (process CPU; every thread of a model runtime
counts) and the summary keeps, per level and over ``all`` levels, the mean, the 95th
percentile (linear interpolation between order statistics, numpy's default), the maximum and
where the maximum happened. Records written before these fields existed contribute nothing;
a method none of whose records has them gets no entry (the table shows "-").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from msgspec import UNSET

from packlab.core.records import DecisionTimes, EpisodeOk, RunSummary

#: The group over every level.
ALL_LEVELS = "all"


@dataclass(frozen=True, slots=True)
class _Decision:
    wall_s: float
    cpu_s: float
    level: str
    case_id: str
    seed: int
    step: int


def _decisions(records: Iterable[EpisodeOk]) -> list[_Decision]:
    found = []
    for r in records:
        for s in r.steps:
            if s.decision_s is UNSET:
                continue
            cpu = 0.0 if s.decision_cpu_s is UNSET else float(s.decision_cpu_s)
            found.append(
                _Decision(float(s.decision_s), cpu, r.difficulty, r.case_id, r.seed, s.step)
            )
    return found


def _stats(decisions: Sequence[_Decision]) -> DecisionTimes:
    wall = np.array([d.wall_s for d in decisions], dtype=float)
    cpu = np.array([d.cpu_s for d in decisions], dtype=float)
    # The first of equal maxima in (case, seed, step) order: records are sorted by key first.
    worst = decisions[int(np.argmax(wall))]
    return DecisionTimes(
        decisions=len(decisions),
        mean_ms=round(1000.0 * math.fsum(wall) / len(wall), 3),
        p95_ms=round(1000.0 * float(np.percentile(wall, 95)), 3),
        max_ms=round(1000.0 * float(wall.max()), 3),
        cpu_mean_ms=round(1000.0 * math.fsum(cpu) / len(cpu), 3),
        cpu_max_ms=round(1000.0 * float(cpu.max()), 3),
        worst_case_id=worst.case_id,
        worst_seed=worst.seed,
        worst_step=worst.step,
    )


def decision_times(
    records: Sequence[EpisodeOk], levels: Sequence[str]
) -> dict[str, DecisionTimes] | None:
    """Per level in ``levels`` (those with timed decisions) and over ``all`` of them; None when
    no record has per-step decision times."""
    everything = _decisions(sorted(records, key=lambda r: r.key))
    if not everything:
        return None
    out = {}
    for level in levels:
        mine = [d for d in everything if d.level == level]
        if mine:
            out[level] = _stats(mine)
    out[ALL_LEVELS] = _stats(everything)
    return out


def decision_time_table(summary: RunSummary, display_name: Callable[[str], str] = str) -> str:
    """Markdown: per method and level, the mean / p95 / max decision time in ms (wall), and
    over all levels the maximum CPU time and where the slowest decision was made."""
    levels = list(summary.difficulties)
    header = ["Method", *(f"{lv} mean / p95 / max" for lv in levels), "max CPU", "slowest decision"]
    align = ["---"] + ["---:"] * (len(header) - 2) + ["---"]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    for policy in summary.policies:
        times = summary.counts[policy].decision_times
        times = {} if times is UNSET else times
        cells = [display_name(policy)]
        for level in levels:
            t = times.get(level)
            cells.append("-" if t is None else f"{t.mean_ms:.1f} / {t.p95_ms:.1f} / {t.max_ms:.1f}")
        total = times.get(ALL_LEVELS)
        if total is None:
            cells += ["-", "-"]
        else:
            cells.append(f"{total.cpu_max_ms:.1f}")
            where = f"{total.worst_case_id} seed {total.worst_seed} step {total.worst_step}"
            cells.append(f"{total.max_ms:.1f} ms: {where}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


__all__ = ["ALL_LEVELS", "decision_time_table", "decision_times"]
