"""The reference's own benchmark files load unchanged; packlab cases survive the trip through them.

The fixture under tests/data/reference_bench is the reference generator's output (see its
README.md): 60 cases, string object ids, ``gt_plan`` beside ``interaction_kwargs``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from packlab.bench.suites import load_suite, resolve_cases, suite_digest
from packlab.cases import (
    case_to_dict,
    cases_sha256,
    load_cases,
    reference_level_files,
    save_cases,
    write_reference,
)
from packlab.cli.main import main
from packlab.core.errors import ConfigError
from packlab.core.types import CaseOrigin, Container

REFERENCE_DIR = Path(__file__).resolve().parents[1] / "data" / "reference_bench"
LEVELS = {"easy": (610000, 3), "medium": (620000, 5), "hard": (630000, 10)}


@pytest.fixture(scope="module")
def reference_cases():
    return load_cases(REFERENCE_DIR)


def _bench(cases: str, out: Path, policies: str, seeds: str = "0") -> int:
    return main(
        [
            "bench",
            "--cases",
            cases,
            "--policies",
            policies,
            "--backend",
            "geometric",
            "--seeds",
            seeds,
            "--out",
            str(out),
            "--workers",
            "1",
            "--no-progress",
            "--no-figures",
        ]
    )


def _records(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "episodes.jsonl").read_text().splitlines()]


def _without_timings(value):
    """A record minus what measures time (keys ``timing`` and ``*_s``: wall and CPU seconds)."""
    if isinstance(value, dict):
        return {
            k: _without_timings(v)
            for k, v in value.items()
            if k != "timing" and not k.endswith("_s")
        }
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


# -- the reference's files as they are ------------------------------------------------------------


def test_fixture_is_the_reference_layout():
    """Guard the fixture itself: columns and nesting as the reference's writer makes them."""
    table = pq.read_table(REFERENCE_DIR / "easy" / "test.parquet")
    assert table.column_names == ["data_source", "prompt_template_id", "ability", "extra_info"]
    extra = table.schema.field("extra_info").type
    assert [extra.field(i).name for i in range(extra.num_fields)] == [
        "split",
        "index",
        "difficulty",
        "generator",
        "gt_plan",
        "interaction_kwargs",
    ]
    row = table.to_pylist()[0]["extra_info"]
    assert row["interaction_kwargs"]["object_sequence"][0]["internal_id"] == "obj_00000"
    assert all(step["action"]["object_id"] is None for step in row["gt_plan"])
    assert isinstance(row["generator"], str) and "gt_plan" not in row["interaction_kwargs"]


def test_reference_directory_loads_every_field(reference_cases):
    assert [lvl for lvl, _ in reference_level_files(REFERENCE_DIR)] == ["easy", "medium", "hard"]
    assert len(reference_cases) == 60
    for n, case in enumerate(reference_cases):
        level = ("easy", "medium", "hard")[n // 20]
        i = n % 20
        seed0, buffer_size = LEVELS[level]
        assert case.episode_id == f"{level}_{i:06d}"  # extra_info.interaction_kwargs.sample_id
        assert (
            case.difficulty == level and case.buffer_size == buffer_size and case.seed == seed0 + i
        )
        assert case.origin == CaseOrigin("test", i)
        assert case.generator == {"name": "layer_cuboid_v1_layer_random_anchor"}
        ids = [b.internal_id for b in case.objects]
        assert ids == [f"obj_{k:05d}" for k in range(len(ids))]  # kept as given
        assert case.gt_plan is not None and [p.internal_id for p in case.gt_plan] == ids
        assert (case.container.cell_xy_mm, case.container.cell_z_mm) == (25, 2)


def test_string_ids_are_written_back_unchanged(reference_cases, tmp_path):
    path = save_cases(reference_cases[:3], tmp_path / "ref.jsonl")
    first = json.loads(path.read_text().splitlines()[0])
    assert first["object_sequence"][0]["internal_id"] == "obj_00000"
    assert first["gt_plan"][0]["internal_id"] == "obj_00000"
    assert load_cases(path) == reference_cases[:3]


def test_reference_files_round_trip_to_the_same_rows(reference_cases, tmp_path):
    """Loaded and written again, the reference's files come out with the same rows and nesting."""
    out = tmp_path / "again"
    write_reference(reference_cases, out)
    for level in LEVELS:
        original = pq.read_table(REFERENCE_DIR / level / "test.parquet")
        again = pq.read_table(out / level / "test.parquet")
        assert again.to_pylist() == original.to_pylist()
        assert again.schema.field("extra_info").type == original.schema.field("extra_info").type
    manifest = json.loads((out / "metadata" / "manifest.json").read_text())
    ref_manifest = json.loads((REFERENCE_DIR / "metadata" / "manifest.json").read_text())
    for level in LEVELS:
        mine, theirs = manifest["difficulties"][level], ref_manifest["difficulties"][level]
        assert {k: v for k, v in mine.items() if k != "parquet_path"} == {
            k: v for k, v in theirs.items() if k != "parquet_path"
        }


def test_oracle_scores_one_on_every_reference_case(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert _bench(str(REFERENCE_DIR), run_dir, "oracle") == 0
    capsys.readouterr()
    table = (run_dir / "table.md").read_text()  # the full table (the terminal's is compact)
    header = next(line for line in table.splitlines() if line.startswith("| Method"))
    for level in ("Easy", "Medium", "Hard"):
        assert f"{level} Overall" in header
    oracle_row = next(line for line in table.splitlines() if line.startswith("| Oracle"))
    # SR, compactness, overall for three levels and the average, each 1.000 (interval too)
    cells = [c.strip() for c in oracle_row.split("|")[2:14]]
    assert all(c in ("1.000", "1.000 [1.000, 1.000]") for c in cells), cells
    records = _records(run_dir)
    assert sorted(r["case_id"] for r in records) == sorted(
        f"{lvl}_{i:06d}" for lvl in LEVELS for i in range(20)
    )
    assert all(r["status"] == "ok" and r["metrics"]["overall"] == 1.0 for r in records)
    assert {r["difficulty"] for r in records} == set(LEVELS)
    # Object ids reach the records as the file gave them.
    step = records[0]["steps"][0]
    assert isinstance(step["internal_id"], str) and step["internal_id"].startswith("obj_")
    assert all(k.startswith("obj_") for k in records[0]["final_poses"])


# -- packlab cases through the reference layout --------------------------------------------------


@pytest.mark.parametrize("target", ["dir", "file.parquet", "rows.jsonl"])
def test_bundled_suite_round_trips_through_the_reference_layout(tmp_path, target):
    cases = load_suite()
    write_reference(cases, tmp_path / target)
    back = load_cases(tmp_path / target)
    assert back == cases
    # Field by field too (origin is provenance and the only field allowed to differ).
    for a, b in zip(cases, back):
        assert dataclasses.replace(b, origin=None) == a
        assert [type(x.internal_id) for x in b.objects] == [int] * len(a.objects)
        assert case_to_dict(a) == case_to_dict(b)
    assert cases_sha256(back) == cases_sha256(cases) == suite_digest("packlab-bench-v1")
    assert resolve_cases(str(tmp_path / target)).sha256 == resolve_cases("packlab-bench-v1").sha256


def test_bench_results_are_identical_from_both_layouts(tmp_path):
    suite = load_suite()
    handful = [c for level in LEVELS for c in [x for x in suite if x.difficulty == level][:2]]
    native = save_cases(handful, tmp_path / "handful.jsonl")
    reference = tmp_path / "handful-ref"
    write_reference(handful, reference)
    policies = "oracle,dblf,random"
    assert _bench(str(native), tmp_path / "run-native", policies) == 0
    assert _bench(str(reference), tmp_path / "run-reference", policies) == 0
    key = lambda r: (r["case_id"], r["policy"], r["seed"])
    a = sorted(map(_without_timings, _records(tmp_path / "run-native")), key=key)
    b = sorted(map(_without_timings, _records(tmp_path / "run-reference")), key=key)
    assert len(a) == len(handful) * 3 and a == b
    cfg_a = json.loads((tmp_path / "run-native" / "config.json").read_text())
    cfg_b = json.loads((tmp_path / "run-reference" / "config.json").read_text())
    assert cfg_a["cases_sha256"] == cfg_b["cases_sha256"] == cases_sha256(handful)
    assert (tmp_path / "run-native" / "cases.jsonl").read_bytes() == (
        tmp_path / "run-reference" / "cases.jsonl"
    ).read_bytes()


def test_reference_directory_loads_levels_in_the_documented_order(reference_cases, tmp_path):
    by_level = {
        "zeta": reference_cases[0],
        "hard": reference_cases[40],
        "alpha": reference_cases[20],
        "easy": reference_cases[1],
    }
    for level, case in by_level.items():
        relabelled = dataclasses.replace(
            case, difficulty=level, episode_id=f"{level}-case", origin=None
        )
        write_reference([relabelled], tmp_path / "parts" / level)
        (tmp_path / "mixed" / level).mkdir(parents=True)
        (tmp_path / "parts" / level / level / "test.parquet").rename(
            tmp_path / "mixed" / level / "test.parquet"
        )
    loaded = load_cases(tmp_path / "mixed")
    assert [c.difficulty for c in loaded] == ["easy", "hard", "alpha", "zeta"]


def test_a_case_on_another_grid_cannot_be_written_in_the_reference_layout(
    reference_cases, tmp_path
):
    c = reference_cases[0]
    odd = dataclasses.replace(c, container=Container(c.container.size_mm, 25, 5))
    with pytest.raises(ConfigError, match="no grid field"):
        write_reference([odd], tmp_path / "x.parquet")
    assert not (tmp_path / "x.parquet").exists() and list(tmp_path.iterdir()) == []


def test_export_refuses_an_existing_target(reference_cases, tmp_path):
    (tmp_path / "taken").mkdir()
    with pytest.raises(ConfigError, match="already exists"):
        write_reference(reference_cases, tmp_path / "taken")


# -- the command line ------------------------------------------------------------------------------


def test_cases_export_and_validate_commands(tmp_path, capsys):
    out = tmp_path / "bench-ref"
    assert (
        main(["cases", "export", "packlab-bench-v1", "--format", "reference", "--out", str(out)])
        == 0
    )
    assert (out / "easy" / "test.parquet").is_file() and (
        out / "metadata" / "manifest.json"
    ).is_file()
    assert (
        main(
            [
                "cases",
                "export",
                str(out),
                "--format",
                "jsonl",
                "--out",
                str(tmp_path / "back.jsonl"),
            ]
        )
        == 0
    )
    # Back to packlab's JSONL: byte for byte the bundled suite file.
    from packlab.bench.suites import suite_files

    assert (tmp_path / "back.jsonl").read_bytes() == suite_files("packlab-bench-v1")[0].read_bytes()
    capsys.readouterr()
    assert main(["cases", "validate", str(REFERENCE_DIR)]) == 0
    out_text = capsys.readouterr().out
    assert (
        "60 cases OK" in out_text
        and "easy 20, medium 20, hard 20" in out_text
        and "internal_id str" in out_text
    )
    again = [
        "cases",
        "export",
        str(REFERENCE_DIR),
        "--format",
        "jsonl",
        "--out",
        str(tmp_path / "back.jsonl"),
    ]
    assert main(again) == 2
    assert "already exists" in capsys.readouterr().err
