"""``packlab train candidate`` end to end on a handful of generated cases (tiny model, CPU):
both rounds run, the final model plays through the ``vlm`` policy, and a rerun resumes (changes
nothing)."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("transformers")

from packlab.bench.suites import resolve_cases
from packlab.cli.main import main
from packlab.policies.registry import make_policy
from packlab.sim.episode import run_episode
from packlab.vlm.candidate.states import read_states

pytestmark = pytest.mark.torch


def test_train_candidate_runs_both_rounds_and_resumes(tmp_path, capsys):
    cases = tmp_path / "cases"
    argv = ["generate", "--difficulty", "easy,medium", "--episodes", "3,3", "--seed", "5"]
    argv += ["--validation", "geometric", "--sft", "none", "--out", str(cases), "--no-progress"]
    assert main(argv) == 0
    run = tmp_path / "run"
    train = ["train", "candidate", "--cases", str(cases), "--out", str(run), "--teacher", "sdf"]
    train += ["--rounds", "1", "--cases-per-round", "2", "--eval-cases", "1", "--steps", "3"]
    train += ["--round-steps", "2", "--workers", "1", "--model", "tiny:qwen3_vl:tiny"]
    assert main(train) == 0
    r1 = list(read_states(run / "r1" / "states.jsonl"))
    assert r1 and {s.source for s in r1} == {"student-r1"} and {s.teacher for s in r1} == {"sdf"}
    assert (run / "r1" / "train" / "curves.png").is_file()
    card = json.loads((run / "final" / "packlab_model.json").read_text())
    assert card["teacher"] == "sdf" and card["dagger_round"] == 1 and card["trained_steps"] == 2
    assert card["map"] == "image"  # the default: the heightmap through the vision tower
    before = (run / "final" / "pointer_head.safetensors").read_bytes()
    assert main(train) == 0  # everything done: nothing is collected or trained again
    assert len(list(read_states(run / "r1" / "states.jsonl"))) == len(r1)
    assert (run / "final" / "pointer_head.safetensors").read_bytes() == before
    case = resolve_cases(str(cases)).cases[0]
    result = run_episode(case, make_policy("vlm", model=str(run / "final")), 0, "geometric")
    assert len(result.steps) == len(case.objects)


def test_train_candidate_refuses_an_unknown_map(tmp_path, capsys):
    argv = ["train", "candidate", "--cases", str(tmp_path), "--out", str(tmp_path / "run")]
    with pytest.raises(SystemExit):
        main([*argv, "--map", "picture"])
    assert "--map" in capsys.readouterr().err
