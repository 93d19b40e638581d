"""scripts/learned_policies.sh stops each training run where the shipped model stopped.

The recipe caps every run by updates, not minutes (a time cap depends on the machine). These
tests tie its caps to the shipped model cards, so a retrained model that ships without the
recipe being brought along fails here.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from packlab.rl.config import RLTrainConfig

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "scripts" / "learned_policies.sh"
MODELS = ROOT / "src" / "packlab" / "data" / "models"
#: The recipe's PPO runs: 4 envs (``--envs 4``) x the default rollout length per env.
ROLLOUT = 4 * RLTrainConfig().n_steps


def _recipe() -> str:
    # Joined continuation lines, so each command is one line.
    return RECIPE.read_text().replace("\\\n", " ")


def _flag_of_run(flag: str, out: str) -> int:
    """The value of ``flag`` on the recipe's last command that writes ``$OUT/<out>`` (a run
    may be stopped and resumed: the last command sets where it ends)."""
    lines = [ln for ln in _recipe().splitlines() if f'--out "$OUT/{out}"' in ln]
    assert lines, f"{RECIPE.name}: no command writes $OUT/{out}"
    found = re.search(rf"{flag} (\d+)", lines[-1])
    assert found, f"{RECIPE.name}: the run writing $OUT/{out} has no {flag}"
    return int(found.group(1))


@pytest.mark.parametrize("agent", ["irbpp", "tapnet"])
def test_each_shipped_agent_s_run_stops_at_its_last_whole_update(agent):
    card = json.loads((MODELS / agent / "card.json").read_text())
    # The shipped run was stopped by a time cap part way through a rollout, which is not
    # trained on: its weights are those after the last whole rollout.
    whole = card["env_steps"] // ROLLOUT * ROLLOUT
    assert _flag_of_run("--steps", f"{agent}-mix") == whole


def test_the_pointer_model_s_run_stops_at_its_trained_updates():
    meta = json.loads((MODELS / "vlm-small" / "packlab_model.json").read_text())
    assert _flag_of_run("--stop-after", "vlm-text") == meta["trained_steps"]
    # --steps sets the learning-rate schedule: it must be the shipped run's.
    assert _flag_of_run("--steps", "vlm-text") == meta["pointer_train"]["steps"]


def test_no_run_is_capped_by_time():
    assert "--minutes" not in _recipe()


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_the_recipe_parses():
    subprocess.run(["bash", "-n", str(RECIPE)], check=True)
