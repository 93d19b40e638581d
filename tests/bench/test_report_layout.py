"""report.html's structure without a browser: one calm headline instead of a list that repeats
the table, notes kept for warnings, the replay opening on the best method against the best
heuristic, and the page's slots for the results layout (the browser checks are in
test_report_browser.py)."""

from __future__ import annotations

import re

from record_helpers import ok_record
from report_helpers import small_run

from packlab.bench.html_report import headline_text, replay_pair, run_html
from packlab.bench.report import load_run
from packlab.bench.summary import run_intervals, summarize
from packlab.viz.report_html import embedded_data


def _summary(scores: dict[str, float]):
    records = [
        ok_record(f"c{i}", 0, p, level, v + 0.01 * i)
        for p, v in scores.items()
        for i, level in enumerate(("easy", "easy", "hard", "hard"))
    ]
    return summarize(records, list(scores), [0], ["easy", "hard"])


def test_headline_names_the_best_method_and_its_interval_the_oracle_aside():
    summary = _summary({"dblf": 0.5, "plan-fast": 0.9, "oracle": 1.0})
    intervals = run_intervals(summary)
    mean = summary.table["plan-fast"]["average"].overall.mean
    lo, hi = intervals.bounds("plan-fast", "average", "overall")
    text = headline_text(summary, intervals)
    assert text == (
        f"Best: Plan (completion + lookahead, fast), Average Overall {mean:.3f} "
        f"[{lo:.3f}, {hi:.3f}]."
    )
    assert "\n" not in text and "Oracle" not in text


def test_replay_opens_on_the_best_method_against_the_best_heuristic():
    policies = ["dblf", "hm", "sdf", "plan-fast", "vlm", "random"]
    # ranked best first (indices into policies): plan-fast, vlm, sdf, dblf, hm, random
    assert replay_pair([3, 4, 2, 0, 1, 5], policies) == [3, 2]  # the planner vs SDF-Pack
    assert replay_pair([2, 0, 3], policies) == [2, 0]  # best is a heuristic: the next heuristic
    assert replay_pair([3, 4], policies) == [3, 4]  # no heuristic: the next best
    assert replay_pair([3], policies) == [3, 3]
    assert replay_pair([], policies) == [0, 1]


def test_a_run_page_has_a_headline_calm_notes_and_the_replay_pair(tiny_suite, tmp_path):
    small_run(tiny_suite, tmp_path / "run", policies=("random", "hm", "dblf"), seeds=(0,))
    run = load_run(tmp_path / "run")
    html = run_html(run.config, run.records, run.cases, generated="2026-01-01 00:00:00 UTC")
    data = embedded_data(html)
    assert data["headline"].startswith("Best: ")
    assert data["notes"] == []  # nothing needs the reader's attention: no list at all
    assert data["differences"] == []
    best = data["headline"].removeprefix("Best: ").split(",")[0]
    names = [m["name"] for m in data["methods"]]
    left, right = data["replay"]
    assert names[left] == best and data["methods"][right]["policy"] in {"hm", "dblf"}
    assert right != left
    # The page's slots: the headline line, the notes list, the interval toggle, the table.
    for slot in ('id="headline"', 'id="notes"', 'id="t-intervals"', 'id="results-table"'):
        assert slot in html
    assert re.search(r'id="differences"', html)
