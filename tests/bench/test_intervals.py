"""The bootstrap of ``packlab.bench.intervals`` on data with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from packlab.bench.intervals import (
    Interval,
    bootstrap_interval,
    paired_difference,
    paired_units,
    point_estimate,
    varies_over_seeds,
)


def _cases(values, seeds=1):
    """One stratum: case i -> every seed -> values[i] (a deterministic policy)."""
    return {f"c{i:03d}": {str(s): float(v) for s in range(seeds)} for i, v in enumerate(values)}


def test_constant_data_gives_a_point_at_the_constant():
    found = bootstrap_interval([_cases([0.7] * 25, seeds=3)], over_seeds=True)
    assert found is not None and found.low == found.high == pytest.approx(0.7)


def test_the_interval_holds_the_mean_and_narrows_with_more_cases():
    rng = np.random.default_rng(1)
    small = _cases(rng.uniform(0, 1, 20))
    large = _cases(rng.uniform(0, 1, 320))
    a = bootstrap_interval([small], over_seeds=False)
    b = bootstrap_interval([large], over_seeds=False)
    assert a.low < point_estimate([small]) < a.high and b.low < point_estimate([large]) < b.high
    # the standard error falls as 1/sqrt(n): 16 times the cases, about a quarter of the width
    ratio = (b.high - b.low) / (a.high - a.low)
    assert 0.15 < ratio < 0.4


def test_coverage_of_a_known_mean_is_near_95_percent():
    """Simulated suites of 40 cases with scores ~ Beta(4, 2) (mean 2/3): about 95 % of their
    intervals hold 2/3. Wrong arithmetic (a spread over cases instead of an error of the mean,
    or no resampling) lands near 100 % or far below."""
    rng = np.random.default_rng(7)
    trials, hits = 400, 0
    for t in range(trials):
        found = bootstrap_interval(
            [_cases(rng.beta(4, 2, 40))], over_seeds=False, resamples=500, seed=t
        )
        hits += found.low <= 2 / 3 <= found.high
    assert 0.90 <= hits / trials <= 0.98


def test_two_level_coverage_with_seed_noise():
    """Case effects plus per-seed noise (3 seeds): the two-level interval covers the true mean
    at least nominally (it counts seed noise twice, so it may be a little wide)."""
    rng = np.random.default_rng(11)
    trials, hits = 300, 0
    for t in range(trials):
        case_means = rng.normal(0.6, 0.1, 30)
        stratum = {
            f"c{i}": {str(s): float(m + rng.normal(0, 0.1)) for s in range(3)}
            for i, m in enumerate(case_means)
        }
        found = bootstrap_interval([stratum], over_seeds=True, resamples=500, seed=t)
        hits += found.low <= 0.6 <= found.high
    assert 0.92 <= hits / trials <= 1.0


def test_seeds_resampled_only_when_asked_and_only_they_add_width():
    # every case has the same mean over seeds: cases alone carry no uncertainty; seeds do
    stratum = {f"c{i}": {"0": 0.4, "1": 0.6, "2": 0.5} for i in range(20)}
    cases_only = bootstrap_interval([stratum], over_seeds=False)
    both = bootstrap_interval([stratum], over_seeds=True)
    assert cases_only.low == cases_only.high == pytest.approx(0.5)
    assert both.low < 0.5 < both.high
    # a deterministic policy (equal scores per seed): the seed level changes nothing
    rng = np.random.default_rng(3)
    det = _cases(rng.uniform(0, 1, 30), seeds=3)
    assert bootstrap_interval([det], over_seeds=True) == bootstrap_interval([det], over_seeds=False)


def test_uneven_seed_counts_are_averaged_per_case():
    stratum = {"a": {"0": 1.0, "1": 0.0}, "b": {"0": 1.0}}  # case means 0.5 and 1.0
    assert point_estimate([stratum]) == pytest.approx(0.75)
    found = bootstrap_interval([stratum], over_seeds=True)
    assert 0.0 <= found.low <= 0.75 <= found.high <= 1.0


def test_average_weighs_levels_equally_and_resamples_within_them():
    easy = _cases([1.0] * 10)  # constant levels: any cross-level mixing would move the mean
    hard = _cases([0.0] * 90)
    assert point_estimate([easy, hard]) == pytest.approx(0.5)  # not the pooled 0.1
    found = bootstrap_interval([easy, hard], over_seeds=False)
    assert found.low == found.high == pytest.approx(0.5)
    assert bootstrap_interval([easy, {}], over_seeds=False) is None  # a level with no scores


def test_same_data_same_interval_whatever_the_order_and_seed_matters():
    rng = np.random.default_rng(5)
    stratum = {f"c{i}": {str(s): float(rng.uniform()) for s in range(3)} for i in range(30)}
    shuffled = {c: dict(reversed(stratum[c].items())) for c in reversed(list(stratum))}
    first = bootstrap_interval([stratum], over_seeds=True)
    assert bootstrap_interval([shuffled], over_seeds=True) == first
    assert bootstrap_interval([stratum], over_seeds=True, seed=1) != first


def test_paired_difference_finds_a_clear_shift():
    rng = np.random.default_rng(2)
    base = rng.uniform(0.3, 0.9, 40)  # cases differ a lot; the shift is small but steady
    a = _cases(base + 0.02 + rng.normal(0, 0.005, 40), seeds=3)
    b = _cases(base, seeds=3)
    diff = paired_difference([a], [b], over_seeds=False)
    assert diff.significant and diff.interval.low > 0 and diff.n_cases == 40
    assert diff.estimate == pytest.approx(0.02, abs=0.003)
    reverse = paired_difference([b], [a], over_seeds=False)
    assert reverse.significant and reverse.interval.high < 0
    # unpaired, the case spread swamps the shift: the two intervals overlap
    ia, ib = (bootstrap_interval([x], over_seeds=False) for x in (a, b))
    assert ia.low < ib.high


def test_paired_difference_with_no_shift_includes_zero():
    rng = np.random.default_rng(4)
    base = rng.uniform(0.3, 0.9, 40)
    a = _cases(base + rng.normal(0, 0.02, 40))
    b = _cases(base + rng.normal(0, 0.02, 40))
    diff = paired_difference([a], [b], over_seeds=False)
    assert not diff.significant and diff.interval.low < 0 < diff.interval.high
    same = paired_difference([a], [a], over_seeds=True)
    assert same.interval == Interval(0.0, 0.0) and not same.significant


def test_pairs_only_common_cases_and_seeds():
    a = {"x": {"0": 0.5, "1": 0.7}, "y": {"0": 0.2}}
    b = {"x": {"1": 0.6, "2": 0.1}, "z": {"0": 0.9}}
    assert paired_units(a, b) == {"x": {"1": pytest.approx(0.1)}}
    assert paired_difference([{"y": {"0": 0.2}}], [{"z": {"0": 0.1}}], over_seeds=False) is None


def test_varies_over_seeds():
    assert not varies_over_seeds([{"0": 0.5, "1": 0.5}, {"0": 0.1}])
    assert varies_over_seeds([{"0": 0.5, "1": 0.5}, {"0": 0.1, "1": 0.2}])
