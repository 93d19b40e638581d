"""episodes.jsonl: torn last lines are tolerated and repaired, damage elsewhere is an error;
versions and types of a run directory's records are checked (older ones migrate)."""

from __future__ import annotations

import json

import pytest
from record_helpers import error_record, ok_record
from report_helpers import as_run1

from packlab.bench.compare import compare_markdown
from packlab.bench.config import RunConfig
from packlab.bench.records import RecordsError, RecordWriter, dumps, read_record_file, read_records
from packlab.bench.report import build_report
from packlab.bench.runner import run_bench
from packlab.bench.table import results_table
from packlab.cli.main import main
from packlab.core.errors import EXIT_USAGE, ConfigError, RecordFormatError
from packlab.core.records import RUN_FORMAT, RUN_FORMAT_1, SUMMARY_FORMAT


def _rec(case, seed=0, policy="dblf", **extra):
    return ok_record(case, seed, policy, **extra)


def test_torn_last_line_is_skipped_and_cut_before_appending(tmp_path):
    path = tmp_path / "episodes.jsonl"
    with RecordWriter(path) as w:
        w.write(_rec("a"))
        w.write(_rec("b"))
    with open(path, "a") as fh:
        fh.write('{"status":"ok","case_id":"c","se')  # a kill mid-write
    state = read_record_file(path)
    assert [r.case_id for r in state.records] == ["a", "b"] and state.torn_tail
    with RecordWriter(path) as w:
        w.write(_rec("c"))
    lines = path.read_text().splitlines()
    assert [json.loads(line)["case_id"] for line in lines] == ["a", "b", "c"]


def test_a_complete_but_unparsable_last_line_counts_as_torn(tmp_path):
    path = tmp_path / "episodes.jsonl"
    path.write_text(dumps(_rec("a")) + "\n" + '{"status":"ok","case_id":\n')
    assert [r.case_id for r in read_records(path)] == ["a"]


def test_damage_before_the_end_is_an_error_naming_the_line(tmp_path):
    path = tmp_path / "episodes.jsonl"
    path.write_text(dumps(_rec("a")) + "\nnot json\n" + dumps(_rec("b")) + "\n")
    with pytest.raises(RecordsError, match=r"episodes.jsonl:2"):
        read_records(path)


def test_later_record_of_a_key_wins(tmp_path):
    path = tmp_path / "episodes.jsonl"
    with RecordWriter(path) as w:
        w.write(error_record("a", policy="dblf"))
        w.write(_rec("a", overall=0.25))
        w.write(_rec("a", seed=1))
    recs = read_records(path)
    assert len(recs) == 2
    assert next(r for r in recs if r.seed == 0).metrics.overall == 0.25


def test_missing_file_holds_nothing(tmp_path):
    assert read_records(tmp_path / "none.jsonl") == []


# -- versions and types of a whole run directory ---------------------------------------------------


def _run(tiny_suite, out):
    cfg = RunConfig(
        cases=str(tiny_suite),
        out=str(out),
        backend="geometric",
        policies=("dblf", "random"),
        seeds=(0, 1),
        workers=1,
        progress=False,
    )
    return run_bench(cfg, figures=False)


def test_a_run1_directory_still_reports_the_same_numbers(tiny_suite, tmp_path):
    live = _run(tiny_suite, tmp_path / "run")
    as_run1(tmp_path / "run")
    summary, _, _ = build_report(tmp_path / "run", figures=False)
    assert summary.table == live.summary.table and summary.per_case == live.summary.per_case
    assert results_table(summary) == results_table(live.summary)
    # ... but it is not resumed: its heuristic episodes were played under run-1's rules.
    with pytest.raises(ConfigError, match=f"'format' = '{RUN_FORMAT_1}' here, '{RUN_FORMAT}' now"):
        _run(tiny_suite, tmp_path / "run")


def test_a_newer_record_format_is_a_one_line_error_naming_file_line_and_value(
    tiny_suite, tmp_path, capsys
):
    _run(tiny_suite, tmp_path / "run")
    path = tmp_path / "run" / "episodes.jsonl"
    lines = path.read_text().splitlines()
    lines[2] = lines[2].replace(f'"format":"{RUN_FORMAT}"', '"format":"packlab-bench-run-3"')
    path.write_text("\n".join(lines) + "\n")
    assert main(["bench", "report", str(tmp_path / "run"), "--no-figures"]) == EXIT_USAGE
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "episodes.jsonl:3: field 'format' = 'packlab-bench-run-3': unknown format version" in err
    # The runner refuses to append to it as well (nothing run, nothing written).
    with pytest.raises(RecordFormatError, match="episodes.jsonl:3"):
        _run(tiny_suite, tmp_path / "run")


def test_a_wrong_typed_field_anywhere_is_an_error_even_on_the_last_line(tmp_path):
    path = tmp_path / "episodes.jsonl"
    bad = json.loads(dumps(_rec("b")))
    bad["steps"][0]["valid"] = "yes"
    path.write_text(dumps(_rec("a")) + "\n" + json.dumps(bad, separators=(",", ":")) + "\n")
    with pytest.raises(RecordFormatError) as err:
        read_records(path)
    assert str(err.value) == f"{path}:2: field 'steps[0].valid' = 'yes': Expected `bool`, got `str`"


def test_a_summary_of_a_newer_version_is_refused_by_compare(tiny_suite, tmp_path):
    _run(tiny_suite, tmp_path / "run")
    path = tmp_path / "run" / "summary.json"
    summary = json.loads(path.read_text())
    assert summary["format"] == SUMMARY_FORMAT and next(iter(summary)) == "format"
    path.write_text(json.dumps({**summary, "format": "packlab-bench-summary-2"}))
    message = "summary.json: field 'format' = 'packlab-bench-summary-2'"
    with pytest.raises(RecordFormatError, match=message):
        compare_markdown([tmp_path / "run"])
