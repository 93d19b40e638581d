"""The RL agents on ONNX Runtime: the same actions as torch, no torch imported, clear errors.

The torch-free tests run on the core install; those comparing with torch or exporting need the
rl extra (marked ``torch``, skipped without sb3-contrib).
"""

from __future__ import annotations

import json
import pickle
import shutil
import subprocess
import sys

import numpy as np
import pytest

from packlab.core.errors import ConfigError
from packlab.datagen.generator import generate_cases
from packlab.policies import make_policy
from packlab.policies.onnx_model import ONNX_FORMAT, file_sha256
from packlab.rl.decision import SET_ASIDE, decide, pick_row, ranked_rows
from packlab.rl.features import FeatureSpec, encode
from packlab.rl.onnx_agent import GRAPH_FILE, load_onnx_agent
from packlab.rl.policy import SHIPPED_MODELS
from packlab.sim.episode import Episode, policy_start, run_episode

AGENTS = ("irbpp", "tapnet")
TORCH_STACK = ("torch", "stable_baselines3", "sb3_contrib")


@pytest.fixture(scope="module")
def cases():
    """Generated cases of every level (training seed domain), never a bench suite."""
    levels = ("easy", "medium", "hard")
    return [c for level in levels for c in generate_cases(level, 2, 21, False, domain="train")]


@pytest.fixture(scope="module")
def states(cases):
    """Observations along the proposer's and the random policy's episodes of ``cases``."""
    out = []
    for case in cases:
        for name in ("proposer", "random"):
            episode, policy = Episode("geometric"), make_policy(name)
            observation = episode.reset(case, 0)
            policy.reset(policy_start(policy, case, 0), 0)
            while not episode.done:
                out.append(observation)
                episode.step(policy.act(observation))
                if not episode.done:
                    observation = episode.observe()
    return out


@pytest.fixture
def rl_extra():
    return pytest.importorskip("sb3_contrib")


@pytest.fixture
def irbpp_copy(tmp_path):
    """A copy of the shipped irbpp directory (weights, card, ONNX export)."""
    return shutil.copytree(SHIPPED_MODELS / "irbpp", tmp_path / "irbpp")


# -- the decision rule (pure) -------------------------------------------------------------------


def test_pick_row_takes_the_best_allowed_row_and_the_first_on_a_tie():
    logits = np.array([0.5, 9.0, 0.5, 0.2], dtype=np.float32)
    assert pick_row(logits, np.array([True, False, True, True])) == 0  # masked 9.0 never wins
    assert pick_row(logits, np.array([True, True, True, True])) == 1
    assert pick_row(logits, np.array([False, False, True, True])) == 2
    with pytest.raises(ValueError, match="every row is masked"):
        pick_row(logits, np.zeros(4, dtype=bool))
    with pytest.raises(ValueError, match="differ"):
        pick_row(logits, np.ones(3, dtype=bool))


def test_ranked_rows_put_the_decided_row_first_and_leave_masked_rows_out(states):
    encoded = encode(states[0], FeatureSpec.default("irbpp"))
    n = len(encoded.actions)
    assert n >= 3 and len(encoded.rows) == n
    logits = np.arange(encoded.mask.size, dtype=np.float32)[::-1].copy()
    logits[1] = 99.0  # row 1 first, then rows 0, 2, 3, ... (descending), masked rows never
    ranked = ranked_rows(encoded, lambda arrays: logits)
    assert ranked[:3] == [1, 0, 2] and ranked == sorted(ranked, key=lambda r: -logits[r])
    assert set(ranked) == {r for r in range(n) if encoded.mask[r]}
    assert encoded.actions[ranked[0]] == decide(encoded, lambda arrays: logits)
    assert ranked_rows(type(encoded)(encoded.arrays, ()), lambda arrays: logits) == []


def test_decide_sets_the_box_aside_without_asking_the_network_when_nothing_is_listed(states):
    spec = FeatureSpec.default("irbpp")
    encoded = encode(states[0], spec)
    assert encoded.actions

    def never(arrays):
        raise AssertionError("the network was asked")

    empty = type(encoded)(encoded.arrays, ())
    assert decide(empty, never) == SET_ASIDE
    last = len(encoded.actions) - 1
    scores = np.arange(spec.n_items, dtype=np.float32)  # the last real row scores highest
    assert decide(encoded, lambda arrays: scores) == encoded.actions[last]


# -- the two runtimes agree ---------------------------------------------------------------------


@pytest.mark.torch
@pytest.mark.parametrize("agent", AGENTS)
def test_onnx_and_torch_runtimes_take_identical_actions(agent, states, rl_extra):
    onnx, torch_ = make_policy(agent), make_policy(agent, runtime="torch")
    assert (onnx.runtime, torch_.runtime) == ("onnx", "torch")
    differ = [i for i, o in enumerate(states) if onnx.act(o) != torch_.act(o)]
    assert len(states) > 150
    assert not differ, f"{len(differ)} of {len(states)} states differ, first {differ[0]}"


@pytest.mark.torch
@pytest.mark.parametrize("agent", AGENTS)
def test_onnx_logits_match_torch_and_the_torch_rule_matches_maskableppo(agent, states, rl_extra):
    from packlab.rl.agent import choose_row, load_agent, row_logits

    directory = SHIPPED_MODELS / agent
    loaded, onnx = load_agent(directory), load_onnx_agent(directory)
    for observation in states[::5]:
        encoded = encode(observation, loaded.card.spec)
        if not encoded.actions:
            continue
        real = encoded.mask
        expected = row_logits(loaded.model, encoded.arrays)
        got = onnx.row_logits(encoded.arrays)
        np.testing.assert_allclose(got[real], expected[real], rtol=1e-4, atol=1e-4)
        # The shared rule on torch's logits is MaskablePPO's own deterministic choice.
        predicted, _ = loaded.model.predict(
            encoded.arrays, action_masks=encoded.mask, deterministic=True
        )
        assert choose_row(loaded.model, encoded) == int(np.asarray(predicted).reshape(-1)[0])


# -- no torch on the default runtime ------------------------------------------------------------

NO_TORCH_SCRIPT = """
import importlib.abc, json, sys

class Refuse(importlib.abc.MetaPathFinder):  # the core install: the rl extra is absent
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {blocked!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)

sys.meta_path.insert(0, Refuse())
from packlab.datagen.generator import generate_cases
from packlab.policies import make_policy
from packlab.sim.episode import run_episode

case = generate_cases("medium", 1, 3, False, domain="train")[0]
scores = {{a: run_episode(case, make_policy(a), 0, "geometric").metrics.overall
          for a in ("irbpp", "tapnet")}}
print(json.dumps({{"scores": scores, "loaded": [m for m in {blocked!r} if m in sys.modules]}}))
"""


def test_the_default_runtime_plays_without_importing_torch():
    script = NO_TORCH_SCRIPT.format(blocked=TORCH_STACK)
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["loaded"] == []
    assert all(0.0 < v <= 1.0 for v in result["scores"].values()), result


# -- clear errors -------------------------------------------------------------------------------


def _reset(directory, agent="irbpp", **options):
    policy = make_policy(agent, model=str(directory), **options)
    policy.reset(generate_cases("easy", 1, 4, False, domain="train")[0], 0)
    return policy


def test_a_directory_without_onnx_json_says_to_export_it(irbpp_copy):
    (irbpp_copy / "onnx.json").unlink()
    with pytest.raises(ConfigError, match=rf"no onnx.json .*packlab export onnx {irbpp_copy}"):
        _reset(irbpp_copy)


def test_an_onnx_card_of_another_format_is_refused(irbpp_copy):
    path = irbpp_copy / "onnx.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "format": "packlab-onnx-0"}))
    with pytest.raises(ConfigError, match=rf"'format' = 'packlab-onnx-0'.*{ONNX_FORMAT}"):
        _reset(irbpp_copy)


def test_a_missing_graph_file_is_named(irbpp_copy):
    (irbpp_copy / GRAPH_FILE).unlink()
    with pytest.raises(ConfigError, match=rf"{GRAPH_FILE}: ONNX graph missing.*export onnx"):
        _reset(irbpp_copy)


@pytest.mark.parametrize("changed", ["model.zip", "card.json"])
def test_weights_or_card_changed_after_the_export_are_stale(irbpp_copy, changed):
    _reset(irbpp_copy)  # plays (and is cached in this process) before the change
    path = irbpp_copy / changed
    if changed == "model.zip":
        path.write_bytes(path.read_bytes() + b"\0")
    else:
        path.write_text(json.dumps({**json.loads(path.read_text()), "env_steps": 1}))
    with pytest.raises(ConfigError, match=rf"exported from other weights \({changed} changed"):
        _reset(irbpp_copy)


def test_an_agent_of_another_kind_and_an_unknown_runtime_are_refused(irbpp_copy):
    with pytest.raises(ConfigError, match="'irbpp' agent"):
        _reset(irbpp_copy, agent="tapnet")
    with pytest.raises(ConfigError, match=r"runtime = 'tensorrt': must be one of onnx, torch"):
        make_policy("irbpp", runtime="tensorrt")


def test_a_loaded_policy_pickles_as_configuration(cases):
    policy = make_policy("tapnet")
    first = run_episode(cases[2], policy, 0, "geometric")
    blob = pickle.dumps(policy)
    assert len(blob) < 2_000  # no session, no weights
    again = run_episode(cases[2], pickle.loads(blob), 0, "geometric")
    assert [s.action for s in again.steps] == [s.action for s in first.steps]


# -- the export ---------------------------------------------------------------------------------


@pytest.mark.torch
def test_export_writes_a_checked_graph_and_its_card(irbpp_copy, cases, rl_extra):
    from packlab.rl.onnx_export import export_onnx

    for name in ("onnx.json", GRAPH_FILE):
        (irbpp_copy / name).unlink()
    card = export_onnx(irbpp_copy, check_states=8)
    assert (card.kind, card.opset, card.extra["check_states"]) == ("rl-agent", 18, 8)
    assert card.sources["model.zip"] == file_sha256(irbpp_copy / "model.zip")
    assert card.exported_with.startswith("torch ")
    ours = run_episode(cases[4], make_policy("irbpp", model=str(irbpp_copy)), 0, "geometric")
    shipped = run_episode(cases[4], make_policy("irbpp"), 0, "geometric")
    assert [s.action for s in ours.steps] == [s.action for s in shipped.steps]


@pytest.mark.torch
def test_an_export_whose_decisions_differ_from_torch_writes_nothing(
    irbpp_copy, rl_extra, monkeypatch
):
    from packlab.rl import onnx_export
    from packlab.rl.agent import row_logits

    for name in ("onnx.json", GRAPH_FILE):
        (irbpp_copy / name).unlink()
    # torch's logits negated: states with two or more distinct rows then pick another row
    monkeypatch.setattr(onnx_export, "row_logits", lambda model, arrays: -row_logits(model, arrays))
    with pytest.raises(ConfigError, match=r"picks another row than torch on \d+ of 16"):
        onnx_export.export_onnx(irbpp_copy, check_states=16)
    assert sorted(p.name for p in irbpp_copy.iterdir()) == ["card.json", "model.zip"]


def test_shipped_agents_carry_their_onnx_export():
    for agent in AGENTS:
        directory = SHIPPED_MODELS / agent
        onnx = load_onnx_agent(directory)  # not stale, right format, graph present
        assert onnx.card.agent == agent and onnx.onnx.extra["n_items"] == onnx.card.n_items


def test_policies_of_one_directory_share_one_loaded_agent_in_a_process(irbpp_copy):
    """The bench makes a policy per episode: the session is opened once per process."""
    first, second = _reset(irbpp_copy), _reset(irbpp_copy)
    assert first._playing is second._playing
    assert _reset(irbpp_copy, threads=2)._playing is not first._playing
