"""Bootstrap intervals for bench scores (pure: numpy only, no I/O, the random draws seeded).

Why a bootstrap: a bench suite is a sample of cases, and how much a table's mean would move on
another sample of the same recipe is the uncertainty a reader needs. Deterministic policies play
every run seed identically, so the spread over seeds (the table's old "± 0.000") says nothing
about that; resampling cases does.

The statistic is the bench summary's: the mean over strata (difficulty levels; one stratum for a
single level) of the mean over a stratum's cases of the case's mean over its seeds, so the
"average" keeps equal weight per level. One resample draws, in every stratum independently, as
many cases as it has, with replacement (stratified, so every resample holds each level's case
count); with ``over_seeds`` (policies whose scores vary across seeds on a case) it then draws,
within every drawn case, as many of that case's seed values as it has, with replacement (the
two-level bootstrap). The interval is the percentile interval of the resampled statistics.

A fixed generator seed (``BOOTSTRAP_SEED``, a fresh generator per interval) makes an interval a
function of its data alone: the same records give the same interval, whatever else the run
holds or the order it was computed in.

Paired differences (two methods on the same cases): per case the mean over the seeds both have
of the difference a - b, bootstrapped as above over the cases both have. A difference is
significant only where its interval excludes 0.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

#: Two-sided coverage of every interval.
CONFIDENCE = 0.95
#: Resamples per interval: enough that the 2.5 % / 97.5 % percentiles move by well under the
#: tables' third decimal between generator seeds on bench-sized suites.
N_RESAMPLES = 2000
#: The bootstrap generator's seed, fixed so that intervals are reproducible.
BOOTSTRAP_SEED = 0

#: One stratum's scores: case id -> seed (as a string, the summary's key) -> score.
CaseScores = Mapping[str, Mapping[str, float]]


@dataclass(frozen=True, slots=True)
class Interval:
    """A two-sided bootstrap interval (``low <= high``)."""

    low: float
    high: float

    def excludes(self, value: float = 0.0) -> bool:
        return value < self.low or value > self.high


@dataclass(frozen=True, slots=True)
class Difference:
    """A paired difference a - b: its estimate, interval and the number of cases paired."""

    estimate: float
    interval: Interval
    n_cases: int

    @property
    def significant(self) -> bool:
        """True only where the interval excludes 0."""
        return self.interval.excludes(0.0)


def varies_over_seeds(cases: Iterable[Mapping[str, float]]) -> bool:
    """True when some case's scores differ across seeds (a stochastic policy)."""
    return any(len(set(seeds.values())) > 1 for seeds in cases)


def _matrix(stratum: CaseScores) -> tuple[np.ndarray, np.ndarray]:
    """(values, counts): values (n_cases, max_seeds) float64 padded with 0 past each case's
    count; counts (n_cases,) int64. Cases and seeds in sorted order (determinism)."""
    rows = [[float(v) for _, v in sorted(stratum[c].items())] for c in sorted(stratum)]
    rows = [r for r in rows if r]
    counts = np.array([len(r) for r in rows], dtype=np.int64)
    values = np.zeros((len(rows), int(counts.max()) if rows else 0), dtype=np.float64)
    for i, r in enumerate(rows):
        values[i, : len(r)] = r
    return values, counts


def _stratum_means(
    values: np.ndarray, counts: np.ndarray, rng: np.random.Generator, n: int, over_seeds: bool
) -> np.ndarray:
    """(n,) resampled means of one stratum (cases, then seeds within each case if asked)."""
    k, width = values.shape
    pick = rng.integers(0, k, size=(n, k))
    if not over_seeds or width == 1:
        case_means = values.sum(axis=1) / counts
        return case_means[pick].mean(axis=1)
    drawn = counts[pick]  # (n, k): seed count of each drawn case
    slot = np.minimum((rng.random((n, k, width)) * drawn[..., None]).astype(np.int64), width - 1)
    used = np.arange(width) < drawn[..., None]
    taken = np.where(used, values[pick[..., None], slot], 0.0)
    return (taken.sum(axis=2) / drawn).mean(axis=1)


def point_estimate(strata: Sequence[CaseScores]) -> float | None:
    """The statistic on the data itself (None when a stratum has no scores)."""
    parts = []
    for stratum in strata:
        values, counts = _matrix(stratum)
        if counts.size == 0:
            return None
        parts.append(float((values.sum(axis=1) / counts).mean()))
    return float(np.mean(parts)) if parts else None


def bootstrap_interval(
    strata: Sequence[CaseScores],
    *,
    over_seeds: bool,
    resamples: int = N_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
    confidence: float = CONFIDENCE,
) -> Interval | None:
    """The percentile interval of the statistic (module docstring); None when any stratum has
    no scores (as the summary's average needs every level)."""
    if not strata or not 0.0 < confidence < 1.0 or resamples < 1:
        raise ValueError(f"need strata, 0 < confidence < 1 and resamples >= 1 ({confidence=})")
    matrices = [_matrix(s) for s in strata]
    if any(counts.size == 0 for _, counts in matrices):
        return None
    rng = np.random.default_rng(seed)
    total = np.zeros(resamples, dtype=np.float64)
    for values, counts in matrices:
        total += _stratum_means(values, counts, rng, resamples, over_seeds)
    stats = total / len(matrices)
    tail = (1.0 - confidence) / 2.0
    low, high = np.quantile(stats, [tail, 1.0 - tail])
    return Interval(float(low), float(high))


def paired_units(a: CaseScores, b: CaseScores) -> dict[str, dict[str, float]]:
    """Per case both have, the differences a - b on the seeds both have (others dropped)."""
    out: dict[str, dict[str, float]] = {}
    for case in sorted(set(a) & set(b)):
        common = sorted(set(a[case]) & set(b[case]))
        if common:
            out[case] = {s: float(a[case][s]) - float(b[case][s]) for s in common}
    return out


def paired_difference(
    a: Sequence[CaseScores],
    b: Sequence[CaseScores],
    *,
    over_seeds: bool,
    resamples: int = N_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
    confidence: float = CONFIDENCE,
) -> Difference | None:
    """a - b over the common (case, seed) units, stratum by stratum (``a[i]`` pairs with
    ``b[i]``); None when some stratum has no common unit."""
    if len(a) != len(b):
        raise ValueError(f"{len(a)} strata against {len(b)}")
    diffs = [paired_units(x, y) for x, y in zip(a, b)]
    estimate = point_estimate(diffs) if diffs else None
    interval = (
        bootstrap_interval(
            diffs, over_seeds=over_seeds, resamples=resamples, seed=seed, confidence=confidence
        )
        if estimate is not None
        else None
    )
    if estimate is None or interval is None:
        return None
    return Difference(estimate, interval, sum(len(d) for d in diffs))


__all__ = [
    "BOOTSTRAP_SEED",
    "CONFIDENCE",
    "N_RESAMPLES",
    "CaseScores",
    "Difference",
    "Interval",
    "bootstrap_interval",
    "paired_difference",
    "paired_units",
    "point_estimate",
    "varies_over_seeds",
]
