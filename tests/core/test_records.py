"""Typed, versioned records (packlab.core.records): round trips, version checks, migrations and
errors that name file, line, field and value. Pure: no engine, no files beyond strings."""

from __future__ import annotations

import json

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st
from record_helpers import error_record, ok_record

from packlab.core.errors import PacklabError, RecordFormatError
from packlab.core.records import (
    PACKDATA_FORMAT,
    RUN_FORMAT,
    RUN_FORMAT_1,
    SUMMARY_FORMAT,
    ActionRecord,
    EpisodeError,
    EpisodeOk,
    NotJSON,
    dataset_info_from_json,
    decode_episode,
    dumps_line,
    run_config_from_json,
    summary_from_json,
    to_builtins,
)
from packlab.core.types import Action, Unparsable

SRC = "run/episodes.jsonl"


def _line(obj: dict) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode()


def _run1_ok_line() -> dict:
    """An ok record as packlab-bench-run-1 wrote it: no format, steps say ``capped``, metrics
    ``capped_placements``, no rest fields."""
    rec = to_builtins(ok_record("hard-1", 2, "dblf", "hard", overall=0.25, sr=0.5))
    del rec["format"]
    for key in (
        "unsettled_steps",
        "final_settle_steps",
        "at_rest",
        "residual_linear_mps",
        "residual_angular_radps",
    ):
        del rec["metrics"][key]
    rec["metrics"]["capped_placements"] = 3
    for step in rec["steps"]:
        for key in ("settled", "max_linear_speed_mps", "max_angular_speed_radps"):
            del step[key]
        step["capped"] = True
    return rec


# -- round trips ----------------------------------------------------------------------------------


@pytest.mark.parametrize("record", [ok_record(), error_record(kind="timeout")], ids=["ok", "error"])
def test_an_episode_record_round_trips_and_carries_its_version(record):
    line = dumps_line(record)
    obj = json.loads(line)
    assert list(obj)[:2] == ["status", "format"] and obj["format"] == RUN_FORMAT
    assert decode_episode(line.encode(), SRC, 1) == record
    assert type(decode_episode(line.encode(), SRC, 1)) is type(record)


def test_the_written_line_is_what_the_standard_json_module_writes():
    """Bytes stay as before the types: ``json.dumps`` of the record's plain form."""
    record = ok_record(overall=2.7e-05)  # msgspec alone would write 0.000027
    assert dumps_line(record) == json.dumps(to_builtins(record), separators=(",", ":"))
    assert "2.7e-05" in dumps_line(record)


@given(st.floats(allow_nan=False, allow_infinity=False), st.floats(0, 1e6, allow_nan=False))
def test_floats_survive_the_round_trip_bit_for_bit(overall, speed):
    record = msgspec.structs.replace(
        ok_record(),
        policy_time_s=speed,
        metrics=msgspec.structs.replace(ok_record().metrics, overall=overall),
    )
    back = decode_episode(dumps_line(record).encode(), SRC, 1)
    assert back.metrics.overall == overall and back.policy_time_s == speed


def test_records_are_frozen():
    with pytest.raises(AttributeError):
        ok_record().seed = 3  # type: ignore[misc]


def test_actions_have_exactly_one_form():
    assert ActionRecord.of(Action(1, 0, 2, 3)).to_action() == Action(1, 0, 2, 3)
    assert ActionRecord.of(Unparsable("??", "no json")).to_action() == Unparsable("??", "no json")
    with pytest.raises(ValueError, match="either"):
        ActionRecord(object_id=1, x=2, y=3, rotation=0, unparsable="x", error="")
    with pytest.raises(ValueError, match="either"):
        ActionRecord(object_id=1)


# -- versions: unknown is an error, older migrates ------------------------------------------------


def test_an_unknown_episode_version_names_file_line_field_and_value():
    obj = {**to_builtins(ok_record()), "format": "packlab-bench-run-9"}
    with pytest.raises(RecordFormatError) as err:
        decode_episode(_line(obj), SRC, 7)
    msg = str(err.value)
    assert msg.startswith(
        f"{SRC}:7: field 'format' = 'packlab-bench-run-9': unknown format version"
    )
    assert RUN_FORMAT in msg and isinstance(err.value, PacklabError)
    # Even when the rest of the record no longer looks like today's, the version is what is named.
    with pytest.raises(RecordFormatError, match="field 'format' = 'packlab-bench-run-9'"):
        decode_episode(
            _line({"status": "ok", "format": "packlab-bench-run-9", "shape": "new"}), SRC, 7
        )


def test_a_run1_ok_record_migrates_without_changing_a_number():
    obj = _run1_ok_line()
    rec = decode_episode(_line(obj), SRC, 1)
    assert isinstance(rec, EpisodeOk) and rec.format == RUN_FORMAT
    assert rec.metrics.unsettled_steps == 3  # capped_placements
    assert rec.metrics.at_rest is True and rec.metrics.final_settle_steps == 0
    assert rec.metrics.residual_linear_mps == rec.metrics.residual_angular_radps == 0.0
    assert [s.settled for s in rec.steps] == [False]  # capped
    assert rec.metrics.overall == obj["metrics"]["overall"] and rec.metrics.success_ratio == 0.5


def test_a_run1_error_record_reads_as_an_exception():
    obj = to_builtins(error_record())
    del obj["format"], obj["error_kind"]
    rec = decode_episode(_line(obj), SRC, 1)
    assert (
        isinstance(rec, EpisodeError)
        and rec.error_kind == "exception"
        and rec.error == obj["error"]
    )


def test_a_record_without_status_is_an_ok_record():
    obj = _run1_ok_line()
    del obj["status"]
    assert isinstance(decode_episode(_line(obj), SRC, 1), EpisodeOk)


# -- wrong types: file, line, field path, value ---------------------------------------------------


@pytest.mark.parametrize("legacy", [False, True], ids=["current", "run-1"])
def test_a_wrong_typed_field_names_file_line_field_and_value(legacy):
    obj = _run1_ok_line() if legacy else to_builtins(ok_record())
    obj["metrics"]["overall"] = "high"
    with pytest.raises(RecordFormatError) as err:
        decode_episode(_line(obj), SRC, 12)
    assert (
        str(err.value) == f"{SRC}:12: field 'metrics.overall' = 'high': Expected `float`, got `str`"
    )
    assert (err.value.line, err.value.field, err.value.value) == (12, "metrics.overall", "high")


def test_nested_and_missing_fields_are_named_by_their_path():
    obj = to_builtins(ok_record())
    obj["steps"][0]["action"]["x"] = 1.5
    with pytest.raises(
        RecordFormatError, match=r":3: field 'steps\[0\]\.action\.x' = 1\.5: Expected `int`"
    ):
        decode_episode(_line(obj), SRC, 3)
    obj = to_builtins(ok_record())
    del obj["seed"]
    with pytest.raises(RecordFormatError, match=r":3: field 'seed' = <absent>: missing"):
        decode_episode(_line(obj), SRC, 3)
    obj = {**to_builtins(error_record()), "error_kind": "boom"}
    with pytest.raises(RecordFormatError, match=r"field 'error_kind' = 'boom'"):
        decode_episode(_line(obj), SRC, 3)


def test_text_that_is_not_json_is_told_apart():
    with pytest.raises(NotJSON, match=f"{SRC}:4: not JSON"):
        decode_episode(b'{"status":"ok","case_id":', SRC, 4)
    with pytest.raises(RecordFormatError, match="expected a JSON object"):
        decode_episode(b"[1, 2]", SRC, 4)


# -- summary.json ---------------------------------------------------------------------------------


def _summary_obj() -> dict:
    cell = {"mean": 0.5, "std": 0.0, "per_seed": {"0": 0.5}}
    cells = {m: cell for m in ("success_ratio", "compactness", "overall")}
    counts = {
        "episodes": 1,
        "errors": 0,
        "steps": 3,
        "invalid_steps": 0,
        "set_aside": 0,
        "unsettled_steps": 1,
        "not_at_rest": 0,
        "max_residual_linear_mps": 0.0,
        "max_residual_angular_radps": 0.0,
        "decision_ms": None,
        "step_ms": 1.0,
        "episode_s": 0.1,
    }
    return {
        "format": SUMMARY_FORMAT,
        "suite": "s",
        "backend": "geometric",
        "n_cases": 1,
        "cases_sha256": "abc",
        "policies": ["p"],
        "seeds": [0],
        "difficulties": ["easy"],
        "metrics": ["success_ratio", "compactness", "overall"],
        "aggregation": "a",
        "table": {"p": {"easy": cells}},
        "per_case": {"p": {"c": {"difficulty": "easy", **cells}}},
        "counts": {"p": counts},
        "errors": [{"case_id": "c", "seed": 0, "policy": "p", "error": "E"}],
    }


def test_a_summary_round_trips():
    text = json.dumps(_summary_obj(), indent=1)
    summary = summary_from_json(text, "summary.json")
    assert json.dumps(to_builtins(summary), indent=1) == text
    assert summary.table["p"]["easy"].cell("overall").mean == 0.5


def test_a_summary_of_unknown_version_is_refused_by_name():
    obj = {**_summary_obj(), "format": "packlab-bench-summary-7"}
    with pytest.raises(
        RecordFormatError, match="run/summary.json: field 'format' = 'packlab-bench-summary-7'"
    ):
        summary_from_json(json.dumps(obj), "run/summary.json")


def test_a_summary_from_before_versions_migrates():
    obj = _summary_obj()
    del obj["format"]
    counts = obj["counts"]["p"]
    for key in (
        "unsettled_steps",
        "not_at_rest",
        "max_residual_linear_mps",
        "max_residual_angular_radps",
    ):
        del counts[key]
    counts["capped_placements"] = 4  # run-1's name
    summary = summary_from_json(json.dumps(obj), "summary.json")
    assert summary.format == SUMMARY_FORMAT
    c = summary.counts["p"]
    assert c.unsettled_steps == 4 and c.not_at_rest is None and c.max_residual_linear_mps is None


def test_a_summary_with_a_wrong_typed_cell_names_the_field():
    obj = _summary_obj()
    obj["counts"]["p"]["episodes"] = "one"
    with pytest.raises(
        RecordFormatError, match=r"summary.json: field 'counts\[\.\.\.\]\.episodes': Expected `int`"
    ):
        summary_from_json(json.dumps(obj), "summary.json")


# -- config.json (the part a report reads) ---------------------------------------------------------


def test_run_config_versions():
    base = {"policies": ["p"], "seeds": [0], "difficulties": ["easy"], "suite": "s"}
    assert (
        run_config_from_json(json.dumps({**base, "format": RUN_FORMAT_1}), "c.json").format
        == RUN_FORMAT_1
    )
    with pytest.raises(
        RecordFormatError, match="c.json: field 'format' = 'packlab-bench-run-3': unknown"
    ):
        run_config_from_json(json.dumps({**base, "format": "packlab-bench-run-3"}), "c.json")
    with pytest.raises(
        RecordFormatError, match="c.json: field 'format' = <absent>: no format version"
    ):
        run_config_from_json(json.dumps(base), "c.json")
    with pytest.raises(RecordFormatError, match=r"c.json: field 'seeds\[0\]' = 'zero'"):
        run_config_from_json(
            json.dumps({**base, "format": RUN_FORMAT, "seeds": ["zero"]}), "c.json"
        )


# -- meta/info.json -------------------------------------------------------------------------------


def _info_obj() -> dict:
    by = {
        "requested": 2,
        "episodes": 2,
        "steps": 9,
        "attempts": 3,
        "rejected": 1,
        "acceptance_rate": 0.666667,
        "rejections": {"overall_below_min": 1},
        "failed_slots": [],
    }
    return {
        "format_version": PACKDATA_FORMAT,
        "name": "packdata-custom",
        "generator": {
            "name": "packlab.datagen",
            "version": "packlab-datagen-1",
            "seed_domain": "train",
        },
        "generator_config": {
            "seed": 7,
            "difficulties": ["easy"],
            "case": {"container": {"clamp_xy_mm": [500, 1700]}},
            "recipe": None,
            "validation": {"min_overall": 0.99},
        },
        "validation_backend": "mujoco",
        "prompt_version": "packlab-prompt-v1",
        "counts": {"episodes": 2, "steps": 9, "shards": 1, "by_difficulty": {"easy": by}},
        "rejections": {"overall_below_min": 1},
        "image": {"size": 224, "format": "png", "mode": "P", "axes": "x", "colour": "c"},
        "files": {"steps": "s", "episodes": "e", "sft": None, "sft_mode": "none", "images": "i"},
    }


def test_dataset_info_round_trips_with_sorted_keys():
    text = json.dumps(_info_obj(), indent=1, sort_keys=True)
    info = dataset_info_from_json(text, "meta/info.json")
    assert json.dumps(to_builtins(info), indent=1, sort_keys=True) == text
    assert info.counts.by_difficulty["easy"].acceptance_rate == 0.666667


def test_dataset_info_versions_are_checked():
    with pytest.raises(
        RecordFormatError, match="d/meta/info.json: field 'format_version' = 'packdata-9': unknown"
    ):
        dataset_info_from_json(
            json.dumps({**_info_obj(), "format_version": "packdata-9"}), "d/meta/info.json"
        )
    obj = _info_obj()
    del obj["format_version"]
    with pytest.raises(
        RecordFormatError, match="field 'format_version' = <absent>: no format version"
    ):
        dataset_info_from_json(json.dumps(obj), "d/meta/info.json")


def test_dataset_info_with_a_wrong_typed_field_names_it():
    obj = _info_obj()
    obj["counts"]["steps"] = 9.5
    with pytest.raises(
        RecordFormatError, match=r"info.json: field 'counts.steps' = 9.5: Expected `int`"
    ):
        dataset_info_from_json(json.dumps(obj), "info.json")
    obj = _info_obj()
    obj["generator_config"]["case"] = {"deep": [[[[[[[[1]]]]]]]]}  # deeper than any config: refused
    with pytest.raises(RecordFormatError, match=r"field 'generator_config"):
        dataset_info_from_json(json.dumps(obj), "info.json")
