"""scripts/robustness_table.py on real (tiny) runs: exact baselines and runs without perception
must print a table, not a traceback."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from bench_helpers import run_tiny, write_tiny_suite

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "robustness_table.py"


def _script():
    spec = importlib.util.spec_from_file_location("robustness_table", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("robustness")
    suite = write_tiny_suite(root)
    out = {}
    for name, kw in {
        "exact": {},
        "seen": {"observation": "perceived", "noise": "none"},
    }.items():
        run_tiny(suite, root / name, policies=("dblf", "ffp"), **kw)
        out[name] = root / name
    return out


def test_an_exact_run_as_the_mode_prints_a_table_and_says_there_is_no_perception(runs, capsys):
    code = _script().main([str(runs["exact"]), f"same={runs['exact']}"])
    printed = capsys.readouterr().out
    assert code == 0
    assert "| DBLF |" in printed and "| FFP |" in printed
    assert "no perception in this run" in printed
    assert "re-scan" not in printed  # no rate of zero scans


def test_a_perceived_mode_gets_its_perception_errors(runs, capsys):
    code = _script().main([str(runs["exact"]), f"seen={runs['seen']}"])
    printed = capsys.readouterr().out
    assert code == 0
    assert "heightmap MAE mm (per scan)" in printed
    assert "steps that needed a re-scan:" in printed
    assert "no perception" not in printed


def test_a_missing_run_is_one_line_and_exit_2(runs, tmp_path, capsys):
    code = _script().main([str(runs["exact"]), f"x={tmp_path / 'nowhere'}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "nowhere" in err[0] and "episodes.jsonl" in err[0]
