"""Labelled states are checked by their cases' content: every row carries its case's
fingerprint; a row of a suite case, of a case not given, of another case under the same id, or
without the field is refused by ``train rl-imitate``, ``train candidate`` and the scripts."""

from __future__ import annotations

import dataclasses
import runpy
import sys
from pathlib import Path

import msgspec
import pytest

from packlab.bench.suites import load_suite
from packlab.cases import save_cases
from packlab.cases.fingerprint import case_fingerprint
from packlab.cli.main import main
from packlab.core.errors import ConfigError
from packlab.datagen import generate_cases
from packlab.vlm.candidate.collect import collect
from packlab.vlm.candidate.states import append_states, read_states
from packlab.vlm.candidate.states_guard import checked_states, require_training_states

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def train_cases():
    return generate_cases("easy", 2, 4402, False, domain="train")


@pytest.fixture(scope="module")
def states(train_cases, tmp_path_factory):
    out = tmp_path_factory.mktemp("states") / "states.jsonl"
    collect(train_cases, out, "sdf", "teacher", workers=1, progress=False)
    return out


def test_collected_states_pass_with_and_without_their_cases(states, train_cases):
    rows = checked_states(states, train_cases)
    assert rows and all(s.case_sha256 for s in rows)
    assert checked_states(states) == rows


def test_states_of_a_renamed_suite_case_are_refused(tmp_path):
    case = load_suite("packlab-bench-v1")[3]
    renamed = dataclasses.replace(case, episode_id="train-s1-easy-00000", seed=17)
    out = tmp_path / "s.jsonl"
    collect([renamed], out, "sdf", "teacher", workers=1, progress=False)
    with pytest.raises(ConfigError, match=r"packlab-bench-v1 case 'bench-easy-00003'"):
        checked_states(out)


def test_states_of_other_cases_under_the_same_ids_are_refused(states, train_cases):
    """Selection cases (seed 7413) renamed to the ids of training cases (seed 4402): the ids
    match, and the content still tells them apart."""
    other = generate_cases("easy", 2, 7413, False, domain="train")
    same_ids = [dataclasses.replace(o, episode_id=t.episode_id) for o, t in zip(other, train_cases)]
    with pytest.raises(ConfigError, match="stale or mismatched states"):
        checked_states(states, same_ids)
    with pytest.raises(ConfigError, match="not among the given cases"):
        checked_states(states, other)


def test_a_file_without_case_hashes_is_refused(states, train_cases, tmp_path):
    old = tmp_path / "old.jsonl"
    rows = [msgspec.structs.replace(s, format="packlab-states-2", case_sha256="")
            for s in read_states(states)]  # fmt: skip
    append_states(old, rows)
    with pytest.raises(ConfigError, match="no case_sha256.*collect the states again"):
        require_training_states([old], train_cases)


def test_train_candidate_refuses_stale_states_in_its_run_directory(states, tmp_path, capsys):
    cases = save_cases(generate_cases("easy", 2, 7413, False, domain="train"), tmp_path / "c.jsonl")
    run = tmp_path / "run"
    (run / "r0").mkdir(parents=True)
    (run / "r0" / "states.jsonl").write_bytes(states.read_bytes())
    assert main(["train", "candidate", "--cases", str(cases), "--out", str(run)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not among the given cases" in err


def test_the_continuation_script_checks_its_states(states, tmp_path, monkeypatch):
    cases = save_cases(generate_cases("easy", 2, 7413, False, domain="train"), tmp_path / "c.jsonl")
    argv = ["x", "--model", "m", "--states", str(states), "--cases", str(cases), "--out", "o"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(ConfigError, match="not among the given cases"):
        runpy.run_path(str(ROOT / "scripts" / "vlm_continue.py"), run_name="__main__")


def test_rl_imitate_refuses_states_of_other_cases(states, tmp_path, capsys):
    cases = save_cases(generate_cases("easy", 2, 7413, False, domain="train"), tmp_path / "c.jsonl")
    argv = ["train", "rl-imitate", "--states", str(states), "--cases", str(cases)]
    assert main([*argv, "--out", str(tmp_path / "m")]) == 2
    assert "not among the given cases" in capsys.readouterr().err


def test_a_state_row_names_its_case_by_content(train_cases, states):
    prints = {c.episode_id: case_fingerprint(c) for c in train_cases}
    assert {s.case_sha256 for s in read_states(states)} == set(prints.values())
