"""Per-decision time in records, the summary and table.md, on hand-made records with
hand-computed answers, and from a real run rebuilt by ``packlab bench report``."""

from __future__ import annotations

import json

import msgspec
from bench_helpers import run_tiny
from record_helpers import ok_record, step

from packlab.bench.decision_times import ALL_LEVELS, decision_times
from packlab.bench.report import build_report
from packlab.bench.summary import summarize
from packlab.bench.table import render_markdown
from packlab.core.records import summary_from_json


def _timed(case, seed, difficulty, walls, cpus=None, policy="p"):
    cpus = cpus or [w / 2 for w in walls]
    steps = tuple(
        msgspec.structs.replace(step(i), decision_s=w, decision_cpu_s=c)
        for i, (w, c) in enumerate(zip(walls, cpus))
    )
    return msgspec.structs.replace(ok_record(case, seed, policy, difficulty), steps=steps)


def test_mean_p95_max_per_level_and_where_the_slowest_was():
    easy = [_timed("e1", 0, "easy", [0.010, 0.020]), _timed("e2", 0, "easy", [0.030])]
    # 20 hard decisions: 0.001 .. 0.019 s, and one of 2 s at step 7 of h2 seed 1.
    walls = [0.001 * (i + 1) for i in range(19)]
    hard = [_timed("h1", 0, "hard", walls[:12]), _timed("h2", 1, "hard", walls[12:] + [2.0])]
    hard[1] = msgspec.structs.replace(
        hard[1],
        steps=hard[1].steps[:7]
        + (msgspec.structs.replace(hard[1].steps[7], step=7),)
        + hard[1].steps[8:],
    )
    times = decision_times(easy + hard, ["easy", "hard"])
    assert times["easy"].decisions == 3
    assert times["easy"].mean_ms == 20.0 and times["easy"].max_ms == 30.0
    assert times["easy"].p95_ms == 29.0  # linear: 20 + 0.9 * (30 - 20)
    assert times["hard"].decisions == 20 and times["hard"].max_ms == 2000.0
    hard_walls = sorted(walls + [2.0])
    assert times["hard"].p95_ms == round(1000 * (hard_walls[18] + 0.05 * (2.0 - hard_walls[18])), 3)
    assert (times["hard"].worst_case_id, times["hard"].worst_seed) == ("h2", 1)
    assert times["hard"].worst_step == 7
    assert times[ALL_LEVELS].decisions == 23
    assert times[ALL_LEVELS].cpu_max_ms == 1000.0  # the cpu given is half the wall time
    assert times[ALL_LEVELS].worst_case_id == "h2"


def test_records_without_decision_times_give_none_and_the_table_has_no_section():
    recs = [ok_record("e1", 0, "p", "easy")]
    assert decision_times(recs, ["easy"]) is None
    summary = summarize(recs)
    assert summary.counts["p"].decision_times is msgspec.UNSET
    assert "Decision time" not in render_markdown(summary)


def test_summary_json_round_trips_and_table_md_shows_the_tail():
    recs = [_timed("e1", 0, "easy", [0.001, 0.5]), _timed("h1", 0, "hard", [0.002, 0.003])]
    summary = summarize(recs)
    again = summary_from_json(msgspec.json.encode(summary).decode(), "summary.json")
    assert again.counts["p"].decision_times == summary.counts["p"].decision_times
    table = render_markdown(summary)
    assert "### Decision time" in table
    section = table.split("### Decision time", 1)[1]
    row = next(line for line in section.splitlines() if line.startswith("| p |"))
    assert "250.5 / 475.1 / 500.0" in row  # easy: mean / p95 (1 + 0.95 * 499) / max
    assert "500.0 ms: e1 seed 0 step 1" in row


def test_a_real_run_records_each_decision_and_the_report_rebuilds_the_table(tiny_suite, tmp_path):
    out = tmp_path / "run"
    outcome = run_tiny(tiny_suite, out)
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    for r in records:
        assert all(s["decision_s"] >= 0 and s["decision_cpu_s"] >= 0 for s in r["steps"])
        assert abs(sum(s["decision_s"] for s in r["steps"]) - r["policy_time_s"]) < 1e-4
    assert "### Decision time" in outcome.table_md
    (out / "table.md").unlink()
    _, table_md, _ = build_report(out, figures=False)
    assert "### Decision time" in table_md
    assert (out / "table.md").read_text().count("### Decision time") == 1
