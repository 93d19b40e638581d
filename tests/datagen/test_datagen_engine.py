"""The engine: determinism, resume, worker independence, config checks before work."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from datagen_helpers import make_dataset, tiny_config, tree_bytes

from packlab.core.errors import ConfigError
from packlab.datagen import engine
from packlab.datagen.config import DatasetConfig
from packlab.datagen.engine import RunOptions, generate_dataset, plan_shards


def test_same_seed_gives_byte_identical_output(tiny_dataset, tmp_path):
    make_dataset(tmp_path / "again")
    assert tree_bytes(tmp_path / "again") == tree_bytes(tiny_dataset)


def test_different_seed_gives_different_data(tiny_dataset, tmp_path):
    make_dataset(tmp_path / "other", tiny_config(seed=8))
    a, b = tree_bytes(tiny_dataset), tree_bytes(tmp_path / "other")
    assert a["data/episodes/easy-00000.parquet"] != b["data/episodes/easy-00000.parquet"]


def test_counts_and_markers(tiny_dataset):
    info = json.loads((tiny_dataset / "meta/info.json").read_text())
    assert info["counts"]["episodes"] == 10
    assert info["counts"]["shards"] == len(plan_shards(tiny_config())) == 3 + 2 + 1
    assert {d: v["episodes"] for d, v in info["counts"]["by_difficulty"].items()} == {
        "easy": 5,
        "medium": 3,
        "hard": 2,
    }
    assert info["generator_config"]["seed"] == 7
    assert len(list((tiny_dataset / "meta/shards").glob("*.json"))) == 6


def test_resume_after_an_interrupted_shard(tiny_dataset, tmp_path):
    out = tmp_path / "resumed"
    cfg = tiny_config()
    calls = {"n": 0}
    real = engine.run_shard

    def dying_run_shard(cfg_, spec, root, report=None):
        # The third shard dies half-way: its first slot's images are written, nothing else.
        calls["n"] += 1
        if calls["n"] == 3:

            def report_then_die(kept, rejected):
                raise KeyboardInterrupt

            return real(cfg_, spec, root, report_then_die)
        return real(cfg_, spec, root, report)

    engine.run_shard = dying_run_shard
    try:
        with pytest.raises(KeyboardInterrupt):
            make_dataset(out, cfg)
    finally:
        engine.run_shard = real
    assert len(list((out / "meta/shards").glob("*.json"))) == 2
    assert not (out / "meta/info.json").exists()
    assert [p.name for p in (out / "images").rglob(".*.tmp")] == [
        ".medium-00001.tmp"
    ]  # staged, not published
    assert not (out / "images/medium/medium-00001").exists()
    # A killed writer can leave a temporary file; it is never taken for data and is cleaned up.
    (out / "data/steps/.hard-00000.parquet.x.tmp").write_bytes(b"partial")
    done_before = {p.name: p.stat().st_mtime_ns for p in (out / "data/steps").glob("*.parquet")}

    ran = []
    engine.run_shard = lambda c, spec, root, report=None: (
        ran.append(spec.name) or real(c, spec, root, report)
    )
    try:
        make_dataset(out, cfg)
    finally:
        engine.run_shard = real
    assert len(ran) == 4  # the two finished shards were not redone
    for name, mtime in done_before.items():
        if name.removesuffix(".parquet") not in ran:
            assert (out / "data/steps" / name).stat().st_mtime_ns == mtime
    assert tree_bytes(out) == tree_bytes(tiny_dataset)


def test_rerun_of_a_finished_dataset_does_nothing(tiny_dataset, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(tiny_dataset, out)
    real, ran = engine.run_shard, []
    engine.run_shard = lambda *a, **k: ran.append(a) or real(*a, **k)
    try:
        make_dataset(out)
    finally:
        engine.run_shard = real
    assert ran == [] and tree_bytes(out) == tree_bytes(tiny_dataset)


def test_process_pool_output_equals_serial(tiny_dataset, tmp_path):
    out = tmp_path / "pool"
    generate_dataset(
        tiny_config(), RunOptions(str(out), workers=2, executor="process", progress=False)
    )
    assert tree_bytes(out) == tree_bytes(tiny_dataset)


def test_resume_with_another_config_is_refused(tiny_dataset, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(tiny_dataset, out)
    with pytest.raises(ConfigError, match="different config.*seed"):
        make_dataset(out, tiny_config(seed=99))


def test_foreign_directory_is_refused(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not an empty directory"):
        make_dataset(tmp_path)


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"episodes": (5, -1, 2)}, "episodes for medium = -1"),
        ({"difficulties": ("easy", "extreme", "hard")}, "difficulty = 'extreme'"),
        ({"episodes": (5, 3)}, "one count per difficulty"),
        ({"seed": -4}, "seed = -4"),
        ({"shard_size": 0}, "shard_size"),
        ({"sft": "all"}, "sft = 'all'"),
    ],
)
def test_bad_configs_fail_with_one_line(fields, message):
    with pytest.raises(ConfigError, match=message) as err:
        tiny_config(**fields)
    assert "\n" not in str(err.value)


def test_unwritable_output_fails_before_any_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="cannot write there"):
        make_dataset(blocker / "dataset")


def test_bad_run_options():
    with pytest.raises(ConfigError, match="executor"):
        RunOptions("x", executor="slurm")
    with pytest.raises(ConfigError, match="workers"):
        RunOptions("x", workers=-1)


def test_recipe_resolves_to_the_published_mix():
    cfg = DatasetConfig.from_recipe("packdata-20k")
    assert dict(zip(cfg.difficulties, cfg.episodes)) == {"easy": 9000, "medium": 7000, "hard": 4000}
    assert cfg.total_episodes == 20000 and cfg.recipe == "packdata-20k"
    assert DatasetConfig.from_recipe("packdata-20k", seed=3).seed == 3


def test_empty_difficulty_count_is_allowed(tmp_path):
    info = make_dataset(tmp_path / "d", tiny_config(episodes=(2, 0, 0)))
    assert info.counts.episodes == 2
    assert Path(tmp_path / "d/data/steps/easy-00000.parquet").exists()
