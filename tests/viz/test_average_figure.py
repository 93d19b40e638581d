"""``overall_average.png``: bars of mean Overall with the bootstrap interval as error bars."""

from __future__ import annotations

import json

import numpy as np
import pytest
from matplotlib.container import ErrorbarContainer
from msgspec import to_builtins
from record_helpers import ok_record

from packlab.bench.summary import run_intervals, summarize
from packlab.viz.plots import average_overall_figure, overall_bounds, save_figure


@pytest.fixture(scope="module")
def summary():
    rng = np.random.default_rng(3)
    recs = []
    for i in range(12):
        level = "easy" if i % 2 else "hard"
        base = float(rng.uniform(0.3, 0.9))
        for seed in range(3):
            recs.append(ok_record(f"c{i}", seed, "steady", level, base))
            # seed spread of +-0.2 on every case: the old error bars were that spread
            recs.append(ok_record(f"c{i}", seed, "noisy", level, base - 0.2 + 0.2 * seed))
    return summarize(recs, ["steady", "noisy"], [0, 1, 2], ["easy", "hard"])


def _error_segments(fig):
    """Every drawn error bar as (x, low, high), sorted by x."""
    ax = fig.axes[0]
    out = []
    for container in ax.containers:
        if isinstance(container, ErrorbarContainer):
            for segment in container.lines[2][0].get_segments():
                (x0, y0), (_, y1) = segment
                out.append((float(x0), float(min(y0, y1)), float(max(y0, y1))))
    return sorted(out)


def test_error_bars_are_the_bootstrap_intervals_not_the_seed_spread(summary, tmp_path):
    intervals = run_intervals(summary)
    fig = average_overall_figure(summary, intervals)
    segments = _error_segments(fig)
    assert len(segments) == 2 * 3  # two methods x (easy, hard, average)
    wanted = sorted(
        (b[0], b[1])
        for p in summary.policies
        for g in ("easy", "hard", "average")
        if (b := intervals.bounds(p, g, "overall")) is not None
    )
    drawn = sorted((low, high) for _, low, high in segments)
    assert np.allclose(drawn, wanted)
    noisy = summary.table["noisy"]["average"].overall
    assert noisy.std == pytest.approx(0.2)  # not what is drawn
    assert not any(
        (low, high) == pytest.approx((noisy.mean - noisy.std, noisy.mean + noisy.std))
        for _, low, high in segments
    )
    assert "95 % bootstrap interval over cases" in fig.axes[0].get_title()
    assert save_figure(fig, tmp_path / "overall_average.png").stat().st_size > 5000


def test_summary_json_intervals_draw_the_same_bars(summary):
    intervals = run_intervals(summary)
    as_json = json.loads(json.dumps(to_builtins(intervals)))  # summary.json's "intervals" key
    assert np.allclose(
        _error_segments(average_overall_figure(summary, as_json)),
        _error_segments(average_overall_figure(summary, intervals)),
    )
    del as_json["policies"]["noisy"]
    assert len(_error_segments(average_overall_figure(summary, as_json))) == 3  # steady's only


def test_without_intervals_there_is_no_error_bar(summary):
    fig = average_overall_figure(summary)
    assert _error_segments(fig) == []
    assert "no interval" in fig.axes[0].get_title()


def test_overall_bounds_ignores_missing_and_malformed_entries():
    cells = {"policies": {"p": {"cells": {"average": {"overall": [0.2, 0.4]}}}}}
    assert overall_bounds(cells, "p", "average") == (0.2, 0.4)
    assert overall_bounds(cells, "p", "easy") is None
    assert overall_bounds(cells, "q", "average") is None
    assert overall_bounds(None, "p", "average") is None
    cells["policies"]["p"]["cells"]["average"]["overall"] = [0.5, 0.4]  # low > high
    assert overall_bounds(cells, "p", "average") is None
    cells["policies"]["p"]["cells"]["average"]["overall"] = None
    assert overall_bounds(cells, "p", "average") is None
