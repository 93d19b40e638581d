"""Bad case files: one clear line naming file, line or row, field and value.

Exit code 2; nothing written.

Each maker writes one bad file into a directory of its own and returns its path and the pieces
the error must contain. Every case is checked twice: through ``load_cases`` (the message) and
through ``packlab bench --cases BAD`` (exit code 2, one line on stderr, no run directory and no
stray file next to the input).
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from packlab.cases import MAX_BUFFER_SIZE, MAX_HEIGHTMAP_CELLS, MAX_OBJECTS, load_cases
from packlab.cli.main import main
from packlab.core.errors import PacklabError

REFERENCE_EASY = (
    Path(__file__).resolve().parents[1] / "data" / "reference_bench" / "easy" / "test.parquet"
)


def _case(**overrides) -> dict:
    record = {
        "episode_id": "ok",
        "container_size_cm": [50, 40, 30],
        "buffer_size": 2,
        "object_sequence": [
            {"internal_id": 0, "size_cm": [25, 40, 10]},
            {"internal_id": 1, "size_cm": [25, 40, 10]},
        ],
    }
    record.update(overrides)
    return record


def _jsonl(directory: Path, *records: dict, name: str = "cases.jsonl") -> Path:
    path = directory / name
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return path


def _reference_row() -> dict:
    return pq.read_table(REFERENCE_EASY).slice(0, 1).to_pylist()[0]


def _parquet_rows(directory: Path, rows: list[dict], name: str = "bench.parquet") -> Path:
    path = directory / name
    pq.write_table(pa.Table.from_pylist(rows), path)
    return path


# -- the bad files ---------------------------------------------------------------------------------


def not_utf8(d):
    good = (json.dumps(_case()) + "\n").encode()
    path = d / "latin1.jsonl"
    path.write_bytes(good + b'{"episode_id": "caf\xe9"}\n')
    return path, ["latin1.jsonl:2", "not UTF-8", f"byte offset {len(good) + 19}"]


def not_utf8_json(d):
    path = d / "one.json"
    path.write_bytes(b'{\n "episode_id": "\xff"\n}')
    return path, ["one.json:2", "not UTF-8", "byte offset 18"]


def text_named_parquet(d):
    path = d / "notes.parquet"
    path.write_text("this is not parquet\n")
    return path, ["notes.parquet", "not a readable parquet file"]


def truncated_parquet(d):
    path = d / "cut.parquet"
    path.write_bytes(REFERENCE_EASY.read_bytes()[:4000])
    return path, ["cut.parquet", "not a readable parquet file", "truncated"]


def malformed_parquet(d):
    path = d / "garbage.parquet"
    path.write_bytes(b"PAR1" + bytes(range(256)) * 4 + b"PAR1")
    return path, ["garbage.parquet", "not a readable parquet file"]


def extra_info_integer(d):
    return _parquet_rows(d, [{"extra_info": 7}]), [
        "bench.parquet (row 1)",
        "'extra_info' = 7",
        "expected an object",
    ]


def extra_info_not_json(d):
    path = _parquet_rows(
        d, [{"extra_info": json.dumps(_reference_row()["extra_info"])}, {"extra_info": "{oops"}]
    )
    return path, ["bench.parquet (row 2)", "'extra_info' = '{oops'", "not JSON"]


def missing_interaction_kwargs(d):
    row = _reference_row()
    del row["extra_info"]["interaction_kwargs"]
    return _parquet_rows(d, [row]), [
        "bench.parquet (row 1)",
        "'extra_info.interaction_kwargs'",
        "missing",
    ]


def no_extra_info_column(d):
    return _parquet_rows(d, [{"prompt": "x"}]), ["bench.parquet", "no 'extra_info' column"]


def a_plain_directory(d):
    sub = d / "some_dir"
    sub.mkdir()
    (sub / "cases.jsonl").write_text(json.dumps(_case()) + "\n")
    return sub, ["some_dir", "is a directory", "pass a case file", "reference benchmark directory"]


def huge_container(d):
    path = _jsonl(d, _case(), _case(episode_id="big", container_size_cm=[1e300, 40, 30]))
    return path, ["cases.jsonl:2", "'container_size_cm[0]' = 1e+300", "limit of 1000 cm"]


def huge_integer_container(d):
    path = _jsonl(d, _case(container_size_cm=[50, 40, 10**400]))
    return path, ["cases.jsonl:1", "'container_size_cm[2]'", "(401 digits)", "limit of 1000 cm"]


def reference_row_huge_container(d):
    row = _reference_row()
    row["extra_info"]["interaction_kwargs"]["container_size_cm"] = [1e300, 50.0, 35.0]
    return _parquet_rows(d, [_reference_row(), row]), [
        "bench.parquet (row 2)",
        "'extra_info.interaction_kwargs.container_size_cm[0]' = 1e+300",
        "limit",
    ]


def too_many_objects(d):
    objects = [{"internal_id": i, "size_cm": [2.5, 2.5, 0.2]} for i in range(MAX_OBJECTS + 1)]
    path = _jsonl(d, _case(object_sequence=objects))
    return path, ["cases.jsonl:1", "'object_sequence'", f"limit of {MAX_OBJECTS} objects"]


def buffer_too_large(d):
    path = _jsonl(d, _case(buffer_size=MAX_BUFFER_SIZE + 1))
    return path, ["cases.jsonl:1", f"'buffer_size' = {MAX_BUFFER_SIZE + 1}", "MAX_BUFFER_SIZE"]


def too_many_cells(d):
    path = _jsonl(
        d, _case(grid_cell_size_cm={"xy": 0.1, "z": 0.1}, container_size_cm=[500, 500, 30])
    )
    return path, [
        "cases.jsonl:1",
        "'container_size_cm'",
        f"limit of {MAX_HEIGHTMAP_CELLS} heightmap cells",
    ]


def nan_box_side(d):
    path = d / "nan.jsonl"
    text = json.dumps(_case()).replace("[25, 40, 10]", "[NaN, 40, 10]", 1)
    path.write_text(text + "\n")
    return path, ["nan.jsonl:1", "'object_sequence[0].size_cm[0]' = nan", "finite"]


def mixed_id_types(d):
    objects = [
        {"internal_id": 0, "size_cm": [25, 40, 10]},
        {"internal_id": "obj_1", "size_cm": [25, 40, 10]},
    ]
    path = _jsonl(d, _case(object_sequence=objects))
    return path, [
        "cases.jsonl:1",
        "'object_sequence[1].internal_id' = 'obj_1'",
        "must all be integers or all strings",
    ]


def id_with_control_character(d):
    objects = [{"internal_id": "a\nb", "size_cm": [25, 40, 10]}]
    path = _jsonl(d, _case(object_sequence=objects))
    return path, ["cases.jsonl:1", "'object_sequence[0].internal_id'", "printable"]


def deeply_nested_line(d):
    path = d / "deep.jsonl"
    path.write_text(json.dumps(_case()) + "\n" + "[" * 100_000 + "\n")
    return path, ["deep.jsonl:2", "bad JSON line"]


def plan_outside_the_container(d):
    row = _reference_row()
    row["extra_info"]["gt_plan"][0]["target_box_cells"]["x"] = 1000
    return _parquet_rows(d, [row]), [
        "bench.parquet (row 1)",
        "'extra_info.gt_plan[0].target_box_cells'",
        "outside the container",
    ]


def reference_dir_with_a_bad_level(d):
    root = d / "bench"
    (root / "easy").mkdir(parents=True)
    (root / "easy" / "test.parquet").write_bytes(REFERENCE_EASY.read_bytes())
    (root / "hard").mkdir()
    (root / "hard" / "test.parquet").write_text("not parquet")
    return root, [str(Path("bench") / "hard" / "test.parquet"), "not a readable parquet file"]


BAD_FILES = [
    not_utf8,
    not_utf8_json,
    text_named_parquet,
    truncated_parquet,
    malformed_parquet,
    extra_info_integer,
    extra_info_not_json,
    missing_interaction_kwargs,
    no_extra_info_column,
    a_plain_directory,
    huge_container,
    huge_integer_container,
    reference_row_huge_container,
    too_many_objects,
    buffer_too_large,
    too_many_cells,
    nan_box_side,
    mixed_id_types,
    id_with_control_character,
    deeply_nested_line,
    plan_outside_the_container,
    reference_dir_with_a_bad_level,
]


@pytest.fixture(params=BAD_FILES, ids=lambda f: f.__name__)
def bad_file(request, tmp_path):
    d = tmp_path / "input"
    d.mkdir()
    path, expected = request.param(d)
    return path, expected


def _snapshot(root: Path) -> dict[str, bytes | None]:
    return {
        str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
        for p in sorted(root.rglob("*"))
    }


def test_load_names_file_place_field_and_value(bad_file):
    path, expected = bad_file
    with pytest.raises(PacklabError) as info:
        load_cases(path)
    message = str(info.value)
    assert len(message.splitlines()) == 1, message
    for piece in expected:
        assert piece in message, f"{piece!r} not in {message!r}"


def test_bench_exits_2_and_writes_nothing(bad_file, tmp_path, capsys):
    path, expected = bad_file
    before = _snapshot(tmp_path)
    run_dir = tmp_path / "run"
    code = main(
        [
            "bench",
            "--cases",
            str(path),
            "--backend",
            "geometric",
            "--policies",
            "oracle",
            "--seeds",
            "0",
            "--out",
            str(run_dir),
            "--workers",
            "1",
            "--no-progress",
            "--no-figures",
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("packlab bench: error: "), err
    assert expected[-1] in err
    assert not run_dir.exists()
    assert _snapshot(tmp_path) == before  # no partial or temporary file anywhere


def test_export_of_a_bad_source_writes_nothing(tmp_path, capsys):
    path, _ = huge_container(tmp_path)
    out = tmp_path / "exported"
    assert main(["cases", "export", str(path), "--format", "reference", "--out", str(out)]) == 2
    assert "limit of 1000 cm" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cases.jsonl"]
