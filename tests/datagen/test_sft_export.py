"""The SFT export: one conversation per episode, in the formats trainers read as they are."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections import Counter

import pyarrow.parquet as pq
import pytest

from packlab.core.errors import ConfigError
from packlab.core.types import Action
from packlab.datagen.sft_export import HF_SCHEMA, VERL_SCHEMA, export_sft
from packlab.vlm.prompt.render import PROMPT_VERSION


def _steps(root):
    return pq.read_table(root / "data/steps").to_pylist()


def _rows(files):
    return [r for f in files for r in pq.read_table(f).to_pylist()]


def test_generate_writes_one_conversation_per_episode(tiny_dataset):
    files = sorted((tiny_dataset / "sft").glob("*.parquet"))
    steps = _steps(tiny_dataset)
    rows = _rows(files)
    n_episodes = len({s["episode_id"] for s in steps})
    assert len(rows) == n_episodes and not list((tiny_dataset / "sft").glob("*.jsonl"))
    answers = {(s["episode_id"], s["step_index"]): s["action_text"] for s in steps}
    for row in rows:
        msgs = row["messages"]
        assert msgs[0]["role"] == "system"
        roles = [m["role"] for m in msgs[1:]]
        assert roles == ["user", "assistant"] * row["n_steps"]
        targets = [m["content"][0]["text"] for m in msgs if m["role"] == "assistant"]
        expected = [
            answers[(row["episode_id"], row["first_step"] + i)] for i in range(len(targets))
        ]
        assert targets == expected
        Action(**json.loads(targets[-1]))
        # one image per user turn, in order, embedded with its relative path
        placeholders = sum(c["type"] == "image" for m in msgs for c in m["content"])
        assert placeholders == len(row["images"]) == row["n_steps"]
        for i, im in enumerate(row["images"]):
            assert im["bytes"] == (tiny_dataset / im["path"]).read_bytes()
            assert im["path"].endswith(f"{row['first_step'] + i:03d}.png")
        assert row["prompt_version"] == PROMPT_VERSION


def test_size_is_linear_in_steps(tiny_dataset):
    """Each step's text appears once (the per-step layout repeated the whole history)."""
    rows = _rows(sorted((tiny_dataset / "sft").glob("*.parquet")))
    for row in rows:
        user_texts = [m["content"][-1]["text"] for m in row["messages"] if m["role"] == "user"]
        assert len(user_texts) == len(set(user_texts)) == row["n_steps"]


def test_datasets_reads_the_export_as_it_is(tiny_dataset):
    datasets = pytest.importorskip("datasets")
    ds = datasets.load_dataset(str(tiny_dataset), "sft", split="train")
    row = ds[0]
    assert row["images"] and all(hasattr(im, "size") for im in row["images"])  # PIL images
    assert row["images"][0].size == (64, 64)
    assert ds.features["images"].feature.__class__.__name__ == "Image"
    schema = pq.read_schema(next((tiny_dataset / "sft").glob("*.parquet")))
    assert schema.metadata[b"huggingface"] == HF_SCHEMA.metadata[b"huggingface"]


@pytest.mark.parametrize("window", [1, 2, 3])
def test_windows_make_every_step_a_target_once(tiny_dataset, tmp_path, window):
    files = export_sft(tiny_dataset, "hf", window=window, out=tmp_path / "w")
    rows = _rows(files)
    targets = Counter()
    for row in rows:
        assert 1 <= row["n_steps"] <= window
        for i in range(row["n_steps"]):
            targets[(row["episode_id"], row["first_step"] + i)] += 1
        # a window's history starts at its own first step
        first_user = row["messages"][1]["content"][-1]["text"]
        assert first_user.startswith(f"Step {row['first_step'] + 1}.")
    steps = {(s["episode_id"], s["step_index"]) for s in _steps(tiny_dataset)}
    assert set(targets) == steps and set(targets.values()) == {1}


def test_verl_export_has_the_reference_fields_and_types(tiny_dataset, tmp_path):
    files = export_sft(tiny_dataset, "verl", out=tmp_path / "verl")
    table = pq.read_table(files[0])
    assert table.schema.names == VERL_SCHEMA.names
    assert [f.type.id for f in table.schema] == [f.type.id for f in VERL_SCHEMA]
    for row in _rows(files):
        assert row["data_source"] == "packing_sft" and row["enable_thinking"] is False
        assert isinstance(row["prompt_template_id"], str)
        assert all(isinstance(m["content"], str) for m in row["messages"])
        placeholders = sum(m["content"].count("<image>") for m in row["messages"])
        assert placeholders == len(row["images"]) == row["extra_info"]["num_steps"]
        for im in row["images"]:
            assert set(im) == {"image"} and (tiny_dataset / im["image"]).is_file()
        info = row["extra_info"]
        assert info["row_step_index"] is None and info["image_paths"] == [
            im["image"] for im in row["images"]
        ]
        assert info["prompt_view"] == {"history_mode": "full", "height_map_mode": "image"}


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "packlab.cli.main", *args],
        check=False,
        capture_output=True,
        text=True,
    )


def test_bad_format_is_one_line_and_exit_2(tiny_dataset, tmp_path):
    proc = _cli("export", "sft", str(tiny_dataset), "--format", "jsonl", "--out", str(tmp_path))
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "format = 'jsonl'" in proc.stderr
    assert not list(tmp_path.iterdir())


def test_missing_image_is_one_line_and_keeps_what_was_written(tiny_dataset, tmp_path):
    data = tmp_path / "copy"
    shutil.copytree(tiny_dataset, data)
    out = tmp_path / "out"
    export_sft(data, "verl", out=out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    victim = next(iter(sorted((data / "images").rglob("*.png"))))
    victim.unlink()
    for form in ("verl", "hf"):
        proc = _cli("export", "sft", str(data), "--format", form, "--out", str(out))
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.strip().count("\n") == 0 and victim.name in proc.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    with pytest.raises(ConfigError, match="image missing"):
        export_sft(data, "hf", out=tmp_path / "other")
