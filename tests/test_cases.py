"""Case files: round trip, reference parquet rows and clear errors for malformed input."""

import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from layered_cases import make_layered_case

from packlab.cases import case_to_dict, load_cases, save_cases
from packlab.errors import CaseFormatError


def _record(**overrides):
    record = {
        "episode_id": "c0",
        "container_size_cm": [50, 40, 30],
        "buffer_size": 2,
        "object_sequence": [
            {"internal_id": 0, "gt_index": 0, "type_id": 1, "size_cm": [25, 40, 10]},
            {"internal_id": 1, "gt_index": 1, "type_id": 2, "size_cm": [25, 40, 10.4]},
        ],
    }
    record.update(overrides)
    return record


def test_round_trip_jsonl(tmp_path):
    cases = [make_layered_case(s, episode_id=f"case-{s}") for s in range(4)]
    path = save_cases(cases, tmp_path / "suite.jsonl")
    assert load_cases(path) == cases


def test_single_json_case_in_cm(tmp_path):
    path = tmp_path / "one.json"
    path.write_text(json.dumps(_record()))
    (case,) = load_cases(path)
    assert case.container.size_mm == (500, 400, 300)
    assert case.objects[1].size_mm == (250, 400, 104)
    assert case.container.cells == (20, 16)
    assert case_to_dict(case)["object_sequence"][1]["size_cm"] == [25, 40, 10.4]


def test_reference_parquet_rows(tmp_path):
    rows = [{"extra_info": {"interaction_kwargs": _record(episode_id=f"p{i}")}} for i in range(2)]
    # The reference stores the case as a JSON string inside a struct; accept both encodings.
    rows[1]["extra_info"]["interaction_kwargs"] = json.dumps(rows[1]["extra_info"]["interaction_kwargs"])
    table = pa.table({"extra_info": [json.dumps(r["extra_info"]) for r in rows]})
    pq.write_table(table, tmp_path / "bench.parquet")
    cases = load_cases(tmp_path / "bench.parquet")
    assert [c.episode_id for c in cases] == ["p0", "p1"]


@pytest.mark.parametrize(
    "mutate, field, value_text",
    [
        (lambda r: r.pop("buffer_size"), "buffer_size", "None"),
        (lambda r: r.update(buffer_size=0), "buffer_size", "0"),
        (lambda r: r["object_sequence"][1].update(size_cm=[-25, 40, 10]), "object_sequence[1].size_cm[0]", "-25"),
        (lambda r: r["object_sequence"][0].update(size_cm=[26, 40, 10]), "object_sequence[0].size_cm[0]", "26"),
        (lambda r: r["object_sequence"][0].update(size_cm=[25, 40, 35]), "object_sequence[0].size_cm", "35"),
        (lambda r: r["object_sequence"][0].update(size_cm=[75, 45, 10]), "object_sequence[0].size_cm", "75"),
        (lambda r: r["object_sequence"][0].pop("size_cm"), "object_sequence[0].size_cm", "None"),
    ],
)
def test_malformed_case_names_file_line_field_value(tmp_path, mutate, field, value_text):
    record = _record()
    mutate(record)
    path = tmp_path / "bad.jsonl"
    path.write_text(json.dumps(_record(episode_id="ok")) + "\n" + json.dumps(record) + "\n")
    with pytest.raises(CaseFormatError) as info:
        load_cases(path)
    message = str(info.value)
    assert f"{path}:2" in message and f"'{field}'" in message and value_text in message


def test_bad_json_line_is_reported_with_its_line(tmp_path):
    path = tmp_path / "broken.jsonl"
    path.write_text(json.dumps(_record()) + "\n{not json\n")
    with pytest.raises(CaseFormatError, match=r"broken.jsonl:2: .*bad JSON line"):
        load_cases(path)


def test_duplicate_episode_ids_are_rejected(tmp_path):
    path = tmp_path / "dup.jsonl"
    path.write_text(json.dumps(_record()) + "\n" + json.dumps(_record()) + "\n")
    with pytest.raises(CaseFormatError, match="not unique"):
        load_cases(path)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.jsonl"):
        load_cases(tmp_path / "nope.jsonl")


def test_save_is_atomic_and_keeps_the_old_file_on_failure(tmp_path):
    path = save_cases([make_layered_case(0)], tmp_path / "suite.jsonl")
    before = path.read_text()

    def bad_cases():
        yield make_layered_case(1)
        raise RuntimeError("generator died")

    with pytest.raises(RuntimeError):
        save_cases(bad_cases(), path)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["suite.jsonl"]
