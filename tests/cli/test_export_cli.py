"""`packlab export onnx DIR` through the CLI: which exporter a directory gets, the one-line
errors, and an agent exported and then played under the default (ONNX) runtime."""

from __future__ import annotations

import json
import shutil
import sys

import pytest

from packlab.cases import load_cases
from packlab.cli.export import TIE_TOLERANCE, check_summary
from packlab.cli.main import main
from packlab.core.errors import EXIT_USAGE, ConfigError
from packlab.policies import make_policy
from packlab.policies.onnx_model import CARD_FILE
from packlab.rl.policy import SHIPPED_MODELS
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import run_episode


def _error(capsys: pytest.CaptureFixture[str]) -> str:
    return capsys.readouterr().err.strip()


def test_a_path_that_is_no_directory_is_one_line(tmp_path, capsys):
    assert main(["export", "onnx", str(tmp_path / "nope")]) == EXIT_USAGE
    assert "not a directory" in _error(capsys)


def test_a_directory_of_no_known_model_says_what_it_looked_for(tmp_path, capsys):
    assert main(["export", "onnx", str(tmp_path)]) == EXIT_USAGE
    err = _error(capsys)
    assert "card.json" in err and "packlab_model.json" in err


def test_a_text_answer_vlm_is_refused_with_the_field(tmp_path, capsys):
    (tmp_path / "packlab_model.json").write_text(json.dumps({"action_format": "json"}))
    assert main(["export", "onnx", str(tmp_path)]) == EXIT_USAGE
    assert "field 'action_format' = 'json'" in _error(capsys)


def test_negative_check_states_is_refused(tmp_path, capsys):
    assert main(["export", "onnx", str(tmp_path), "--check-states", "-1"]) == EXIT_USAGE
    assert "check-states = -1" in _error(capsys)


def test_a_missing_extra_is_named_with_the_install_command(tmp_path, capsys, monkeypatch):
    shutil.copy(SHIPPED_MODELS / "irbpp" / "card.json", tmp_path / "card.json")
    monkeypatch.delitem(sys.modules, "packlab.rl.onnx_export", raising=False)
    monkeypatch.setitem(sys.modules, "torch", None)  # `import torch` fails as if not installed
    assert main(["export", "onnx", str(tmp_path)]) == EXIT_USAGE
    err = _error(capsys)
    assert "needs the rl extra (torch missing)" in err and "pip install -e '.[rl]'" in err


def test_an_exported_agent_plays_under_the_default_runtime(tmp_path, capsys):
    pytest.importorskip("sb3_contrib")
    agent = tmp_path / "agent"
    agent.mkdir()
    for name in ("model.zip", "card.json"):  # the checkpoint without its ONNX export
        shutil.copy(SHIPPED_MODELS / "irbpp" / name, agent / name)
    with pytest.raises(ConfigError, match="packlab export onnx"):
        make_policy("irbpp", model=str(agent)).reset(load_cases(demo_cases_path())[0], 0)

    assert main(["export", "onnx", str(agent), "--check-states", "8"]) == 0
    out = capsys.readouterr().out
    assert f"card: {agent / CARD_FILE}" in out and (agent / CARD_FILE).is_file()
    # The check it ran is said, not only written into onnx.json.
    check = out.strip().splitlines()[-1]
    assert check.startswith("check: torch vs ONNX Runtime, the greedy row on 8 generated states")
    assert "same row on all 8; max |logit difference|" in check and check.endswith(": pass")
    case = load_cases(demo_cases_path())[0]
    mine = run_episode(case, make_policy("irbpp", model=str(agent)), seed=0, backend="geometric")
    shipped = run_episode(case, make_policy("irbpp"), seed=0, backend="geometric")
    # The same weights, re-exported: the same actions at every step.
    assert [s.action for s in mine.steps] == [s.action for s in shipped.steps]
    assert mine.metrics.overall == shipped.metrics.overall


def test_the_pointer_check_line_names_ties_and_the_largest_difference():
    extra = {"check": {"states": 64, "argmax_equal": 63, "ties": 1, "max_abs_diff": 3.1e-6}}
    assert check_summary("pointer", extra) == (
        "check: torch vs ONNX Runtime, the listed pick on 64 generated states: same pick on 63, "
        "1 picks between placements tied within 0.0001; max |score difference| 3.10e-06: pass"
    )
    assert check_summary("pointer", {"check": {"states": 0}}).startswith("check: skipped")
    assert check_summary("rl-agent", {"check_states": 0}).startswith("check: skipped")


def test_the_tie_tolerance_is_the_exporters():
    pytest.importorskip("torch")
    from packlab.vlm.candidate.onnx_export import TIE_TOLERANCE as EXPORTER_TOLERANCE

    assert TIE_TOLERANCE == EXPORTER_TOLERANCE
