"""``packlab generate --teacher``: trajectories of a policy on the states it reaches itself."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from datagen_helpers import tiny_config

from packlab.bench.suites import resolve_cases
from packlab.core.errors import ConfigError
from packlab.core.types import Container, Observation, ShownItem
from packlab.datagen.engine import RunOptions, generate_dataset
from packlab.datagen.stats import dataset_cases
from packlab.policies import make_policy


def _steps(root):
    rows = []
    for path in sorted((root / "data" / "steps").glob("*.parquet")):
        rows += pq.read_table(path).to_pylist()
    return rows


def _observation(row) -> Observation:
    container = Container(tuple(round(v * 10) for v in row["container_size_cm"]))
    hm = np.asarray(row["heightmap_mm"], dtype=np.int32).reshape(container.cells)
    shown = tuple(
        ShownItem(
            i,
            s["internal_id"],
            tuple(round(v * 10) for v in s["size_cm"]),
            tuple(s["size_cells"]),
        )
        for i, s in enumerate(row["shown"])
    )
    return Observation(row["step_index"], container, hm, shown)


def test_every_action_is_the_teachers_on_the_state_it_reached(tmp_path):
    cfg = tiny_config(episodes=(3, 1, 0), teacher="sdf")
    generate_dataset(cfg, RunOptions(str(tmp_path), workers=1, progress=False))
    info = json.loads((tmp_path / "meta" / "info.json").read_text())
    assert info["generator_config"]["teacher"] == "sdf"
    sdf = make_policy("sdf")
    rows = _steps(tmp_path)
    assert rows
    for row in rows:
        action = sdf.act(_observation(row))
        assert action.to_dict() == row["action"]


def test_the_oracle_default_keeps_the_config_of_older_datasets():
    assert "teacher" not in tiny_config().to_dict()
    assert tiny_config(teacher="plan").to_dict()["teacher"] == "plan"


def test_an_empty_teacher_is_a_one_line_error():
    with pytest.raises(ConfigError, match="teacher = ''"):
        tiny_config(teacher=" ")


def test_the_bench_reads_a_generated_dataset_directory_as_its_cases(tmp_path):
    generate_dataset(
        tiny_config(episodes=(2, 1, 0)), RunOptions(str(tmp_path), workers=1, progress=False)
    )
    source = resolve_cases(str(tmp_path))
    assert [c.episode_id for c in source.cases] == [c.episode_id for c in dataset_cases(tmp_path)]
    assert len(source.cases) == 3
