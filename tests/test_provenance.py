"""Model cards record how a model was made without naming a machine's paths."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from packlab.bench.suites import load_suite
from packlab.policies.provenance import (
    card_path,
    card_source,
    dir_sha256,
    file_sha256,
    git_state,
    init_record,
    provenance,
    selection_record,
)
from packlab.rl.card import AgentCard, read_card, write_card

ROOT = Path(__file__).resolve().parents[1]


def test_card_paths_are_relative_to_the_run_or_names_only(tmp_path):
    run = tmp_path / "runs" / "student" / "irbpp-ppo-s0"
    assert card_path(run / "best" / "model.zip", run) == "best/model.zip"
    assert card_path(tmp_path / "runs" / "student" / "train-cases.jsonl", run) == (
        "train-cases.jsonl"
    )
    assert card_path("/home/someone/x/states.jsonl", run) == "states.jsonl"
    assert card_source("suite:packlab-bench-v1", run) == "suite:packlab-bench-v1"
    assert card_source("recipe:packdata-20k", run) == "recipe:packdata-20k"


def test_the_commit_is_this_checkout_s_and_none_outside_one(tmp_path):
    commit, dirty = git_state(ROOT)
    assert commit is not None and len(commit) == 40 and isinstance(dirty, bool)
    assert git_state(tmp_path) == (None, None)


def test_the_selection_set_is_recorded_by_content_and_size():
    cases = load_suite("packlab-bench-v1")[:6]
    renamed = [dataclasses.replace(c, episode_id=f"x{i}", seed=i) for i, c in enumerate(cases)]
    a = selection_record(cases, "best held-out")
    assert a == selection_record(list(reversed(renamed)), "best held-out")
    assert a["n"] == 6 and len(a["sha256"]) == 64 and a["rule"] == "best held-out"


def test_the_init_checkpoint_is_a_name_and_a_digest(tmp_path):
    init = tmp_path / "elsewhere" / "irbpp-im-s0"
    init.mkdir(parents=True)
    (init / "model.zip").write_bytes(b"weights")
    record = init_record(init, tmp_path / "run")
    assert record == {"path": "irbpp-im-s0", "sha256": dir_sha256(init)}
    (init / "model.zip").write_bytes(b"other weights")
    assert init_record(init, tmp_path / "run")["sha256"] != record["sha256"]  # type: ignore[index]
    assert init_record(None, tmp_path) is None


def test_an_rl_card_holds_the_fields_and_no_absolute_path(tmp_path):
    states = tmp_path / "data" / "states.jsonl"
    states.parent.mkdir()
    states.write_text("{}\n")
    run = tmp_path / "run"
    prov = provenance(run, 7, states=[states], selection=selection_record([], "none"))
    card = AgentCard("irbpp", 16, "overall", cases=card_source(str(tmp_path / "c.jsonl"), run),
                     cases_sha256="ab" * 32, **prov)  # fmt: skip
    run.mkdir()
    write_card(run, card)
    text = (run / "card.json").read_text()
    assert str(tmp_path) not in text and "runs/" not in text
    back = read_card(run)
    assert back == card and back.seed == 7 and back.cases == "c.jsonl"
    assert back.states == [{"path": "states.jsonl", "sha256": file_sha256(states)}]
    assert {"seed", "commit", "dirty", "init", "states", "selection"} <= set(json.loads(text))


def test_a_card_without_the_fields_still_reads(tmp_path):
    # Cards written before the provenance fields existed lack them: they read with them empty.
    shipped = json.loads((ROOT / "src/packlab/data/models/irbpp/card.json").read_text())
    fields = ("seed", "commit", "dirty", "init", "states", "selection")
    (tmp_path / "card.json").write_text(
        json.dumps({k: v for k, v in shipped.items() if k not in fields})
    )
    card = read_card(tmp_path)
    assert card.seed is None and card.init is None and card.states == []


@pytest.mark.parametrize("agent", ["irbpp", "tapnet"])
def test_the_shipped_cards_say_how_they_were_made(agent):
    # Seed, commit, init checkpoint, cases' digest and selection set; no scratch path.
    text = (ROOT / "src/packlab/data/models" / agent / "card.json").read_text()
    card = read_card(ROOT / "src/packlab/data/models" / agent)
    assert card.seed is not None and card.commit and card.init and card.init["sha256"]
    assert len(card.cases_sha256) == 64 and card.selection and card.selection["sha256"]
    assert "runs/" not in text and "/work" not in text and "/tmp" not in text


def test_the_shipped_pointer_model_s_card_says_how_it_was_made():
    # A clean commit, every input by name and sha256 (the states and the cases each
    # state file was collected on), no scratch path.
    text = (ROOT / "src/packlab/data/models/vlm-small/packlab_model.json").read_text()
    card = json.loads(text)
    assert card["dirty"] is False and len(card["commit"]) == 40 and card["seed"] is not None
    assert card["states"] and all(len(s["sha256"]) == 64 for s in card["states"])
    cases = [card["cases"], *card.get("states_cases", [])]
    assert len(cases) >= 2 and all(len(c["sha256"]) == 64 for c in cases)
    assert "runs/" not in text and "/work" not in text and "/tmp" not in text
