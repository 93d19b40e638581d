"""episodes.jsonl: torn last lines are tolerated and repaired, damage elsewhere is an error."""

from __future__ import annotations

import json

import pytest

from packlab.bench.records import RecordsError, RecordWriter, read_record_file, read_records


def _rec(case, seed=0, policy="dblf", **extra):
    return {"status": "ok", "case_id": case, "seed": seed, "policy": policy, "backend": "geometric", **extra}


def test_torn_last_line_is_skipped_and_cut_before_appending(tmp_path):
    path = tmp_path / "episodes.jsonl"
    with RecordWriter(path) as w:
        w.write(_rec("a"))
        w.write(_rec("b"))
    with open(path, "a") as fh:
        fh.write('{"status":"ok","case_id":"c","se')  # a kill mid-write
    state = read_record_file(path)
    assert [r["case_id"] for r in state.records] == ["a", "b"] and state.torn_tail
    with RecordWriter(path) as w:
        w.write(_rec("c"))
    lines = path.read_text().splitlines()
    assert [json.loads(line)["case_id"] for line in lines] == ["a", "b", "c"]


def test_a_complete_but_unparsable_last_line_counts_as_torn(tmp_path):
    path = tmp_path / "episodes.jsonl"
    path.write_text(json.dumps(_rec("a")) + "\n" + '{"status":"ok","case_id":\n')
    assert [r["case_id"] for r in read_records(path)] == ["a"]


def test_damage_before_the_end_is_an_error_naming_the_line(tmp_path):
    path = tmp_path / "episodes.jsonl"
    path.write_text(json.dumps(_rec("a")) + "\nnot json\n" + json.dumps(_rec("b")) + "\n")
    with pytest.raises(RecordsError, match=r"episodes.jsonl:2"):
        read_records(path)


def test_later_record_of_a_key_wins(tmp_path):
    path = tmp_path / "episodes.jsonl"
    with RecordWriter(path) as w:
        w.write({**_rec("a"), "status": "error"})
        w.write(_rec("a", note="retry"))
        w.write(_rec("a", seed=1))
    recs = read_records(path)
    assert len(recs) == 2
    assert next(r for r in recs if r["seed"] == 0)["note"] == "retry"


def test_missing_file_holds_nothing(tmp_path):
    assert read_records(tmp_path / "none.jsonl") == []
