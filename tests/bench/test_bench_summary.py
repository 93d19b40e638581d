"""Aggregation rules of the table, on hand-made records with hand-computed answers."""

from __future__ import annotations

import math

import pytest
from record_helpers import error_record, ok_record

from packlab.bench.summary import summarize
from packlab.bench.table import format_cell, render_markdown


def _rec(case, difficulty, seed, overall, sr=1.0, policy="p", status="ok"):
    if status == "ok":
        return ok_record(case, seed, policy, difficulty, overall, sr)
    return error_record(case, seed, policy, difficulty)


def test_per_seed_means_then_mean_and_sample_std_over_seeds():
    recs = [
        _rec("e1", "easy", 0, 0.2),
        _rec("e2", "easy", 0, 0.4),  # easy seed 0 -> 0.3
        _rec("e1", "easy", 1, 0.6),
        _rec("e2", "easy", 1, 0.4),  # easy seed 1 -> 0.5
        _rec("h1", "hard", 0, 0.1),
        _rec("h1", "hard", 1, 0.3),  # hard -> 0.1, 0.3
    ]
    s = summarize(recs, ["p"], [0, 1], ["easy", "hard"])
    easy = s.table["p"]["easy"].overall
    assert easy.per_seed == pytest.approx({"0": 0.3, "1": 0.5})
    assert easy.mean == pytest.approx(0.4) and easy.std == pytest.approx(math.sqrt(0.02))
    avg = s.table["p"]["average"].overall  # mean of difficulties per seed: 0.2, 0.4
    assert avg.per_seed == pytest.approx({"0": 0.2, "1": 0.4}) and avg.mean == pytest.approx(0.3)
    assert s.per_case["p"]["e1"].overall.mean == pytest.approx(0.4)
    assert format_cell(easy) == "0.400 ± 0.141"


def test_failed_episodes_are_counted_not_averaged_and_flagged():
    recs = [_rec("e1", "easy", 0, 0.5), _rec("e2", "easy", 0, 0.0, status="error")]
    s = summarize(recs, ["p"], [0], ["easy"])
    assert s.table["p"]["easy"].overall.mean == pytest.approx(0.5)
    assert s.counts["p"].errors == 1 and s.counts["p"].episodes == 1
    assert s.errors[0].case_id == "e2"
    md = render_markdown(s)
    assert "| p * |" in md and "1 episode(s) failed" in md


def test_order_of_records_does_not_matter():
    recs = [
        _rec(f"c{i}", "easy", s, (i * 7 % 10) / 10 + 0.01 * s) for i in range(9) for s in range(3)
    ]
    a = summarize(recs, ["p"], [0, 1, 2], ["easy"])
    b = summarize(list(reversed(recs)), ["p"], [0, 1, 2], ["easy"])
    assert a == b


def test_a_method_without_records_shows_dashes():
    s = summarize([_rec("e1", "easy", 0, 0.5)], ["p", "q"], [0], ["easy"])
    assert s.table["q"]["easy"].overall.mean is None
    assert "| q | - | - | - |" in render_markdown(s)
