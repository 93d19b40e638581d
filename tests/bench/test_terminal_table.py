"""The table a bench command prints: 120 columns at most for the default 11 methods (long names
and all), rows by Average Overall best first (the oracle last), ``--wide`` the whole table.md."""

from __future__ import annotations

import argparse
import re

import pytest
from bench_helpers import write_tiny_suite
from record_helpers import error_record, ok_record
from report_helpers import small_run

from packlab.bench.config import default_policies
from packlab.bench.report import TABLE_FILE
from packlab.bench.summary import run_intervals, summarize
from packlab.bench.table import render_markdown
from packlab.bench.terminal import WIDTH, compact_table, ranked_policies, terminal_text
from packlab.cli import bench_run
from packlab.viz.labels import display_name

LEVELS = ("easy", "medium", "hard")


def _default_summary(n_cases: int = 6, failing: str | None = None):
    """The default 11 methods on 3 levels x 3 seeds; each method's score set by its index so
    the ranking is known (index 0, DBLF, is the worst; the oracle scores 1)."""
    policies = default_policies()
    records = []
    for k, p in enumerate(policies):
        for i in range(n_cases):
            level = LEVELS[i % 3]
            for seed in range(3):
                if p == failing and i == 0 and seed == 0:
                    records.append(error_record(f"c{i}", seed, p, level))
                    continue
                score = 1.0 if p == "oracle" else 0.05 + 0.08 * k + 0.01 * (i % 4) + 0.002 * seed
                records.append(ok_record(f"c{i}", seed, p, level, score))
    return summarize(records, list(policies), [0, 1, 2], list(LEVELS))


def _table_rows(text: str) -> list[list[str]]:
    lines = [line for line in text.splitlines() if line.startswith("| ")]
    return [[c.strip() for c in line.strip("|").split("|")] for line in lines]


def test_the_default_printed_table_fits_120_columns():
    summary = _default_summary()
    assert "Plan (completion + lookahead, fast)" in {display_name(p) for p in summary.policies}
    full = render_markdown(summary)
    text = terminal_text(summary, table_file="runs/bench-packlab-bench-v1/table.md")
    assert max(len(line) for line in full.splitlines()) > 300  # what it replaces
    assert max(len(line) for line in text.splitlines()) <= WIDTH
    header = _table_rows(text)[0]
    assert header == ["Method", "Easy", "Medium", "Hard", "Average Overall", "sd over seeds"]
    assert "(--wide prints it)" in text and "runs/bench-packlab-bench-v1/table.md" in text


def test_rows_best_first_oracle_last_with_the_interval_of_the_average():
    summary = _default_summary()
    intervals = run_intervals(summary)
    rows = _table_rows(compact_table(summary, intervals))[2:]  # header and alignment row off
    names = [r[0] for r in rows]
    assert names[-1] == "Oracle (gt plan)"
    averages = [float(r[4].split()[0]) for r in rows[:-1]]
    assert averages == sorted(averages, reverse=True)
    # Scores rise with the registry index: Random (index 9) first, then TAP-Net, ... DBLF.
    assert ranked_policies(summary) == [*reversed(summary.policies[:-1]), "oracle"]
    lo, hi = intervals.bounds("random", "average", "overall")
    mean = summary.table["random"]["average"].overall.mean
    assert rows[0][:1] == ["Random"] and rows[0][4] == f"{mean:.3f} [{lo:.3f}, {hi:.3f}]"
    assert all(re.fullmatch(r"\d\.\d{3}", c) for r in rows for c in r[1:4])  # means only


def test_long_names_are_shortened_only_when_a_line_would_not_fit():
    summary = _default_summary()
    long = "runs-with-a-very-long-directory-name-for-an-ablation: " + "x" * 60
    renamed = summary.__class__(
        **{
            **{f: getattr(summary, f) for f in summary.__struct_fields__},
            "policies": (*summary.policies[:-1], long),
            "table": {**summary.table, long: summary.table["oracle"]},
            "counts": {**summary.counts, long: summary.counts["oracle"]},
        }
    )
    text = compact_table(renamed)
    assert max(len(line) for line in text.splitlines()) <= WIDTH
    assert "…" in text and "Plan (completion + lookahead, fast)" in text


def test_failures_are_flagged_and_explained_within_the_width():
    text = terminal_text(_default_summary(failing="hm"))
    assert "| HM * " in text and "episode(s) failed" in text
    assert max(len(line) for line in text.splitlines()) <= WIDTH


@pytest.mark.parametrize("wide", [False, True])
def test_bench_report_prints_the_compact_table_or_with_wide_the_whole(tmp_path, capsys, wide):
    cases = write_tiny_suite(tmp_path)
    small_run(cases, tmp_path / "run", policies=("dblf", "hm"))
    args = argparse.Namespace(
        dir=str(tmp_path / "run"), no_figures=True, case=None, seed=None, html=False, wide=wide
    )
    assert bench_run.run_report(args) == 0
    out = capsys.readouterr().out
    table_md = (tmp_path / "run" / TABLE_FILE).read_text(encoding="utf-8")
    if wide:
        assert out == table_md + "\n"
    else:
        assert max(len(line) for line in out.splitlines()) <= WIDTH
        assert "Average Overall" in out and "Run details" not in out


def test_wide_is_a_flag_of_bench_report_and_compare():
    from packlab.cli.main import build_parser

    parser = build_parser()
    assert parser.parse_args(["bench", "--wide"]).wide
    assert parser.parse_args(["bench", "report", "d", "--wide"]).wide
    assert parser.parse_args(["bench", "compare", "a", "b", "--wide"]).wide
    assert not parser.parse_args(["bench", "report", "d"]).wide
