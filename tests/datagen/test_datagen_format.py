"""The dataset on disk: parquet schemas, images by relative path, SFT export, datasets loading."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from packlab.cases import case_from_dict
from packlab.core.types import Action
from packlab.datagen.format import EPISODE_SCHEMA, STEP_SCHEMA
from packlab.sim.raster import heightmap_to_rgb
from packlab.vlm.prompt.render import action_text


def _steps(root):
    return pq.read_table(sorted((root / "data/steps").glob("*.parquet"))).to_pylist()


def test_shards_share_one_schema(tiny_dataset):
    for path in (tiny_dataset / "data/steps").glob("*.parquet"):
        assert pq.read_schema(path).remove_metadata() == STEP_SCHEMA
    for path in (tiny_dataset / "data/episodes").glob("*.parquet"):
        assert pq.read_schema(path).remove_metadata() == EPISODE_SCHEMA


def test_steps_replay_their_episode(tiny_dataset):
    episodes = {
        r["episode_id"]: r
        for r in pq.read_table(
            sorted((tiny_dataset / "data/episodes").glob("*.parquet"))
        ).to_pylist()
    }
    rows = _steps(tiny_dataset)
    by_episode = {}
    for r in rows:
        by_episode.setdefault(r["episode_id"], []).append(r)
    assert set(by_episode) == set(episodes)
    for eid, steps in by_episode.items():
        case = case_from_dict(json.loads(episodes[eid]["case_json"]))
        plan = {p.internal_id: p for p in case.gt_plan}
        assert [s["step_index"] for s in steps] == list(range(len(case.objects)))
        assert episodes[eid]["overall"] == 1.0
        for s in steps:
            # object_id indexes the buffer as shown that step, and the action is the plan's,
            # its rotation referring to the sides as shown (longer first: the plan's turned
            # where the catalogue lists the shorter side first).
            placed = s["shown"][s["action"]["object_id"]]
            assert placed["internal_id"] == s["internal_id"]
            p = plan[s["internal_id"]]
            l, w, _ = case.box_by_id(s["internal_id"]).size_mm
            assert (s["action"]["x"], s["action"]["y"], s["action"]["rotation"]) == (
                p.x,
                p.y,
                p.rotation ^ int(l < w),
            )
            assert len(s["shown"]) == min(case.buffer_size, s["remaining"])
            assert json.loads(s["action_text"]) == s["action"]
            assert s["action_text"] == action_text(Action(**s["action"]))


def test_images_are_the_rasterised_heightmaps(tiny_dataset):
    rows = _steps(tiny_dataset)
    for r in rows[::7]:
        from packlab.core.types import Container

        c = Container(tuple(round(v * 10) for v in r["container_size_cm"]))
        hm = np.array(r["heightmap_mm"], dtype=np.int32)
        assert not (r["image"].startswith("/") or ".." in r["image"])
        img = np.asarray(Image.open(tiny_dataset / r["image"]).convert("RGB"))
        assert (img == heightmap_to_rgb(hm, c, size=64)).all()


def test_dataset_loads_with_hf_datasets(tiny_dataset):
    datasets = pytest.importorskip("datasets")
    steps = datasets.load_dataset(
        "parquet",
        data_files=str(tiny_dataset / "data/steps/*.parquet"),
        split="train",
        cache_dir=str(tiny_dataset.parent / "hf-cache"),
    )
    assert (
        steps.num_rows
        == json.loads((tiny_dataset / "meta/info.json").read_text())["counts"]["steps"]
    )
    row = steps[0]
    assert (
        set(row["action"]) == {"object_id", "x", "y", "rotation"}
        and (tiny_dataset / row["image"]).is_file()
    )
    episodes = datasets.load_dataset(
        str(tiny_dataset),
        "episodes",
        split="train",
        cache_dir=str(tiny_dataset.parent / "hf-cache"),
    )
    assert episodes.num_rows == 10
