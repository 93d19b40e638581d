"""``packlab generate`` and ``packlab inspect-data`` end to end on a tiny dataset."""

from __future__ import annotations

import json

import pytest

from packlab.cli.main import main
from packlab.core.records import PACKDATA_FORMAT, to_builtins
from packlab.datagen.format import read_info


def test_generate_then_inspect(tmp_path, capsys):
    out = tmp_path / "ds"
    rc = main(
        [
            "generate",
            "--difficulty",
            "easy,hard",
            "--episodes",
            "3,1",
            "--seed",
            "2",
            "--out",
            str(out),
            "--validation",
            "geometric",
            "--workers",
            "1",
            "--image-size",
            "48",
            "--no-progress",
        ]
    )
    assert rc == 0
    assert "4 episodes" in capsys.readouterr().out
    rc = main(["inspect-data", str(out), "--plots", str(tmp_path / "plots")])
    text = capsys.readouterr().out
    assert rc == 0 and "objects_per_case" in text and "anchors" in text and "rejections" in text
    assert len(list((tmp_path / "plots").glob("*.png"))) == 6
    assert main(["inspect-data", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["distributions"]["easy"]["episodes"] == 3


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--difficulty", "easy", "--episodes", "x"], "episodes = 'x'"),
        (["--difficulty", "nope", "--episodes", "1"], "difficulty = 'nope'"),
        (["--difficulty", "easy"], "give --episodes"),
        (["--difficulty", "easy", "--episodes=-2"], "must be a whole number >= 0"),
    ],
)
def test_bad_flags_fail_with_one_line_and_no_output(tmp_path, capsys, argv, message):
    out = tmp_path / "never"
    assert main(["generate", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


def test_recipe_flag_reproduces_packdata_20k():
    from packlab.cli.generate import config_from_args
    from packlab.cli.main import build_parser

    args = build_parser().parse_args(["generate", "--recipe", "packdata-20k", "--out", "x"])
    cfg = config_from_args(args)
    assert (cfg.difficulties, cfg.episodes, cfg.recipe) == (
        ("easy", "medium", "hard"),
        (9000, 7000, 4000),
        "packdata-20k",
    )


def test_inspect_of_a_missing_dataset_fails_cleanly(tmp_path, capsys):
    assert main(["inspect-data", str(tmp_path)]) == 2
    assert "no meta/info.json" in capsys.readouterr().err


def test_info_json_is_a_typed_versioned_record(tiny_dataset):
    info = read_info(tiny_dataset)
    assert info.format_version == PACKDATA_FORMAT and info.counts.episodes == 10
    # Written as it always was: the record's plain form with sorted keys, indent 1.
    text = (tiny_dataset / "meta/info.json").read_text()
    assert json.dumps(to_builtins(info), indent=1, sort_keys=True) + "\n" == text


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"format_version": "packdata-9"},
            "field 'format_version' = 'packdata-9': unknown format version",
        ),
        (
            {"counts": {"episodes": "ten"}},
            "field 'counts.episodes' = 'ten': Expected `int`, got `str`",
        ),
    ],
)
def test_inspect_of_an_unreadable_info_json_names_file_field_and_value(
    tiny_dataset, tmp_path, capsys, change, message
):
    root = tmp_path / "copy"
    (root / "meta").mkdir(parents=True)
    info = json.loads((tiny_dataset / "meta/info.json").read_text())
    for key, value in change.items():
        info[key] = {**info[key], **value} if isinstance(value, dict) else value
    (root / "meta/info.json").write_text(json.dumps(info))
    assert main(["inspect-data", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{root / 'meta/info.json'}: {message}" in err
