"""Every example under examples/ runs, on a case or two of the geometric backend.

``examples/my_policy`` is "installed" the way ``pip install`` would leave it, without pip: its
package is copied into a directory on ``sys.path`` beside a ``*.dist-info`` whose
``entry_points.txt`` is written from the example's own ``pyproject.toml``, so a wrong group or
factory path in that file fails here. The scripts run in a fresh interpreter, as a user runs
them.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from packlab.cases import load_cases
from packlab.cli.main import main
from packlab.policies import make_policy, registry
from packlab.policies.registry import ENTRY_POINT_GROUP
from packlab.sim.env import demo_cases_path
from packlab.sim.episode import run_episode

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MY_POLICY = EXAMPLES / "my_policy"
MY_POLICY_NAME = "my-policy"


def _run(script: Path, *args: str, timeout: float = 120) -> str:
    """``python SCRIPT ARGS`` in a fresh interpreter; its stdout (fails on a non-zero exit)."""
    done = subprocess.run(
        [sys.executable, str(script), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


@pytest.mark.parametrize("name", ["my_policy", "robot_cell_onnx", "sb3_gymnasium"])
def test_every_example_has_a_readme(name):
    readme = EXAMPLES / name / "README.md"
    assert readme.is_file() and readme.read_text().startswith("# ")


@pytest.fixture
def my_policy_installed(tmp_path, monkeypatch):
    """examples/my_policy as pip would install it, entry point from its pyproject.toml."""
    project = tomllib.loads((MY_POLICY / "pyproject.toml").read_text())["project"]
    group = project["entry-points"][ENTRY_POINT_GROUP]
    site = tmp_path / "site"
    dist_info = site / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    dist_info.mkdir(parents=True)
    (dist_info / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n"
    )
    lines = [f"{name} = {target}" for name, target in group.items()]
    (dist_info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\n" + "\n".join(lines))
    shutil.copytree(MY_POLICY / "my_policy", site / "my_policy")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(registry, "_LOADED", {})  # the factory is not kept past this test
    yield project
    sys.modules.pop("my_policy", None)


def test_my_policy_declares_itself_in_packlabs_group():
    project = tomllib.loads((MY_POLICY / "pyproject.toml").read_text())["project"]
    assert project["entry-points"][ENTRY_POINT_GROUP] == {
        MY_POLICY_NAME: "my_policy:make_lowest_first"
    }


def test_my_policy_is_listed_and_runs_in_the_bench(my_policy_installed, tmp_path, capsys):
    assert main(["policies", MY_POLICY_NAME, "--json"]) == 0
    (info,) = json.loads(capsys.readouterr().out)["policies"]
    assert info["source"] == my_policy_installed["name"]
    assert [(o["key"], o["default"]) for o in info["options"]] == [("prefer", "area")]

    out = tmp_path / "run"
    argv = ["bench", "--policies", f"{MY_POLICY_NAME},dblf", "--cases", demo_cases_path()]
    argv += ["--backend", "geometric", "--seeds", "0", "--workers", "1", "--out", str(out)]
    assert main([*argv, "--no-progress", "--no-figures", "--no-html"]) == 0
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert {r["policy"] for r in records} == {MY_POLICY_NAME, "dblf"}
    assert len(records) == 6 and all(r["status"] == "ok" for r in records)
    assert MY_POLICY_NAME in capsys.readouterr().out  # a row of the printed table


def test_my_policy_refuses_an_unknown_preference(my_policy_installed, tmp_path, capsys):
    argv = ["bench", "--policies", MY_POLICY_NAME, "--cases", demo_cases_path()]
    argv += ["--policy-arg", f"{MY_POLICY_NAME}:prefer=biggest", "--out", str(tmp_path / "r")]
    assert main([*argv, "--backend", "geometric", "--workers", "1", "--no-progress"]) == 2
    assert "choose one of area, scan" in capsys.readouterr().err


def test_my_policy_places_every_box_of_a_demo_case(my_policy_installed):
    case = load_cases(demo_cases_path())[0]
    result = run_episode(case, make_policy(MY_POLICY_NAME), seed=0, backend="geometric")
    assert result.policy == MY_POLICY_NAME and len(result.steps) == len(case.objects)
    assert result.metrics.overall > 0


def test_my_policy_step_by_step_script():
    out = _run(MY_POLICY / "run_episode.py", "--limit", "1")
    assert "step 0: box" in out and "demo-easy-00000" in out


def test_robot_cell_onnx_packs_one_order_without_torch():
    out = _run(EXAMPLES / "robot_cell_onnx" / "robot_cell.py", "--limit", "1")
    assert "policy.onnx) on ONNX Runtime" in out
    assert "step 0: box" in out and "overall" in out
    assert out.rstrip().endswith("torch imported: no")


@pytest.mark.skipif(
    importlib.util.find_spec("sb3_contrib") is None, reason="needs the rl extra (sb3-contrib)"
)
def test_sb3_maskable_ppo_trains_and_plays_an_episode():
    script = EXAMPLES / "sb3_gymnasium" / "train_maskable_ppo.py"
    out = _run(script, "--steps", "32", "--n-steps", "32", timeout=300)
    assert "trained 32 steps" in out and "overall" in out
