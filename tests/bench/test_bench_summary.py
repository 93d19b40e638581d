"""Aggregation rules of the table, on hand-made records with hand-computed answers."""

from __future__ import annotations

import json
import math

import pytest
from record_helpers import error_record, ok_record

from packlab.bench.intervals import bootstrap_interval
from packlab.bench.report import summary_json
from packlab.bench.summary import (
    RESAMPLED_CASES,
    RESAMPLED_CASES_SEEDS,
    RunIntervals,
    run_intervals,
    summarize,
)
from packlab.bench.table import SPREAD_COLUMN, format_cell, format_spread, render_markdown
from packlab.core.records import summary_from_json


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
    assert format_cell(easy) == "0.400"  # no interval given: the mean alone
    assert format_cell(easy, bounds=(0.25, 0.5)) == "0.400 [0.250, 0.500]"
    assert format_spread(easy) == "0.141"


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


def _deterministic_and_noisy(n_cases=12):
    """Policy "det" scores the same on every seed; "noisy" differs across seeds."""
    recs = []
    for i in range(n_cases):
        level = "easy" if i % 2 else "hard"
        for s in range(3):
            recs.append(_rec(f"c{i}", level, s, 0.3 + 0.05 * (i % 5), policy="det"))
            recs.append(_rec(f"c{i}", level, s, 0.2 + 0.1 * ((i + s) % 3), policy="noisy"))
    return summarize(recs, ["det", "noisy"], [0, 1, 2], ["easy", "hard"])


def test_intervals_per_level_and_average_hold_the_means():
    s = _deterministic_and_noisy()
    found = run_intervals(s)
    assert found.policies["det"].resampled == RESAMPLED_CASES
    assert found.policies["noisy"].resampled == RESAMPLED_CASES_SEEDS
    for p in ("det", "noisy"):
        for g in ("easy", "hard", "average"):
            low, high = found.bounds(p, g, "overall")
            assert low < s.table[p][g].overall.mean < high
    # the level's interval is the bootstrap of that level's per-case scores, nothing else
    easy = {c: cells.overall.per_seed for c, cells in s.per_case["det"].items()}
    easy = {c: v for c, v in easy.items() if s.per_case["det"][c].difficulty == "easy"}
    direct = bootstrap_interval([easy], over_seeds=False)
    assert found.bounds("det", "easy", "overall") == (direct.low, direct.high)
    assert run_intervals(s) == found  # fixed generator seed: same records, same intervals


def test_table_shows_intervals_and_a_labelled_seed_spread():
    s = _deterministic_and_noisy()
    found = run_intervals(s)
    md = render_markdown(s)
    low, high = found.bounds("det", "average", "overall")
    mean = s.table["det"]["average"].overall.mean
    row = next(line for line in md.splitlines() if line.startswith("| det |"))
    assert row.endswith(f"| {mean:.3f} [{low:.3f}, {high:.3f}] | 0.000 |")
    assert f"Average {SPREAD_COLUMN}" in md and "±" not in md
    assert "| noisy |" in md and "for noisy (scores vary across seeds) seeds also resampled" in md
    assert "95 % bootstrap interval" in md and "2000 resamples" in md


def test_summary_json_adds_intervals_and_old_readers_still_read_it():
    s = _deterministic_and_noisy()
    text = summary_json(s)
    obj = json.loads(text)
    assert obj["table"]["det"]["easy"]["overall"]["std"] == 0.0  # old keys kept
    assert obj["intervals"]["resamples"] == 2000 and obj["intervals"]["confidence"] == 0.95
    back = summary_from_json(text, "summary.json")  # the typed reader ignores the added key
    assert back == s
    stored = obj["intervals"]["policies"]["noisy"]["cells"]["average"]["overall"]
    assert tuple(stored) == run_intervals(back).bounds("noisy", "average", "overall")
    assert isinstance(run_intervals(back), RunIntervals)
