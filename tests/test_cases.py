"""Case files: round trip, reference parquet rows and clear errors for malformed input."""

import json
import os
import stat

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from layered_cases import make_layered_case

from packlab.cases import case_to_dict, load_cases, save_cases
from packlab.core.errors import CaseFormatError


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
    rows[1]["extra_info"]["interaction_kwargs"] = json.dumps(
        rows[1]["extra_info"]["interaction_kwargs"]
    )
    table = pa.table({"extra_info": [json.dumps(r["extra_info"]) for r in rows]})
    pq.write_table(table, tmp_path / "bench.parquet")
    cases = load_cases(tmp_path / "bench.parquet")
    assert [c.episode_id for c in cases] == ["p0", "p1"]


@pytest.mark.parametrize(
    "mutate, field, value_text",
    [
        (lambda r: r.pop("buffer_size"), "buffer_size", "None"),
        (lambda r: r.update(buffer_size=0), "buffer_size", "0"),
        (
            lambda r: r["object_sequence"][1].update(size_cm=[-25, 40, 10]),
            "object_sequence[1].size_cm[0]",
            "-25",
        ),
        (
            lambda r: r["object_sequence"][0].update(size_cm=[26.05, 40, 10]),
            "object_sequence[0].size_cm[0]",
            "26.05",
        ),
        (
            lambda r: r["object_sequence"][0].update(size_cm=[25, 40, 35]),
            "object_sequence[0].size_cm",
            "35",
        ),
        (
            lambda r: r["object_sequence"][0].update(size_cm=[75, 45, 10]),
            "object_sequence[0].size_cm",
            "75",
        ),
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


def test_sizes_off_the_grid_load_in_whole_millimetres(tmp_path):
    """A carton's sides need not lie on the 2.5 cm / 0.2 cm grid: whole millimetres load (a
    footprint then covers every cell it touches); a tenth of a millimetre does not."""
    record = _record()
    record["object_sequence"][0]["size_cm"] = [26, 14, 9.7]
    path = tmp_path / "off.jsonl"
    path.write_text(json.dumps(record) + "\n")
    [case] = load_cases(path)
    assert case.objects[0].size_mm == (260, 140, 97)
    assert case_to_dict(case)["object_sequence"][0]["size_cm"] == [26, 14, 9.7]


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


# -- ids, reference rows, limits, file modes ------------------------------------------------------


def _reference_row(**extra_overrides):
    kwargs = {
        "name": "packing",
        "sample_id": "easy_000007",
        "container_size_cm": [50.0, 40.0, 30.0],
        "buffer_size": 2,
        "seed": 610007,
        "object_sequence": [
            {
                "internal_id": f"obj_0000{i}",
                "gt_index": i,
                "type_id": i,
                "size_cm": [25.0, 40.0, 10.0],
            }
            for i in range(2)
        ],
    }
    plan = [
        {
            "internal_id": f"obj_0000{i}",
            "gt_index": i,
            "layer_index": 0,
            "target_box_cells": {"x": 10 * i, "y": 0, "z": 0, "dx": 10, "dy": 16, "dz": 50},
            "action": {"object_id": None, "x": 10 * i, "y": 0, "rotation": 0},
        }
        for i in range(2)
    ]
    extra = {
        "split": "test",
        "index": 7,
        "difficulty": "easy",
        "generator": "layer_cuboid_v1_layer_random_anchor",
        "gt_plan": plan,
        "interaction_kwargs": kwargs,
    }
    extra.update(extra_overrides)
    return {
        "data_source": "packing_eval",
        "prompt_template_id": "packing_sft",
        "ability": "spatial_packing",
        "extra_info": extra,
    }


@pytest.mark.parametrize("encoding", ["struct", "json-text"])
def test_reference_row_gives_every_field(tmp_path, encoding):
    from packlab.core.types import CaseOrigin

    row = _reference_row()
    if encoding == "json-text":  # extra_info and interaction_kwargs as JSON strings
        row["extra_info"]["interaction_kwargs"] = json.dumps(
            row["extra_info"]["interaction_kwargs"]
        )
        row["extra_info"] = json.dumps(row["extra_info"])
    pq.write_table(pa.Table.from_pylist([row]), tmp_path / "ref.parquet")
    (case,) = load_cases(tmp_path / "ref.parquet")
    assert case.episode_id == "easy_000007" and case.difficulty == "easy" and case.seed == 610007
    assert [b.internal_id for b in case.objects] == ["obj_00000", "obj_00001"]
    assert [p.internal_id for p in case.gt_plan] == ["obj_00000", "obj_00001"] and case.gt_plan[
        1
    ].x == 10
    assert case.generator == {"name": "layer_cuboid_v1_layer_random_anchor"}
    assert case.origin == CaseOrigin("test", 7)
    # The same row as a JSON line loads to the same case.
    (tmp_path / "ref.jsonl").write_text(json.dumps(_reference_row()) + "\n")
    assert load_cases(tmp_path / "ref.jsonl") == [case]


def test_reference_row_fields_that_disagree_are_refused(tmp_path):
    row = _reference_row()
    row["extra_info"]["interaction_kwargs"]["difficulty"] = "hard"
    (tmp_path / "ref.jsonl").write_text(json.dumps(row) + "\n")
    with pytest.raises(
        CaseFormatError, match=r"ref.jsonl:1: field 'extra_info.difficulty' = 'easy': differs"
    ):
        load_cases(tmp_path / "ref.jsonl")


def test_generator_name_and_mapping_survive_the_reference_row():
    from packlab.cases import case_from_dict, case_to_reference_row

    case = case_from_dict(_reference_row())
    assert (
        case_to_reference_row(case, 0)["extra_info"]["generator"]
        == "layer_cuboid_v1_layer_random_anchor"
    )
    rich = {"name": "packlab.datagen", "layer_heights_cm": [22, 12.4], "first_cell": [0, 0]}
    row = _reference_row(generator=json.dumps(rich))
    assert case_from_dict(row).generator == rich
    assert case_from_dict(row, "<row>") == case_from_dict(
        case_to_reference_row(case_from_dict(row), 0)
    )


def test_container_limits_hold_at_the_boundary(tmp_path):
    from packlab.cases import MAX_CONTAINER_SIDE_CM, case_from_dict

    side = MAX_CONTAINER_SIDE_CM
    box = {"internal_id": 0, "size_cm": [2.5, 2.5, 0.2]}
    case = case_from_dict(_record(container_size_cm=[side, side, side], object_sequence=[box]))
    assert case.container.cells == (400, 400)
    for size in ([side + 2.5, 40, 30], [50, 40, side + 0.2]):
        with pytest.raises(CaseFormatError, match="limit of 1000 cm"):
            case_from_dict(_record(container_size_cm=size, object_sequence=[box]))


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_files_get_the_users_umask(tmp_path, umask):
    from packlab.cases import write_reference

    old = os.umask(umask)
    try:
        path = save_cases([make_layered_case(0)], tmp_path / "suite.jsonl")
        out = tmp_path / "ref"
        write_reference([make_layered_case(0, episode_id="a")], out)
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask
    assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~umask
    for f in [p for p in out.rglob("*") if p.is_file()]:
        assert stat.S_IMODE(f.stat().st_mode) == 0o666 & ~umask, f
