"""The data engine names a box's sides as the bench does (longer first by default) and writes
sizes and ground-truth actions in that one frame; ``sides="catalogue"`` stays selectable, and a
dataset made before the field existed resumes only under the catalogue's names."""

from __future__ import annotations

import json

import pyarrow.parquet as pq
import pytest
from datagen_helpers import make_dataset, tiny_config

from packlab.core.errors import ConfigError
from packlab.datagen.stats import dataset_cases


def _rows(root):
    rows = []
    for path in sorted((root / "data" / "steps").glob("*.parquet")):
        rows += pq.read_table(path).to_pylist()
    return rows


def _check_frame(root, sides: str) -> int:
    """Every row's action puts its box where the plan does, read against the sizes the row
    shows; returns how many rows show a box under other names than the catalogue's."""
    cases = {c.episode_id: c for c in dataset_cases(root)}
    rows = _rows(root)
    assert rows
    renamed = 0
    for row in rows:
        case = cases[row["episode_id"]]
        action = row["action"]
        item = row["shown"][action["object_id"]]
        plan = next(p for p in case.gt_plan if p.internal_id == row["internal_id"])
        l, w, _ = item["size_cells"]
        footprint = (w, l) if action["rotation"] else (l, w)
        assert footprint == tuple(plan.cell_size[:2])
        assert (action["x"], action["y"]) == (plan.x, plan.y)
        catalogue = case.box_by_id(row["internal_id"]).size_mm
        shown_mm = tuple(round(v * 10) for v in item["size_cm"])
        if sides == "longer-first":
            assert shown_mm[0] >= shown_mm[1]
        else:
            assert shown_mm == catalogue
        renamed += shown_mm != catalogue
        # the action's rotation flips exactly where the names do
        assert action["rotation"] == plan.rotation ^ int(shown_mm != catalogue)
    return renamed


def test_rows_name_sides_longer_first_by_default_in_one_frame(tmp_path):
    cfg = tiny_config(episodes=(2, 1, 0))
    assert cfg.sides == "longer-first"
    make_dataset(tmp_path, cfg)
    info = json.loads((tmp_path / "meta" / "info.json").read_text())
    assert info["generator_config"]["sides"] == "longer-first"
    assert _check_frame(tmp_path, "longer-first") > 0  # some boxes are named the other way


def test_catalogue_names_stay_selectable(tmp_path):
    make_dataset(tmp_path, tiny_config(episodes=(2, 1, 0), sides="catalogue"))
    assert _check_frame(tmp_path, "catalogue") == 0
    with pytest.raises(ConfigError, match="sides = 'alphabetical'"):
        tiny_config(sides="alphabetical")


def test_a_dataset_made_before_the_field_resumes_only_under_the_catalogues_names(tmp_path):
    cfg = tiny_config(episodes=(1, 0, 0), sides="catalogue")
    make_dataset(tmp_path, cfg)
    path = tmp_path / "meta" / "config.json"
    stored = json.loads(path.read_text())
    del stored["sides"]  # as an older version wrote it
    path.write_text(json.dumps(stored))
    with pytest.raises(ConfigError, match="sides"):
        make_dataset(tmp_path, tiny_config(episodes=(1, 0, 0)))
    make_dataset(tmp_path, cfg)  # resumes: nothing left to do


def test_the_generate_flag_sets_the_field():
    from packlab.cli.generate import config_from_args
    from packlab.cli.main import build_parser

    parser = build_parser()
    base = ["generate", "--recipe", "packdata-20k", "--out", "x"]
    assert config_from_args(parser.parse_args(base)).sides == "longer-first"
    args = parser.parse_args([*base, "--sides", "catalogue"])
    assert config_from_args(args).sides == "catalogue"
