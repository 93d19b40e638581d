"""``packlab inspect-data``'s token figures of the SFT export, on the tiny generated dataset."""

from __future__ import annotations

import json
import shutil

import pytest

pytest.importorskip("transformers", reason="token figures need the vlm extra")
pytest.importorskip("torch", reason="token figures need the vlm extra")

from packlab.cli import inspect_data_run
from packlab.cli.main import main
from packlab.datagen.sft_export import export_sft
from packlab.vlm.data import sft_tokens


@pytest.fixture(scope="module")
def counter():
    return sft_tokens.project_counter()


def _inspect_json(capsys, *argv: str) -> dict:
    assert main(["inspect-data", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)["sft_tokens"]


def test_whole_episodes_are_encoded_once(tiny_dataset, capsys, counter):
    figures = _inspect_json(capsys, str(tiny_dataset))
    assert not figures["sampled"] and figures["tokenizer"] == "packlab-bpe-v1"
    assert figures["image_tokens"] == {"64x64": 4}  # 64 px / 32 px per merged token, squared
    groups = figures["groups"]
    assert list(groups) == ["easy", "medium", "hard", "all"]
    assert [groups[d]["conversations"] for d in ("easy", "medium", "hard")] == [5, 3, 2]
    files = sft_tokens.export_files(tiny_dataset)
    episodes = {r["episode_id"] for r in sft_tokens.read_index(files)}
    rows = sft_tokens.read_conversations(files, episodes)
    whole = groups["all"]
    assert whole["labelled_actions"] == sum(sft_tokens._n_actions(c) for c in rows)
    assert whole["tokens"] == sum(counter.count(c) for c in rows) == whole["estimated_tokens"]
    assert all(g["passes"] == 1.0 for g in groups.values())
    assert main(["inspect-data", str(tiny_dataset)]) == 0
    text = capsys.readouterr().out
    assert "SFT export tokens" in text and "all 10 conversations measured" in text


def test_a_sample_takes_whole_episodes_and_says_so(tiny_dataset, capsys):
    figures = _inspect_json(capsys, str(tiny_dataset), "--token-sample", "3")
    whole = figures["groups"]["all"]
    assert figures["sampled"] and 1 <= whole["sampled_conversations"] <= 3
    assert whole["conversations"] == 10 and whole["estimated_tokens"] > whole["tokens"]
    assert main(["inspect-data", str(tiny_dataset), "--token-sample", "3"]) == 0
    assert "a sample of" in capsys.readouterr().out
    assert main(["inspect-data", str(tiny_dataset), "--token-sample", "0"]) == 0
    assert "SFT export tokens" not in capsys.readouterr().out


def test_windows_repeat_the_system_turn(tiny_dataset, tmp_path, capsys):
    root = tmp_path / "windows"
    shutil.copytree(tiny_dataset, root, ignore=shutil.ignore_patterns("sft"))
    export_sft(root, window=2)
    groups = _inspect_json(capsys, str(root))["groups"]
    whole = _inspect_json(capsys, str(tiny_dataset))["groups"]
    assert groups["all"]["labelled_actions"] == whole["all"]["labelled_actions"]
    assert groups["all"]["conversations"] > whole["all"]["conversations"]
    assert groups["all"]["episode_tokens"] == whole["all"]["tokens"]  # the windows joined back
    assert groups["all"]["passes"] > 1.0


def test_turn_ends_are_the_prefixes_tokens(tiny_dataset, counter):
    files = sft_tokens.export_files(tiny_dataset)
    index = sft_tokens.read_index(files)
    longest = max(index, key=lambda r: r["n_steps"])["episode_id"]
    (conv,) = sft_tokens.read_conversations(files, {longest})
    ends = counter.turn_end_tokens(conv)
    answers = [i + 1 for i, m in enumerate(conv.messages) if m["role"] == "assistant"]
    assert len(ends) == len(answers) > 1
    for k, end in zip(answers, ends):
        images = sum(c["type"] == "image" for m in conv.messages[:k] for c in m["content"])
        prefix = sft_tokens.Conversation(
            conv.episode_id, conv.difficulty, 0, conv.messages[:k], conv.image_sizes[:images]
        )
        assert end == counter.count(prefix)
    assert ends[-1] == counter.count(conv)


def test_no_vlm_extra_is_one_line(tiny_dataset, capsys, monkeypatch):
    monkeypatch.setattr(inspect_data_run, "TOKENS_MODULE", "packlab_no_such_module")
    assert main(["inspect-data", str(tiny_dataset)]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "SFT export tokens" in ln]
    assert len(lines) == 1 and "not measured" in lines[0] and "vlm extra" in lines[0]
